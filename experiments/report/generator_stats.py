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
STATISTICS = ("realism", "realism_yaw_acc", "collision_speed_mps", "realism_yaw_acc_per_scenario")
"""The pooled realism distances (mean WD; yaw + acceleration alone), the mean collision speed, and the per-scenario
reading of realism: each episode's own yaw + acceleration WDs to its scenario's logged adversary, averaged."""
MATCHED_SPEED = "collision_speed_matched_mps"
"""A paired difference only: the mean over *matched* episodes (the same ego in the same scenario, a contact in both
settings) of the first setting's collision speed minus the other's. The plain difference of the two mean collision
speeds also compares *which* scenarios end in a contact: a generator that makes contacts in more slow scenes (CAT
against SEAL on decisive5's held-out pool: 313 against 266 contacts an ego) has the lower mean even where, contact
for contact, it is not slower. This reading holds the ego and the scenario fixed and asks how hard each generator's
adversary hits when both hit."""
DIFFERENCE_STATISTICS = (*STATISTICS, MATCHED_SPEED)


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


def _episode_yaw_acc(e: Mapping[str, Any]) -> float | None:
    """The mean of the episode's own yaw and acceleration WDs (Table 6.2's ``yaw+acc WD per scenario`` averages
    these), None where either is missing."""
    y, a = e.get("yaw_wd"), e.get("acc_wd")
    v = (float(y) + float(a)) / 2 if y is not None and a is not None else math.nan
    return v if math.isfinite(v) else None


def _sum_count(values: Sequence[float]) -> list[float]:
    return [float(sum(values)), float(len(values))]


def _mean_of_sum(summed: np.ndarray) -> np.ndarray:
    """``[mean]`` from a summed ``[sum, count]`` (the collision speed over the contacts; the per-episode realism
    over the episodes)."""
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


_SUMMARY_WIDTH = realism_counts([]).size + 4
"""Length of one scenario's `_per_scenario_summaries` vector."""


def _per_scenario_summaries(episodes: Sequence[Mapping[str, Any]]) -> dict[str, np.ndarray]:
    """Scenario id -> its additive summary: the `realism_counts` of its episodes, then ``[collision speed sum,
    contacts]``, then ``[sum, count]`` of the episodes' own yaw + acceleration WDs."""
    by_scenario: dict[str, list[Mapping[str, Any]]] = {}
    for e in episodes:
        by_scenario.setdefault(str(e["scenario_id"]), []).append(e)
    out = {}
    for sid, group in by_scenario.items():
        speeds = [v for e in group if (v := _speed(e)) is not None]
        own = [v for e in group if (v := _episode_yaw_acc(e)) is not None]
        out[sid] = np.concatenate([realism_counts([dict(e) for e in group]), _sum_count(speeds), _sum_count(own)])
    return out


def generator_intervals(episodes: Sequence[Mapping[str, Any]], n_boot: int = N_BOOT_GENERATORS, seed: int = 0
                        ) -> dict[str, tuple[float, float, float]]:
    """``{statistic: (estimate, low, high)}`` over ``episodes`` (one setting, histogram columns decoded), the
    scenarios resampled: all of them for the realism distances, those with a contact for the collision speed
    (so that every resample has one)."""
    summary = np.array(list(_per_scenario_summaries(episodes).values())).reshape(-1, _SUMMARY_WIDTH)
    counts, contact, own = summary[:, :-4], summary[:, -4:-2], summary[:, -2:]
    contact = contact[contact[:, 1] > 0]
    realism = _by_scenario_interval(counts, _realism, n_boot, seed)
    speed = _by_scenario_interval(contact, _mean_of_sum, n_boot, seed)
    per_scenario = _by_scenario_interval(own, _mean_of_sum, n_boot, seed)
    return dict(zip(STATISTICS, [*realism, *speed, *per_scenario], strict=True))


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
    """Settings as rows: realism (mean WD), yaw + acceleration WD, collision speed and the per-scenario yaw +
    acceleration WD, each ``estimate [low-high]``."""
    out = ["| generator | scenarios | episodes | realism (mean WD) | yaw+acc WD | coll. speed (m/s) | yaw+acc WD per "
           "scenario |", "|---|---:|---:|---:|---:|---:|---:|"]
    for r in table:
        cells = [ci_cell(r[n], r[f"{n}_low"], r[f"{n}_high"], 1.0, 3 if n != "collision_speed_mps" else 2)
                 for n in STATISTICS]
        out.append(f"| {r['setting']} | {r['scenarios']} | {r['episodes']} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def _statistics(summed: np.ndarray) -> np.ndarray:
    """`STATISTICS` from one summed `_per_scenario_summaries` vector."""
    return np.concatenate([_realism(summed[:-4]), _mean_of_sum(summed[-4:-2]), _mean_of_sum(summed[-2:])])


def _difference(summed: np.ndarray) -> np.ndarray:
    """`DIFFERENCE_STATISTICS`: `STATISTICS` of the first setting's summary (the first `_SUMMARY_WIDTH` columns)
    minus the other's (the next `_SUMMARY_WIDTH`), then the matched collision speed difference from the last two
    columns ``[sum of the matched differences, matched episodes]``."""
    width = 2 * _SUMMARY_WIDTH
    return np.concatenate([_statistics(summed[:_SUMMARY_WIDTH]) - _statistics(summed[_SUMMARY_WIDTH:width]),
                           _mean_of_sum(summed[width:width + 2])])


def _speeds_by_scenario(episodes: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, float]]:
    """Scenario id -> {ego run: collision speed} of the episodes with a contact."""
    out: dict[str, dict[str, float]] = {}
    for e in episodes:
        if (v := _speed(e)) is not None:
            out.setdefault(str(e["scenario_id"]), {})[str(e["run"])] = v
    return out


