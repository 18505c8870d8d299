"""The per-scenario paired view of the ego comparison: which scenarios one pipeline solves and another does not.

Every ego of a setting plays the same scenarios, so two pipelines can be compared scenario by scenario instead of
by their rates alone. A pipeline *solves* a scenario when its egos succeed on it in more than half of its seeds
(with 4 seeds: 3 or 4 of them); `paired_counts` counts, per setting and pair of pipelines of the same algorithm
(`seal.experiments.report.grouping.comparable`), the scenarios both solve, only the first, only the second and
neither. `scenario_rates` is the long table behind it (each scenario's success share over seeds per pipeline).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from seal.experiments.report.compare import ordered_pipelines, ordered_settings, setting_label
from seal.experiments.report.grouping import algo_of, comparable
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
