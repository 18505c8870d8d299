"""Does the training pipeline change what the egos do? Per-scenario agreement of egos within and across pipelines.

Two egos *agree* on a scenario when both succeed or both fail on it; their agreement is the share of the scenarios
both played on which they do. If training against one adversary rather than another changes what an ego does, the
egos of one pipeline (its seeds) agree with each other more often than with the egos of other pipelines.
`agreement_table` gives, per setting and ego algorithm, and over all settings pooled (each setting's scenarios as
items of their own), the mean agreement of the pairs of egos from the same pipeline and of the pairs from different
pipelines, the difference, and a permutation p-value: the share of random relabellings of the egos (pipelines of
the same sizes) whose difference is at least the observed one (one-sided, ``(1 + count) / (1 + permutations)``).
It says nothing about which pipeline is better, only whether the pipeline leaves a trace in the egos' outcomes
beyond the seeds' spread: success rates can differ while the egos fail the same scenarios, and egos can fail
different scenarios at the same rate.

Beside it, each reference ego's (the heuristic driver, Replay) mean agreement with the trained egos: how much of
what the trained egos do the reference already does. In a generator setting each ego meets the adversary generated
against its own roll-outs (K > 0), so "the same scenario" is the same scene perturbed for each ego.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from seal.experiments.report.compare import ordered_pipelines, ordered_settings, setting_label
from seal.experiments.report.grouping import algo_of, base_pipeline, is_trained
from seal.experiments.report.stats import ScoreMatrix, score_matrices

N_PERMUTATIONS = 2000
ALL_SETTINGS = "all settings"
"""The ``setting`` of the pooled row."""


def _group(matrices: Mapping[tuple[str, str], ScoreMatrix], setting: str, algo: str
           ) -> tuple[np.ndarray, list[str], list[str], list[str]] | None:
    """Success ``[scenarios, egos]`` of the trained egos of ``algo`` in ``setting`` on the scenarios all of them
    played, with each ego's pipeline and run and the scenario ids; None without any such scenario."""
    cells = [(p, m) for (p, s), m in matrices.items() if s == setting and is_trained(p) and algo_of(p) == algo]
    if not cells:
        return None
    cells = [(p, matrices[(p, setting)]) for p in ordered_pipelines(p for p, _ in cells)]
    common = sorted(set.intersection(*(set(m.scenario_ids) for _, m in cells)))
    if not common:
        return None
    columns, labels, runs = [], [], []
    for pipeline, m in cells:
        at = {sid: i for i, sid in enumerate(m.scenario_ids)}
        columns.append(m.values[[at[s] for s in common], :, 0])  # EGO_METRICS[0] is success
        labels += [pipeline] * len(m.runs)
        runs += list(m.runs)
    return np.concatenate(columns, axis=1), labels, runs, common