def _matched_speed(a: Mapping[str, float], b: Mapping[str, float]) -> list[float]:
    """``[sum of a's minus b's collision speed, count]`` over the egos with a contact in both (one scenario)."""
    both = sorted(set(a) & set(b))
    return [float(sum(a[r] - b[r] for r in both)), float(len(both))]


def generator_difference_table(rows: Sequence[Mapping[str, Any]], generator_settings: Sequence[str],
                               n_boot: int = N_BOOT_GENERATORS, seed: int = 0) -> list[dict[str, Any]]:
    """Every pair of generated-adversary settings (``generator_settings`` without the replayed ones), *paired*
    over the scenarios both played: per statistic, ``setting``'s value minus ``reference``'s, with a 95 % interval
    from one bootstrap that draws the shared scenarios with replacement and keeps all their episodes in *both*
    settings. The generators perturb the same scenarios, so a scenario that is hard to imitate in one tends to be
    hard in the other; comparing two unpaired intervals (do they overlap?) ignores that and misses differences this
    finds. Both orders of a pair (the reverse negated, same resamples); ``scenarios`` = shared scenarios."""
    by_setting: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        label = setting_label(r["setting"])
        if label in generator_settings and r["setting"] not in REPLAY_SETTINGS:
            by_setting.setdefault(r["setting"], []).append(r)
    settings = ordered_settings(by_setting)
    summaries = {s: _per_scenario_summaries(by_setting[s]) for s in settings}
    speeds = {s: _speeds_by_scenario(by_setting[s]) for s in settings}
    table = []
    for i, a in enumerate(settings):
        for b in settings[i + 1:]:
            shared = sorted(set(summaries[a]) & set(summaries[b]))
            per_group = np.array([np.concatenate([summaries[a][s], summaries[b][s], _matched_speed(
                speeds[a].get(s, {}), speeds[b].get(s, {}))]) for s in shared]).reshape(
                len(shared), 2 * _SUMMARY_WIDTH + 2)
            estimates = _by_scenario_interval(per_group, _difference, n_boot, seed)
            matched = per_group[:, -1]
            if np.count_nonzero(matched) < MIN_SCENARIOS:  # too few scenarios with matched contacts to resample
                estimates[-1] = (estimates[-1][0], math.nan, math.nan)
            for first, second, sign in ((a, b, 1.0), (b, a, -1.0)):
                row: dict[str, Any] = {"setting": setting_label(first), "reference": setting_label(second),
                                       "scenarios": len(shared), "matched_contacts": int(matched.sum())}
                for name, (p, lo, hi) in zip(DIFFERENCE_STATISTICS, estimates, strict=True):
                    low, high = (lo, hi) if sign > 0 else (-hi, -lo)
                    row.update({name: sign * p, f"{name}_low": low, f"{name}_high": high})
                table.append(row)
    return table


def generator_difference_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """Four matrices (realism mean WD, collision speed, collision speed on matched contacts (`MATCHED_SPEED`),
    per-scenario yaw + acceleration WD): row minus column,
    ``estimate [low to high]``, the cells whose interval excludes 0 in bold."""
    settings = list(dict.fromkeys(r["setting"] for r in table))
    cells = {(r["setting"], r["reference"]): r for r in table}
    out = []
    for name, title, digits in (("realism", "realism (mean WD)", 3), ("collision_speed_mps", "coll. speed (m/s)", 2),
                                (MATCHED_SPEED, "coll. speed, matched contacts (m/s)", 2),
                                ("realism_yaw_acc_per_scenario", "yaw+acc WD per scenario", 3)):
        out += [f"| {title}: row - column | " + " | ".join(settings) + " |", "|---|" + "---:|" * len(settings)]
        for a in settings:
            row = []
            for b in settings:
                r = cells.get((a, b))
                if r is None:
                    row.append("-")
                    continue
                p, lo, hi = r[name], r[f"{name}_low"], r[f"{name}_high"]
                text = (f"{p:+.{digits}f} [{lo:+.{digits}f} to {hi:+.{digits}f}]" if math.isfinite(lo)
                        and math.isfinite(hi) else f"{p:+.{digits}f} [no interval]")
                row.append(f"**{text}**" if lo > 0 or hi < 0 else text)
            out.append(f"| {a} | " + " | ".join(row) + " |")
        out.append("")
    return "\n".join(out)
