"""Behavioural labels of 8 s futures (logged or predicted), in world coordinates at 10 Hz.

All functions take futures ``xy [..., T, 2]`` (m; step ``j`` is 0.1 s after step ``j - 1``, the point before
step 0 is ``start [..., 2]``). Kinematics are read from 0.5 s samples (`SAMPLE_STEPS`) so finite differences of
positions do not turn centimetre noise into accelerations.

* `activity_risk` (paper 000, eq. 1): ``0.35 min(v_max / V, 1) + 0.35 min(a_max / A, 1) + 0.30 min(w_max / W, 1)``
  in [0, 1]; the paper's pedestrian constants are replaced by vehicle ones (`RiskConfig`).
* `proximity_risk` (scene-aware): ``exp(-d_min / D)`` where ``d_min`` is the smallest centre distance to a
  reference track (the ego's logged future) over the steps where it is valid.
* `motion_classes` (paper 002, appendix A.3): speed (low < 25 km/h <= moderate <= 50 km/h < high), acceleration
  (path length over ``v0 * T``: < 0.9 decelerating, > 1.1 accelerating, else constant), direction (stationary,
  left, straight, right by the net heading change, 15 deg) and lane change (none, left, right: lateral offset
  in the start frame beyond `LANE_CHANGE_M` while the heading changes by less than 15 deg).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.core.geometry import wrap_angle
from seal.core.scenario import DT_S

SAMPLE_STEPS = 5
"""Kinematics from every 5th step (0.5 s)."""
LOW_SPEED_MPS = 25.0 / 3.6
HIGH_SPEED_MPS = 50.0 / 3.6
ACCEL_RATIO = (0.9, 1.1)
TURN_RAD = np.deg2rad(15.0)
STATIONARY_M = 2.0
"""A future shorter than this (m) is stationary: its direction is meaningless."""
LANE_CHANGE_M = 2.5
"""Lateral offset (m, start frame) that makes a straight future a lane change (about 2/3 of a lane)."""
YAW_MIN_SPEED_MPS = 1.0

SPEED_CLASSES = ("low", "moderate", "high")
ACCEL_CLASSES = ("decelerating", "constant", "accelerating")
DIRECTION_CLASSES = ("stationary", "left", "straight", "right")
LANE_CHANGE_CLASSES = ("none", "left", "right")
CLASS_NAMES: dict[str, tuple[str, ...]] = {
    "speed": SPEED_CLASSES, "acceleration": ACCEL_CLASSES, "direction": DIRECTION_CLASSES,
    "lane_change": LANE_CHANGE_CLASSES,
}


@dataclass(frozen=True)
class RiskConfig:
    """Normalisers of the activity risk (paper 000 eq. 1, vehicle values).

    Attributes:
        speed_mps: speed that saturates the speed term (30 m/s = 108 km/h).
        acc_mps2: |acceleration| that saturates the acceleration term (4 m/s^2, hard braking).
        yaw_rate_rps: |yaw rate| that saturates the turn term (0.5 rad/s, a tight urban turn).
        proximity_m: length scale ``D`` of the proximity risk ``exp(-d_min / D)`` (m).
    """

    speed_mps: float = 30.0
    acc_mps2: float = 4.0
    yaw_rate_rps: float = 0.5
    proximity_m: float = 10.0


def sampled(xy: np.ndarray, start: np.ndarray) -> np.ndarray:
    """``[..., S + 1, 2]``: ``start`` then every `SAMPLE_STEPS`-th point of ``xy`` (the 0.5 s samples)."""
    xy = np.asarray(xy, dtype=np.float64)
    start = np.broadcast_to(np.asarray(start, dtype=np.float64), (*xy.shape[:-2], 2))
    return np.concatenate([start[..., None, :], xy[..., SAMPLE_STEPS - 1 :: SAMPLE_STEPS, :]], axis=-2)


def kinematics(xy: np.ndarray, start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Speed ``[..., S]`` (m/s), |acceleration| ``[..., S - 1]`` (m/s^2) and |yaw rate| ``[..., S - 1]`` (rad/s,
    0 where either sample is slower than 1 m/s) from the 0.5 s samples."""
    pts = sampled(xy, start)
    dt = SAMPLE_STEPS * DT_S
    delta = np.diff(pts, axis=-2)
    speed = np.linalg.norm(delta, axis=-1) / dt
    heading = np.arctan2(delta[..., 1], delta[..., 0])
    acc = np.abs(np.diff(speed, axis=-1)) / dt
    fast = (speed[..., 1:] > YAW_MIN_SPEED_MPS) & (speed[..., :-1] > YAW_MIN_SPEED_MPS)
    yaw = np.where(fast, np.abs(wrap_angle(np.diff(heading, axis=-1))) / dt, 0.0)
    return speed, acc, yaw