def within_across(success: np.ndarray, labels: Sequence[str], n_permutations: int = N_PERMUTATIONS, seed: int = 0
                  ) -> dict[str, float]:
    """``within`` / ``across``: mean agreement of the pairs of columns of ``success [scenarios, egos]`` with the
    same / different ``labels``; ``difference``; ``p_value`` of the difference under random relabelling (NaN
    without a pair of each kind)."""
    agree = (success[:, :, None] == success[:, None, :]).mean(axis=0)
    i, j = np.triu_indices(len(labels), k=1)
    pair_agree = agree[i, j]
    codes = np.unique(np.asarray(labels), return_inverse=True)[1]

    def gap(lab: np.ndarray) -> np.ndarray:
        same = lab[..., i] == lab[..., j]
        n_same, n_diff = same.sum(-1), (~same).sum(-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.stack([(same * pair_agree).sum(-1) / n_same, (~same * pair_agree).sum(-1) / n_diff])

    within, across = gap(codes)
    if not (math.isfinite(within) and math.isfinite(across)):
        return {"within": float(within), "across": float(across), "difference": math.nan, "p_value": math.nan}
    rng = np.random.default_rng(seed)
    shuffled = np.array([rng.permutation(codes) for _ in range(n_permutations)])
    w, a = gap(shuffled)
    observed = within - across
    count = int(np.sum(w - a >= observed - 1e-12))
    return {"within": float(within), "across": float(across), "difference": float(observed),
            "p_value": (1 + count) / (1 + n_permutations)}


def _reference_agreement(matrices: Mapping[tuple[str, str], ScoreMatrix], setting: str, success: np.ndarray,
                         scenario_ids: Sequence[str]) -> dict[str, float]:
    """``{"agree_<reference>": mean over the trained egos of their agreement with it}`` for every reference ego
    evaluated in ``setting``, on the scenarios both played."""
    out = {}
    for (pipeline, s), m in matrices.items():
        if s != setting or is_trained(pipeline):
            continue
        ref = {sid: m.values[k, 0, 0] for k, sid in enumerate(m.scenario_ids)}
        rows = [k for k, sid in enumerate(scenario_ids) if sid in ref]
        if rows:
            ref_col = np.array([ref[scenario_ids[k]] for k in rows])
            out[f"agree_{base_pipeline(pipeline)}"] = float((success[rows] == ref_col[:, None]).mean())
    return out


def agreement_table(rows: Sequence[Mapping[str, Any]], n_permutations: int = N_PERMUTATIONS, seed: int = 0
                    ) -> list[dict[str, Any]]:
    """One row per (setting, ego algorithm) and one per algorithm over all settings (`ALL_SETTINGS`): ``egos``,
    ``pipelines``, ``scenarios``, ``within``, ``across``, ``difference``, ``p_value`` (`within_across`),
    ``permutations`` and ``agree_<reference>`` per reference ego (the pooled row: scenario-weighted means)."""
    matrices = score_matrices(rows)
    settings = ordered_settings(s for _, s in matrices)
    algos = list(dict.fromkeys(algo_of(p) for p, _ in matrices if is_trained(p)))
    out = []
    for algo in algos:
        pooled: list[tuple[np.ndarray, list[str], dict[str, float]]] = []
        pipeline_of: dict[str, str] = {}
        for setting in settings:
            group = _group(matrices, setting, algo)
            if group is None:
                continue
            success, labels, runs, scenario_ids = group
            pipeline_of.update(zip(runs, labels, strict=True))
            refs = _reference_agreement(matrices, setting, success, scenario_ids)
            out.append({"setting": setting_label(setting), "algo": algo, "egos": len(labels),
                        "pipelines": len(set(labels)), "scenarios": len(scenario_ids),
                        **within_across(success, labels, n_permutations, seed), "permutations": n_permutations,
                        **refs})
            pooled.append((success[:, np.argsort(runs)], sorted(runs), refs))
        same_egos = [p for p in pooled if p[1] == pooled[0][1]] if pooled else []
        if len(same_egos) > 1:  # every setting with the same egos: their scenarios side by side
            labels = [pipeline_of[run] for run in same_egos[0][1]]
            success = np.concatenate([p[0] for p in same_egos], axis=0)
            n = np.array([len(p[0]) for p in same_egos], dtype=np.float64)
            keys = set.intersection(*(set(p[2]) for p in same_egos))
            refs = {k: float(np.average([p[2][k] for p in same_egos], weights=n)) for k in sorted(keys)}
            out.append({"setting": ALL_SETTINGS, "algo": algo, "egos": len(labels), "pipelines": len(set(labels)),
                        "scenarios": len(success), **within_across(success, labels, n_permutations, seed),
                        "permutations": n_permutations, **refs})
    return out


def agreement_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """`agreement_table` as a Markdown table (agreements in %)."""
    refs = sorted({k for r in table for k in r if k.startswith("agree_")})
    head = ["setting", "egos", "scenarios", "same pipeline", "different pipelines", "difference (points)",
            "p (permutation)", *(f"{k[len('agree_'):]} agrees" for k in refs)]
    lines = ["| " + " | ".join(head) + " |", "|---|" + "---:|" * (len(head) - 1)]
    for r in table:
        label = f"{r['setting']} ({r['algo']})" if r["algo"] else r["setting"]
        cells = [label, str(r["egos"]), str(r["scenarios"]), _pct(r["within"]), _pct(r["across"]),
                 "-" if not math.isfinite(r["difference"]) else f"{100 * r['difference']:+.1f}",
                 "-" if not math.isfinite(r["p_value"]) else f"{r['p_value']:.3f}",
                 *(_pct(r.get(k, math.nan)) for k in refs)]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def agreement_line(row: Mapping[str, Any]) -> str:
    """The first page's sentence for one algorithm's pooled row."""
    if not math.isfinite(row["difference"]):
        return ""
    trace = ("the egos of one pipeline are more alike than the seeds' spread explains" if row["p_value"] < 0.05
             else "no trace of the pipeline beyond the seeds' spread")
    refs = "; ".join(f"the {k[len('agree_'):]} ego agrees with them on {_pct(v)}" for k, v in row.items()
                     if k.startswith("agree_"))
    return (f"- Does the pipeline change what the egos do? Over {row['scenarios']} scenarios of all settings, two "
            f"egos of the same pipeline agree (both succeed or both fail) on {_pct(row['within'])}, two of different "
            f"pipelines on {_pct(row['across'])} (permutation p = {row['p_value']:.3f}): {trace}"
            + (f"; {refs}" if refs else "") + ".")


def _pct(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{100 * value:.1f} %"
