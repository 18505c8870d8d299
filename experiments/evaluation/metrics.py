"""Per-episode metrics of one scored evaluation episode, as a results-store row
(`seal.experiments.evaluation.results_store`).

Ego outcome flags and route completion; ego-adversary interaction (closest body gap, close call = gap <=
`CLOSE_CALL_M` or a collision, relative speed along the contact normal at the first contact, head-on / severe
head-on as in `seal.scoring.realism.collision_metrics`); realism of the executed adversary against the scenario's
logged adversary: per-episode Wasserstein distances and the yaw-rate / acceleration histogram counts on
`seal.scoring.realism`'s bins. Pooled counts give exactly the set-level distances of `seal.scoring.realism.realism_wd`
(the histogram of concatenated samples is the sum of the per-episode histograms), which `seal compare` uses.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from seal.core.geometry import box_corners, box_gap
from seal.core.outcome import Outcome
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, VALID, WIDTH, Scenario, X, Y
from seal.envs.rollout import Rollout
from seal.experiments.evaluation.generator_metrics import LoggedAdversary, offroad_flags
from seal.scoring.realism import (
    ACC_BINS,
    HARD_BRAKE_MPS2,
    OFFROAD_BINS,
    YAW_RATE_BINS,
    accelerations,
    collision_metrics,
    realism_wd,
    yaw_rates,
)

CLOSE_CALL_M = 2.0
"""Body gap (m) under which an ego-adversary approach counts as a close call (as `seal.scoring.splits` reports)."""


def histogram_counts(samples: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """Counts of ``samples`` on ``bins`` with out-of-range values in the edge bins (as `seal.scoring.realism`)."""
    lo, hi = bins[0], bins[-1]
    eps = 1e-9 * (hi - lo)
    counts, _ = np.histogram(np.clip(np.asarray(samples, dtype=np.float64), lo + eps, hi - eps), bins=bins)
    return counts


def wasserstein_from_counts(a: np.ndarray, b: np.ndarray, bins: np.ndarray) -> float:
    """W1 between two histograms given as counts on ``bins`` (point masses at bin centres); NaN if one is empty.
    Equal to `seal.scoring.realism.histogram_wasserstein` of the samples the counts came from."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != (len(bins) - 1,) or b.shape != a.shape:
        raise ValueError(f"histogram counts of shapes {a.shape} and {b.shape} do not match {len(bins) - 1} bins")
    if a.sum() <= 0 or b.sum() <= 0:
        return float("nan")
    cdf_gap = np.cumsum(a / a.sum() - b / b.sum())[:-1]
    centres = 0.5 * (bins[1:] + bins[:-1])
    return float(np.sum(np.abs(cdf_gap) * np.diff(centres)))


_REALISM_BINS = (YAW_RATE_BINS, YAW_RATE_BINS, ACC_BINS, ACC_BINS, OFFROAD_BINS, OFFROAD_BINS)
"""Bins of the six histograms `realism_counts` concatenates, in its order."""


def realism_counts(rows: Sequence[dict[str, Any]]) -> np.ndarray:
    """The summed histogram counts of episode rows (histogram columns decoded to int lists) - generated and logged
    yaw rate, generated and logged acceleration, generated and logged out-of-road share - concatenated into one
    vector: counts of a union of row sets are the sum of their vectors, so a bootstrap can sum precomputed
    per-group vectors instead of re-reading every row."""
    if not rows:
        return np.zeros(sum(len(b) - 1 for b in _REALISM_BINS), dtype=np.float64)
    parts = [
        np.sum([r["adv_yaw_hist"] for r in rows], axis=0), np.sum([r["log_yaw_hist"] for r in rows], axis=0),
        np.sum([r["adv_acc_hist"] for r in rows], axis=0), np.sum([r["log_acc_hist"] for r in rows], axis=0),
        histogram_counts(np.array([r["adv_offroad_share"] for r in rows]), OFFROAD_BINS),
        histogram_counts(np.array([r["log_offroad_share"] for r in rows]), OFFROAD_BINS),
    ]
    return np.concatenate([np.asarray(p, dtype=np.float64) for p in parts])


def realism_from_counts(counts: np.ndarray) -> dict[str, float]:
    """``yaw_wd``, ``acc_wd``, ``road_wd`` and their mean ``realism`` from a `realism_counts` vector (NaN where a
    histogram is empty), and the generated and logged ``hard_brake_share`` (which way the acceleration differs)."""
    ends = np.cumsum([len(b) - 1 for b in _REALISM_BINS])[:-1]
    ay, ly, aa, la, ar, lr = np.split(np.asarray(counts, dtype=np.float64), ends)
    yaw = wasserstein_from_counts(ay, ly, YAW_RATE_BINS)
    acc = wasserstein_from_counts(aa, la, ACC_BINS)
    road = wasserstein_from_counts(ar, lr, OFFROAD_BINS)
    finite = [v for v in (yaw, acc, road) if np.isfinite(v)]
    return {"yaw_wd": yaw, "acc_wd": acc, "road_wd": road, "realism": float(np.mean(finite)) if finite else np.nan,
            "hard_brake_share": _hard_brake_share(aa), "logged_hard_brake_share": _hard_brake_share(la)}