def activity_risk(xy: np.ndarray, start: np.ndarray, cfg: RiskConfig | None = None) -> np.ndarray:
    """Paper 000's kinematic activity score ``[...]`` in [0, 1] (module docstring)."""
    cfg = cfg or RiskConfig()
    speed, acc, yaw = kinematics(xy, start)
    return (0.35 * np.minimum(speed.max(-1) / cfg.speed_mps, 1.0)
            + 0.35 * np.minimum(acc.max(-1, initial=0.0) / cfg.acc_mps2, 1.0)
            + 0.30 * np.minimum(yaw.max(-1, initial=0.0) / cfg.yaw_rate_rps, 1.0))


def min_distance(xy: np.ndarray, ref_xy: np.ndarray, ref_valid: np.ndarray) -> np.ndarray:
    """Smallest centre distance ``[...]`` (m) between futures ``[..., T, 2]`` and a reference ``[T, 2]`` over the
    steps where ``ref_valid [T]``; inf when the reference is never valid."""
    d = np.linalg.norm(np.asarray(xy, dtype=np.float64) - np.asarray(ref_xy, dtype=np.float64), axis=-1)
    return np.where(np.asarray(ref_valid, dtype=bool), d, np.inf).min(-1)


def proximity_risk(xy: np.ndarray, ref_xy: np.ndarray, ref_valid: np.ndarray,
                   cfg: RiskConfig | None = None) -> np.ndarray:
    """``exp(-d_min / D)`` ``[...]`` in [0, 1]: 1 when the future passes through the reference's centre."""
    cfg = cfg or RiskConfig()
    return np.exp(-min_distance(xy, ref_xy, ref_valid) / cfg.proximity_m)


def mean_speed(xy: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Mean speed ``[...]`` (m/s): path length over the horizon."""
    pts = np.concatenate([np.broadcast_to(np.asarray(start, np.float64), (*np.shape(xy)[:-2], 2))[..., None, :],
                          np.asarray(xy, np.float64)], axis=-2)
    path = np.linalg.norm(np.diff(pts, axis=-2), axis=-1).sum(-1)
    return path / (np.shape(xy)[-2] * DT_S)


def motion_classes(xy: np.ndarray, start: np.ndarray, start_speed_mps: np.ndarray,
                   start_heading: np.ndarray) -> dict[str, np.ndarray]:
    """Paper 002's quantised motion classes of futures ``[..., T, 2]``: ``{name: int array [...]}``, indices into
    `CLASS_NAMES` (module docstring). ``start_speed_mps`` and ``start_heading`` (rad) are ``[...]``."""
    xy = np.asarray(xy, dtype=np.float64)
    horizon_s = xy.shape[-2] * DT_S
    v = mean_speed(xy, start)
    speed = np.where(v < LOW_SPEED_MPS, 0, np.where(v <= HIGH_SPEED_MPS, 1, 2))
    path = v * horizon_s
    ratio = path / np.maximum(np.asarray(start_speed_mps, np.float64) * horizon_s, 1e-6)
    # A start from rest that moves is accelerating; one that stays put is constant.
    ratio = np.where(np.asarray(start_speed_mps) < 0.5, np.where(path > STATIONARY_M, 2.0, 1.0), ratio)
    accel = np.where(ratio < ACCEL_RATIO[0], 0, np.where(ratio > ACCEL_RATIO[1], 2, 1))
    pts = sampled(xy, start)
    delta = np.diff(pts, axis=-2)
    step = np.linalg.norm(delta, axis=-1)
    heading = np.arctan2(delta[..., 1], delta[..., 0])
    # Net heading change: last moving sample's direction against the start heading.
    moving = step > 0.05
    last = np.where(moving.any(-1), (moving.shape[-1] - 1) - np.argmax(moving[..., ::-1], axis=-1), 0)
    end_heading = np.where(moving.any(-1), np.take_along_axis(heading, last[..., None], -1)[..., 0], start_heading)
    turn = wrap_angle(end_heading - np.asarray(start_heading, np.float64))
    stationary = path < STATIONARY_M
    direction = np.where(stationary, 0, np.where(turn > TURN_RAD, 1, np.where(turn < -TURN_RAD, 3, 2)))
    end = xy[..., -1, :] - np.asarray(start, np.float64)
    lateral = -np.sin(start_heading) * end[..., 0] + np.cos(start_heading) * end[..., 1]
    straight = direction == 2
    lane = np.where(straight & (lateral > LANE_CHANGE_M), 1, np.where(straight & (lateral < -LANE_CHANGE_M), 2, 0))
    return {"speed": speed, "acceleration": accel, "direction": direction, "lane_change": lane}
