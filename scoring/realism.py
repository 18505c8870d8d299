"""Realism and collision metrics of generated adversaries (thesis 6.4.3, Table 6.2), on plain track arrays.

* Realism: Wasserstein-1 distances between normalised histograms ("profiles") of the generated adversary's yaw
  rate (rad/s), acceleration (m/s^2, time derivative of the speed) and out-of-road rate (share of an episode's
  steps off the road, or a 0/1 flag per episode) and those of the original (logged) adversary, on fixed bins;
  ``realism`` is their mean (lower = more realistic). Values outside the bin range count in the edge bins.
* Smoothness (reported next to realism, not in it): the jerk profile (m/s^3, second difference of the speed)
  against the logged adversary's, as a Wasserstein-1 distance and the 95th percentile of |jerk|.
* Direction (next to realism, not in it): mean acceleration and the share of hard-braking steps, generated and
  logged, so a large acc WD can be read as "brakes more" or "accelerates more".
* Collisions: for every episode the first step where the ego and adversary boxes overlap; the relative speed
  along the contact normal there (the separating axis of least penetration, as a physics engine's contact
  normal), head-on collisions (headings more than 135 deg apart and each vehicle's centre ahead of the other:
  front to front) and severe head-on collisions (head-on with a relative normal speed above 5 m/s). Rates are
  shares of all episodes; ``*_share`` are shares of the colliding episodes.

Tracks are ``[T, 8]`` arrays with `seal.core.scenario.TRACK_FIELDS` (one per episode, lengths may differ) or one
``[N, T, 8]`` array.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from seal.core.geometry import boxes_overlap, track_corners, wrap_angle
from seal.core.scenario import DT_S, HEADING, VALID, VX, VY, X, Y

YAW_RATE_BINS = np.linspace(-1.5, 1.5, 61)
ACC_BINS = np.linspace(-10.0, 10.0, 81)
JERK_BINS = np.linspace(-100.0, 100.0, 201)
OFFROAD_BINS = np.linspace(-0.05, 1.05, 12)  # centres 0.0, 0.1, ..., 1.0: a 0/1 flag sits exactly on 0 or 1
HARD_BRAKE_MPS2 = 3.0
"""Deceleration (m/s^2) above which a step counts as hard braking in `acceleration_stats`."""
HEAD_ON_ANGLE_RAD = np.deg2rad(135.0)
SEVERE_SPEED_MPS = 5.0

TrackBatch = np.ndarray | Sequence[np.ndarray]


def _episodes(tracks: TrackBatch) -> list[np.ndarray]:
    if isinstance(tracks, np.ndarray) and tracks.ndim == 2:
        return [tracks]
    return [np.asarray(t, dtype=np.float64) for t in tracks]


def yaw_rates(tracks: TrackBatch, dt: float = DT_S) -> np.ndarray:
    """All yaw rates (rad/s) between consecutive valid steps of all episodes, concatenated."""
    out = []
    for t in _episodes(tracks):
        ok = (t[1:, VALID] > 0.5) & (t[:-1, VALID] > 0.5)
        out.append((wrap_angle(np.diff(t[:, HEADING])) / dt)[ok])
    return np.concatenate(out) if out else np.zeros(0)


def accelerations(tracks: TrackBatch, dt: float = DT_S) -> np.ndarray:
    """All accelerations (m/s^2, change of speed per second) between consecutive valid steps, concatenated."""
    out = []
    for t in _episodes(tracks):
        ok = (t[1:, VALID] > 0.5) & (t[:-1, VALID] > 0.5)
        out.append((np.diff(np.hypot(t[:, VX], t[:, VY])) / dt)[ok])
    return np.concatenate(out) if out else np.zeros(0)


def jerks(tracks: TrackBatch, dt: float = DT_S) -> np.ndarray:
    """All jerks (m/s^3, change of `accelerations` per second) over three consecutive valid steps, concatenated."""
    out = []
    for t in _episodes(tracks):
        ok = (t[2:, VALID] > 0.5) & (t[1:-1, VALID] > 0.5) & (t[:-2, VALID] > 0.5)
        out.append((np.diff(np.hypot(t[:, VX], t[:, VY]), n=2) / dt**2)[ok])
    return np.concatenate(out) if out else np.zeros(0)


def jerk_stats(generated: TrackBatch, original: TrackBatch) -> dict[str, float]:
    """Smoothness of generated vs original adversaries (not part of ``realism``): ``jerk_wd`` (Wasserstein-1 of the
    jerk profiles on `JERK_BINS`), the 95th percentile of |jerk| of both (m/s^3)."""
    g, o = jerks(generated), jerks(original)
    p95 = lambda x: float(np.percentile(np.abs(x), 95)) if x.size else float("nan")  # noqa: E731
    return {"jerk_wd": histogram_wasserstein(g, o, JERK_BINS), "jerk_abs_p95": p95(g), "logged_jerk_abs_p95": p95(o)}


def acceleration_stats(generated: TrackBatch, original: TrackBatch) -> dict[str, float]:
    """Which way generated adversaries differ from the logged ones in acceleration (not part of ``realism``; the
    acc WD says how much, these say in which direction): the mean acceleration (m/s^2) of both and their shares of
    steps braking harder than `HARD_BRAKE_MPS2` (NaN for an empty sample)."""
    g, o = accelerations(generated), accelerations(original)
    mean = lambda x: float(x.mean()) if x.size else float("nan")  # noqa: E731
    hard = lambda x: float(np.mean(x < -HARD_BRAKE_MPS2)) if x.size else float("nan")  # noqa: E731
    return {"acc_mean_mps2": mean(g), "logged_acc_mean_mps2": mean(o), "hard_brake_share": hard(g),
            "logged_hard_brake_share": hard(o)}


def offroad_rates(offroad: np.ndarray | Sequence[np.ndarray]) -> np.ndarray:
    """Per-episode out-of-road rate: a 0/1 flag per episode ``[N]`` as is, per-step flags ``[N, T]`` (or a list
    of ``[T]``) as the share of steps off the road."""
    if isinstance(offroad, np.ndarray) and offroad.ndim == 1:
        return offroad.astype(np.float64)
    return np.array([np.mean(np.asarray(f, dtype=np.float64)) if np.size(f) else 0.0 for f in offroad])


def histogram_wasserstein(a: np.ndarray, b: np.ndarray, bins: np.ndarray) -> float:
    """Wasserstein-1 distance between the normalised histograms of samples ``a`` and ``b`` on ``bins`` (edges):
    the histograms are point masses at the bin centres; W1 = sum over bins of |CDF_a - CDF_b| x bin width.
    NaN if either sample is empty."""
    a, b = np.asarray(a, dtype=np.float64).ravel(), np.asarray(b, dtype=np.float64).ravel()
    if a.size == 0 or b.size == 0:
        return float("nan")
    lo, hi = bins[0], bins[-1]
    # Clip into the outer bins so out-of-range values count at the edges instead of vanishing.
    eps = 1e-9 * (hi - lo)
    ha, _ = np.histogram(np.clip(a, lo + eps, hi - eps), bins=bins)
    hb, _ = np.histogram(np.clip(b, lo + eps, hi - eps), bins=bins)
    cdf_gap = np.cumsum(ha / ha.sum() - hb / hb.sum())[:-1]
    centres = 0.5 * (bins[1:] + bins[:-1])
    return float(np.sum(np.abs(cdf_gap) * np.diff(centres)))


def realism_wd(
    generated: TrackBatch, original: TrackBatch, generated_offroad: np.ndarray | Sequence[np.ndarray],
    original_offroad: np.ndarray | Sequence[np.ndarray],
) -> dict[str, float]:
    """``yaw_wd``, ``acc_wd``, ``road_wd`` and their mean ``realism`` for generated vs original adversaries."""
    yaw = histogram_wasserstein(yaw_rates(generated), yaw_rates(original), YAW_RATE_BINS)
    acc = histogram_wasserstein(accelerations(generated), accelerations(original), ACC_BINS)
    road = histogram_wasserstein(offroad_rates(generated_offroad), offroad_rates(original_offroad), OFFROAD_BINS)
    return {"yaw_wd": yaw, "acc_wd": acc, "road_wd": road, "realism": float(np.nanmean([yaw, acc, road]))}


# ------------------------------------------------------------------------------------------------ collisions
def contact_normal(corners_a: np.ndarray, corners_b: np.ndarray) -> np.ndarray:
    """Unit contact normal ``[..., 2]`` of overlapping boxes ``[..., 4, 2]``: the box edge normal with the least
    penetration depth, pointing from a to b."""
    a, b = np.broadcast_arrays(np.asarray(corners_a, dtype=np.float64), np.asarray(corners_b, dtype=np.float64))
    axes = np.concatenate([a[..., 1:3, :] - a[..., 0:2, :], b[..., 1:3, :] - b[..., 0:2, :]], axis=-2)
    axes = axes / np.maximum(np.linalg.norm(axes, axis=-1, keepdims=True), 1e-12)  # [..., 4, 2]
    pa = np.einsum("...kd,...cd->...kc", axes, a)
    pb = np.einsum("...kd,...cd->...kc", axes, b)
    overlap = np.minimum(pa.max(-1), pb.max(-1)) - np.maximum(pa.min(-1), pb.min(-1))  # [..., 4]
    k = np.argmin(overlap, axis=-1)
    n = np.take_along_axis(axes, k[..., None, None], axis=-2)[..., 0, :]
    towards_b = ((b.mean(-2) - a.mean(-2)) * n).sum(-1)
    return np.where((towards_b < 0)[..., None], -n, n)


def first_collision_step(ego: np.ndarray, adv: np.ndarray) -> int:
    """First step (index) where the two ``[T, 8]`` tracks' boxes overlap while both are valid, -1 if none."""
    both = (ego[:, VALID] > 0.5) & (adv[:, VALID] > 0.5)
    hit = boxes_overlap(track_corners(ego), track_corners(adv)) & both
    return int(np.argmax(hit)) if hit.any() else -1