_HARD_BRAKE_BINS = int(np.searchsorted(ACC_BINS, -HARD_BRAKE_MPS2))
"""Acceleration bins below -`HARD_BRAKE_MPS2` (one of `ACC_BINS`' edges, so the share is exact)."""
assert ACC_BINS[_HARD_BRAKE_BINS] == -HARD_BRAKE_MPS2, "the hard-braking threshold must be an ACC_BINS edge"


def _hard_brake_share(acc_counts: np.ndarray) -> float:
    """Share of steps braking harder than `HARD_BRAKE_MPS2` in an acceleration histogram on `ACC_BINS` (as
    `seal.scoring.realism.acceleration_stats`); NaN when empty."""
    total = float(acc_counts.sum())
    return float(acc_counts[:_HARD_BRAKE_BINS].sum()) / total if total else float("nan")


def pooled_realism(rows: Sequence[dict[str, Any]]) -> dict[str, float]:
    """Set-level ``yaw_wd``, ``acc_wd``, ``road_wd`` and their mean ``realism`` over episode rows (histogram
    columns decoded to int lists), generated vs logged adversaries; all NaN without rows."""
    return realism_from_counts(realism_counts(rows))


def min_body_gap(ego_track: np.ndarray, adv_track: np.ndarray) -> float | None:
    """Closest body gap (m) of two ``[T, 8]`` tracks over the steps where both are valid; None if none."""
    both = (ego_track[:, VALID] > 0.5) & (adv_track[:, VALID] > 0.5)
    if not both.any():
        return None
    e, a = ego_track[both], adv_track[both]
    gaps = box_gap(
        box_corners(e[:, X], e[:, Y], e[:, HEADING], e[:, LENGTH], e[:, WIDTH]),
        box_corners(a[:, X], a[:, Y], a[:, HEADING], a[:, LENGTH], a[:, WIDTH]),
    )
    return float(np.min(gaps))


def episode_metrics(
    scenario: Scenario, rollout: Rollout, generation_times_s: Sequence[float] = (),
    logged: LoggedAdversary | None = None,
) -> dict[str, Any]:
    """The metric columns of a results-store episode row for the scored ``rollout`` of ``scenario``."""
    window = slice(CURRENT_STEP, rollout.last_step + 1)
    ego = rollout.ego_track[window].astype(np.float64)
    adv = rollout.adv_track[window].astype(np.float64)
    logged = logged or LoggedAdversary.of(scenario)
    adv_offroad = offroad_flags(scenario, adv)
    coll = collision_metrics([ego], [adv])
    adv_collision = any(other == rollout.adv_id for _, other in rollout.ego_crashes)
    gap = min_body_gap(ego, adv)
    realism = realism_wd([adv], [logged.track], [adv_offroad], [logged.offroad])
    times_ms = 1e3 * np.asarray(generation_times_s, dtype=np.float64)
    return {
        "outcome": rollout.outcome,
        "success": rollout.outcome == Outcome.SUCCESS,
        "crash": rollout.outcome == Outcome.CRASH,
        "out_of_road": rollout.outcome == Outcome.OUT_OF_ROAD,
        "timeout": rollout.outcome == Outcome.TIMEOUT,
        "route_completion": float(rollout.route_completion),
        "episode_return": float(rollout.episode_return),
        "adv_collision": adv_collision,
        "min_gap_m": gap,
        "close_call": adv_collision or (gap is not None and gap <= CLOSE_CALL_M),
        "collision_speed_mps": coll["collision_speed_mps"],  # NaN (stored NULL) without a contact
        "head_on": coll["head_on_rate"] > 0,
        "severe_head_on": coll["severe_head_on_rate"] > 0,
        **realism,
        "adv_offroad_share": float(adv_offroad.mean()) if adv_offroad.size else 0.0,
        "log_offroad_share": float(logged.offroad.mean()) if logged.offroad.size else 0.0,
        "adv_yaw_hist": histogram_counts(yaw_rates([adv]), YAW_RATE_BINS).tolist(),
        "adv_acc_hist": histogram_counts(accelerations([adv]), ACC_BINS).tolist(),
        "log_yaw_hist": histogram_counts(yaw_rates([logged.track]), YAW_RATE_BINS).tolist(),
        "log_acc_hist": histogram_counts(accelerations([logged.track]), ACC_BINS).tolist(),
        "generations": int(times_ms.size),
        "generation_ms_mean": float(times_ms.mean()) if times_ms.size else None,
        "generation_ms_max": float(times_ms.max()) if times_ms.size else None,
    }
