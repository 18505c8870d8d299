"""The per-scenario paired view of the ego comparison: which scenarios one pipeline solves and another does not.

Every ego of a setting plays the same scenarios, so two pipelines can be compared scenario by scenario instead of
by their rates alone. A pipeline *solves* a scenario when its egos succeed on it in more than half of its seeds
(with 4 seeds: 3 or 4 of them); `paired_counts` counts, per setting and pair of pipelines of the same algorithm
(`seal.experiments.report.grouping.comparable`), the scenarios both solve, only the first, only the second and
neither. `scenario_rates` is the long table behind it (each scenario's success share over seeds per pipeline).

`discrimination_counts` says how much of a setting can tell egos apart at all: per setting and ego algorithm, the
scenarios on which every trained ego (all pipelines, all seeds) succeeds, every one fails, and the rest. Only the
rest can move a difference between pipelines; on the decisive run's ReSkill egos that is 68 of 300 scenarios on
`cat` (156 fail for all 24 egos) against 104 on Normal.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from seal.experiments.report.compare import ordered_pipelines, ordered_settings, setting_label
from seal.experiments.report.grouping import algo_of, comparable, is_trained
from seal.experiments.report.stats import ScoreMatrix, score_matrices


def _solved(matrix: ScoreMatrix) -> dict[str, bool]:
    """``{scenario_id: solved}``: success in more than half of the seeds."""
    shares = matrix.values[:, :, 0].mean(axis=1)  # EGO_METRICS[0] is success
    return {sid: bool(share > 0.5) for sid, share in zip(matrix.scenario_ids, shares, strict=True)}


def scenario_rates(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (setting, scenario, pipeline): ``seeds``, ``successes`` and ``success_share`` over the seeds,
    ``solved`` (share > 1/2)."""
    matrices = score_matrices(rows)
    out = []
    for setting in ordered_settings(s for _, s in matrices):
        for pipeline in ordered_pipelines(p for p, s in matrices if s == setting):
            m = matrices[(pipeline, setting)]
            wins = m.values[:, :, 0].sum(axis=1)
            for sid, w in zip(m.scenario_ids, wins, strict=True):
                out.append({"setting": setting_label(setting), "scenario_id": sid, "pipeline": pipeline,
                            "seeds": len(m.runs), "successes": int(w), "success_share": float(w) / len(m.runs),
                            "solved": bool(w > len(m.runs) / 2)})
    return out


def paired_counts(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (setting, ordered pair of comparable pipelines) over the scenarios both played: ``both``,
    ``only_pipeline`` (the first solves, the reference does not), ``only_reference``, ``neither``,
    ``scenarios``."""
    matrices = score_matrices(rows)
    out = []
    for setting in ordered_settings(s for _, s in matrices):
        names = ordered_pipelines(p for p, s in matrices if s == setting)
        solved = {p: _solved(matrices[(p, setting)]) for p in names}
        for a in names:
            for b in names:
                if a == b or not comparable(a, b):
                    continue
                common = sorted(set(solved[a]) & set(solved[b]))
                pairs = [(solved[a][s], solved[b][s]) for s in common]
                out.append({"setting": setting_label(setting), "pipeline": a, "reference": b, "scenarios": len(common),
                            "both": sum(x and y for x, y in pairs), "only_pipeline": sum(x and not y for x, y in pairs),
                            "only_reference": sum(y and not x for x, y in pairs),
                            "neither": sum(not (x or y) for x, y in pairs)})
    return out


def paired_markdown(counts: Sequence[Mapping[str, Any]]) -> str:
    """Per setting (and ego algorithm) a matrix: cell (row X, column Y) = scenarios X solves and Y does not, of
    the scenarios both played."""
    out = []
    groups = dict.fromkeys((r["setting"], algo_of(r["pipeline"])) for r in counts)
    for setting, algo in groups:  # one matrix per setting and ego algorithm: only those are compared
        rows = [r for r in counts if r["setting"] == setting and algo_of(r["pipeline"]) == algo]
        names = ordered_pipelines({r["pipeline"] for r in rows})
        cells = {(r["pipeline"], r["reference"]): r for r in rows}
        n = max(r["scenarios"] for r in rows)
        out.append(f"**{setting}**{f' ({algo} egos)' if algo else ''} ({n} scenarios): scenarios the row solves "
                   "and the column does not\n")
        out.append("| solves, other does not | " + " | ".join(names) + " |")
        out.append("|---|" + "---:|" * len(names))
        for a in names:
            out.append(f"| {a} | " + " | ".join(
                str(c["only_pipeline"]) if (c := cells.get((a, b))) else "-" for b in names) + " |")
        out.append("")
    return "\n".join(out)


def discrimination_counts(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (setting, ego algorithm) over the trained egos' pipelines (built-in egos left out) and the
    scenarios all of them played: ``egos`` (runs), ``scenarios``, ``all_succeed``, ``all_fail``, ``differ``."""
    matrices = {k: m for k, m in score_matrices(rows).items() if is_trained(k[0])}
    out = []
    for setting in ordered_settings(s for _, s in matrices):
        names = ordered_pipelines(p for p, s in matrices if s == setting)
        for algo in dict.fromkeys(algo_of(p) for p in names):
            group = [matrices[(p, setting)] for p in names if algo_of(p) == algo]
            common = sorted(set.intersection(*(set(m.scenario_ids) for m in group)))
            if not common:
                continue
            row_of = [{sid: i for i, sid in enumerate(m.scenario_ids)} for m in group]
            wins = np.concatenate([m.values[[at[s] for s in common], :, 0]
                                   for m, at in zip(group, row_of, strict=True)], axis=1)
            every, none = wins.all(axis=1), ~wins.any(axis=1)
            out.append({"setting": setting_label(setting), "algo": algo, "egos": int(wins.shape[1]),
                        "scenarios": len(common), "all_succeed": int(every.sum()), "all_fail": int(none.sum()),
                        "differ": int(len(common) - every.sum() - none.sum())})
    return out


def discrimination_markdown(counts: Sequence[Mapping[str, Any]]) -> str:
    """`discrimination_counts` as a table."""
    lines = ["| setting | egos | scenarios | every ego succeeds | every ego fails | egos differ |",
             "|---|---:|---:|---:|---:|---:|"]
    for r in counts:
        label = f"{r['setting']} ({r['algo']})" if r["algo"] else r["setting"]
        lines.append(f"| {label} | {r['egos']} | {r['scenarios']} | {r['all_succeed']} | {r['all_fail']} | "
                     f"{r['differ']} ({100 * r['differ'] / r['scenarios']:.0f} %) |")
    return "\n".join(lines) + "\n"
