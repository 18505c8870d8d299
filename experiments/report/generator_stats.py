"""Intervals for the generator table (thesis Table 6.2): the realism distance and the collision speed of each
generator setting with 95 % intervals from rliable's bootstrap.

The resampled unit is the *scenario*: every episode of a setting (one per ego) belongs to a scenario, and the
episodes of one scenario are alike (same road, same logged adversary), so resampling episodes one by one would
give intervals that are too narrow. Each resample draws the setting's scenarios with replacement and keeps all
their episodes; the statistic is then computed as in Table 6.2: the pooled realism Wasserstein distances
(`seal.experiments.evaluation.metrics.pooled_realism`, mean of yaw, acceleration and out-of-road, and yaw +
acceleration alone) and the mean collision speed along the contact normal over the episodes with a contact.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from seal.experiments.evaluation.evaluate import REPLAY_SETTINGS
from seal.experiments.evaluation.metrics import realism_counts, realism_from_counts
from seal.experiments.report.compare import ordered_settings, setting_label
from seal.experiments.report.stats import CONFIDENCE, ci_cell, seeded

N_BOOT_GENERATORS = 300
"""Resamples per generator setting (each recomputes the pooled histograms of all its episodes)."""
MIN_SCENARIOS = 5
"""Scenarios (with a contact, for the collision speed) below which an interval is not given (NaN bounds): from one
scenario the bootstrap returns a zero-width interval whatever the data."""
STATISTICS = ("realism", "realism_yaw_acc", "collision_speed_mps")


def generator_rows(gen_ci: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """The rows of generated adversaries: without the settings whose adversary is the logged one replayed
    (``normal``, ``normal-reactive``: Table 6.2's reference rows, near zero by construction), which no generator
    claim may be ranked against."""
    return [r for r in gen_ci if r["setting"] not in REPLAY_SETTINGS]


def _speed(e: Mapping[str, Any]) -> float | None:
    """The episode's collision speed along the contact normal (m/s), None without a contact."""
    v = e["collision_speed_mps"]
    return float(v) if v is not None and math.isfinite(float(v)) else None


def _realism(summed_counts: np.ndarray) -> np.ndarray:
    """``[realism, realism_yaw_acc]`` from the summed `realism_counts` of a set of episodes, as Table 6.2 computes
    them."""
    realism = realism_from_counts(summed_counts)
    return np.array([realism["realism"], float(np.nanmean([realism["yaw_wd"], realism["acc_wd"]]))])


def _mean_speed(summed: np.ndarray) -> np.ndarray:
    """``[mean collision speed]`` from the summed ``[speed sum, contact count]`` of a set of episodes."""
    return np.array([summed[0] / summed[1] if summed[1] > 0 else math.nan])


def _by_scenario_interval(per_group: np.ndarray, statistic: Callable[[np.ndarray], np.ndarray], n_boot: int,
                          seed: int) -> list[tuple[float, float, float]]:
    """``(estimate, low, high)`` per output of ``statistic`` applied to the sum of ``per_group`` rows ``[G, D]`` (a
    scenario's additive summary: histogram counts, sums), the groups resampled with rliable's bootstrap (a resample's
    summary is the sum of its groups' rows, so no episode is re-read); NaN bounds with fewer than `MIN_SCENARIOS`
    groups."""
    from rliable import library as rly

    if len(per_group) < MIN_SCENARIOS:
        estimate = statistic(per_group.sum(axis=0))  # zeros without groups: the statistic's NaN
        return [(float(p), math.nan, math.nan) for p in estimate]

    def on_index(index: np.ndarray) -> np.ndarray:
        return statistic(per_group[index[:, 0].astype(np.int64)].sum(axis=0))

    with seeded(seed), np.errstate(all="ignore"):
        points, intervals = rly.get_interval_estimates(
            {"x": np.arange(len(per_group), dtype=np.float64)[:, None]}, on_index, reps=n_boot,
            confidence_interval_size=CONFIDENCE)
    return [(float(p), float(intervals["x"][0, i]), float(intervals["x"][1, i])) for i, p in enumerate(points["x"])]


def generator_intervals(episodes: Sequence[Mapping[str, Any]], n_boot: int = N_BOOT_GENERATORS, seed: int = 0
                        ) -> dict[str, tuple[float, float, float]]:
    """``{statistic: (estimate, low, high)}`` over ``episodes`` (one setting, histogram columns decoded), the
    scenarios resampled: all of them for the realism distances, those with a contact for the collision speed
    (so that every resample has one)."""
    by_scenario: dict[str, list[Mapping[str, Any]]] = {}
    for e in episodes:
        by_scenario.setdefault(str(e["scenario_id"]), []).append(e)
    groups = list(by_scenario.values())
    counts = np.array([realism_counts([dict(e) for e in g]) for g in groups]).reshape(len(groups),
                                                                                      realism_counts([]).size)
    speeds = [[v for e in g if (v := _speed(e)) is not None] for g in groups]
    contact = np.array([[sum(v), len(v)] for v in speeds if v], dtype=np.float64).reshape(-1, 2)
    realism = _by_scenario_interval(counts, _realism, n_boot, seed)
    speed = _by_scenario_interval(contact, _mean_speed, n_boot, seed)
    return dict(zip(STATISTICS, [*realism, *speed], strict=True))


def generator_ci_table(rows: Sequence[Mapping[str, Any]], generator_settings: Sequence[str],
                       n_boot: int = N_BOOT_GENERATORS, seed: int = 0) -> list[dict[str, Any]]:
    """One row per setting whose label is in ``generator_settings`` (Table 6.2's rows, ``normal`` included):
    ``scenarios``, ``episodes`` and per statistic the estimate with ``<name>_low`` / ``<name>_high``."""
    by_setting: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        if setting_label(r["setting"]) in generator_settings:
            by_setting.setdefault(r["setting"], []).append(r)
    table = []
    for setting in ordered_settings(by_setting):
        eps = by_setting[setting]
        est = generator_intervals(eps, n_boot, seed)
        table.append({"setting": setting_label(setting), "scenarios": len({e["scenario_id"] for e in eps}),
                      "episodes": len(eps),
                      **{k: v for name, (p, lo, hi) in est.items()
                         for k, v in ((name, p), (f"{name}_low", lo), (f"{name}_high", hi))}})
    return table


def generator_ci_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """Settings as rows: realism (mean WD), yaw + acceleration WD and collision speed, each ``estimate [low-high]``."""
    out = ["| generator | scenarios | episodes | realism (mean WD) | yaw+acc WD | coll. speed (m/s) |",
           "|---|---:|---:|---:|---:|---:|"]
    for r in table:
        cells = [ci_cell(r[n], r[f"{n}_low"], r[f"{n}_high"], 1.0, 3 if n != "collision_speed_mps" else 2)
                 for n in STATISTICS]
        out.append(f"| {r['setting']} | {r['scenarios']} | {r['episodes']} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"