def collision_metrics(ego: TrackBatch, adv: TrackBatch) -> dict[str, float]:
    """Collision rate, mean relative speed along the contact normal (m/s, colliding episodes), head-on and
    severe head-on rates (of all episodes) and shares (of colliding episodes) for paired ego / adversary tracks."""
    egos, advs = _episodes(ego), _episodes(adv)
    if len(egos) != len(advs):
        raise ValueError(f"got {len(egos)} ego tracks but {len(advs)} adversary tracks")
    speeds, head_on = [], []
    for e, a in zip(egos, advs, strict=True):
        k = first_collision_step(e, a)
        if k < 0:
            continue
        n = contact_normal(track_corners(e[k]), track_corners(a[k]))
        rel_v = np.array([a[k, VX] - e[k, VX], a[k, VY] - e[k, VY]])
        speeds.append(abs(float(rel_v @ n)))
        opposite = abs(float(wrap_angle(a[k, HEADING] - e[k, HEADING]))) > HEAD_ON_ANGLE_RAD
        d = np.array([a[k, X] - e[k, X], a[k, Y] - e[k, Y]])
        adv_ahead = d @ [np.cos(e[k, HEADING]), np.sin(e[k, HEADING])] > 0
        ego_ahead = -d @ [np.cos(a[k, HEADING]), np.sin(a[k, HEADING])] > 0
        head_on.append(bool(opposite and adv_ahead and ego_ahead))
    n_ep, n_coll = len(egos), len(speeds)
    sev = [h and s > SEVERE_SPEED_MPS for h, s in zip(head_on, speeds, strict=True)]
    return {
        "episodes": n_ep,
        "collisions": n_coll,
        "collision_rate": n_coll / n_ep if n_ep else float("nan"),
        "collision_speed_mps": float(np.mean(speeds)) if speeds else float("nan"),
        "head_on_rate": sum(head_on) / n_ep if n_ep else float("nan"),
        "severe_head_on_rate": sum(sev) / n_ep if n_ep else float("nan"),
        "head_on_share": sum(head_on) / n_coll if n_coll else float("nan"),
        "severe_head_on_share": sum(sev) / n_coll if n_coll else float("nan"),
    }
