"""Paired success gaps: one ego group's success rate minus another's on the scenarios both played, with the crossed
bootstrap of `seal.experiments.report.stats` drawing the scenarios once for both sides and each side's seeds apart.

The first page asks whether a setting's leader is ahead of its runner-up, and of the reference egos (Replay, the
heuristic driver), by more than the scenario-to-scenario noise. Each side's own crossed interval carries that noise,
but the two sides play the same scenarios, so most of it is shared and cancels in the difference: two intervals that
do not overlap would ask for a margin about twice the noise that is really there. The paired interval of the gap
asks the right question; `gaps.csv` holds every gap the first page reads.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np

from seal.experiments.report.compare import setting_label
from seal.experiments.report.stats import (
    CONFIDENCE,
    N_BOOT,
    ScoreMatrix,
    drawn_seed_rates,
    paired_outcomes,
    scenario_draws,
    score_matrices,
)


def paired_gap(x: ScoreMatrix, y: ScoreMatrix, metric: str = "success", n_boot: int = N_BOOT, seed: int = 0
               ) -> dict[str, float]:
    """``{gap, gap_low, gap_high, scenarios}``: the mean rate of ``x``'s seeds minus ``y``'s on their common
    scenarios, with the 95 % percentile interval of the paired crossed bootstrap (the common scenarios drawn with
    replacement once per resample for both, each side's seeds drawn with replacement apart). NaNs without a common
    scenario."""
    vx, vy = paired_outcomes(x, y, metric)  # [scenarios, seeds_x], [scenarios, seeds_y]
    n = vx.shape[0]
    if not n:
        return {"gap": np.nan, "gap_low": np.nan, "gap_high": np.nan, "scenarios": 0}
    rng = np.random.default_rng(seed)
    counts = scenario_draws(n, n_boot, rng)  # one draw of the scenarios for both sides
    boot = drawn_seed_rates(vx, counts, rng).mean(axis=1) - drawn_seed_rates(vy, counts, rng).mean(axis=1)
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(boot, [tail, 100 - tail])
    return {"gap": float(vx.mean() - vy.mean()), "gap_low": float(low), "gap_high": float(high),
            "scenarios": n}


def gap_table(rows: Sequence[Mapping[str, Any]], pairs: Collection[tuple[str, str, str]], n_boot: int = N_BOOT,
              seed: int = 0) -> list[dict[str, Any]]:
    """One row per ``(pipeline, reference, setting label)`` of ``pairs`` that both were evaluated on:
    ``pipeline``, ``reference``, ``setting``, ``scenarios`` and the success `paired_gap` (rates in [0, 1])."""
    matrices = score_matrices(rows)
    by_label = {(p, setting_label(s)): m for (p, s), m in matrices.items()}
    table = []
    for a, b, setting in dict.fromkeys(pairs):
        if (a, setting) in by_label and (b, setting) in by_label:
            table.append({"pipeline": a, "reference": b, "setting": setting,
                          **paired_gap(by_label[(a, setting)], by_label[(b, setting)], n_boot=n_boot, seed=seed)})
    return table


def gap_lookup(gaps: Sequence[Mapping[str, Any]]) -> dict[tuple[str, str, str], Mapping[str, Any]]:
    """``{(pipeline, reference, setting): gap row}``, each row also under the swapped pair with the gap negated."""
    out: dict[tuple[str, str, str], Mapping[str, Any]] = {}
    for r in gaps:
        out[(r["pipeline"], r["reference"], r["setting"])] = r
        out[(r["reference"], r["pipeline"], r["setting"])] = {
            **r, "pipeline": r["reference"], "reference": r["pipeline"], "gap": -r["gap"],
            "gap_low": -r["gap_high"], "gap_high": -r["gap_low"]}
    return out
