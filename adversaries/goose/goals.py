"""GOOSE goals: what a roll-out achieved (closest ego-adversary approach, the adversary's largest |acceleration| and
|yaw rate|), whether a desired goal is reached, and the goal-conditioned reward (vectorised, for HER relabelling).

Goal vectors are ``[..., 3]`` in the order of `seal.adversaries.goose.spec.GOAL_NAMES` and in physical units
(m, m/s^2, rad/s). A desired goal ``(g, a, w)`` is reached when ``gap <= g``, ``|acc| <= a`` and
``|yaw rate| <= w``: at least this close, at most this harsh.
"""

from __future__ import annotations

import numpy as np

from seal.core.geometry import box_corners, box_gap, wrap_angle
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, LENGTH, VALID, VX, VY, WIDTH, X, Y
from seal.envs.rollout import Rollout

MAX_GAP_M = 50.0
"""Achieved gaps are capped here (and a roll-out where the pair is never present together gets it)."""
GOAL_SCALES = np.array([10.0, 8.0, 0.7], dtype=np.float32)
"""Normalisation of the goal components (m, m/s^2, rad/s) for rewards and network inputs."""
MAX_TERM = 5.0
"""Each normalised violation term of the dense reward is capped here."""


def pair_gaps(rollout: Rollout) -> np.ndarray:
    """``[T]`` ego-adversary body gap (m) at scenario steps ``CURRENT_STEP + 1 .. last_step``; NaN where either is
    absent."""
    rows = slice(CURRENT_STEP + 1, rollout.last_step + 1)
    e, a = rollout.ego_track[rows].astype(np.float64), rollout.adv_track[rows].astype(np.float64)
    both = (e[:, VALID] > 0.5) & (a[:, VALID] > 0.5)

    def corners(t: np.ndarray) -> np.ndarray:
        return box_corners(t[:, X], t[:, Y], t[:, HEADING], t[:, LENGTH], t[:, WIDTH])

    return np.where(both, box_gap(corners(e), corners(a)), np.nan)


def adversary_kinematics(track: np.ndarray, last_step: int) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration (m/s^2, change of speed) and yaw rate (rad/s) between consecutive valid rows of a ``[T, 8]``
    track over scenario steps ``CURRENT_STEP .. last_step`` (the step into the episode included)."""
    t = np.asarray(track, dtype=np.float64)[CURRENT_STEP : last_step + 1]
    ok = (t[1:, VALID] > 0.5) & (t[:-1, VALID] > 0.5)
    acc = np.diff(np.hypot(t[:, VX], t[:, VY])) / DT_S
    yaw = wrap_angle(np.diff(t[:, HEADING])) / DT_S
    return acc[ok], yaw[ok]


def achieved_goal(rollout: Rollout) -> np.ndarray:
    """``[3]`` float32: min body gap (0 if the ego crashed into the adversary, capped at `MAX_GAP_M`), the
    adversary's max |acc| and max |yaw rate| over the executed steps."""
    gaps = pair_gaps(rollout)
    gap = float(np.nanmin(gaps)) if np.isfinite(gaps).any() else MAX_GAP_M
    if any(other == rollout.adv_id for _, other in rollout.ego_crashes):
        gap = 0.0
    acc, yaw = adversary_kinematics(rollout.adv_track, rollout.last_step)
    max_acc = float(np.abs(acc).max()) if acc.size else 0.0
    max_yaw = float(np.abs(yaw).max()) if yaw.size else 0.0
    return np.array([min(gap, MAX_GAP_M), max_acc, max_yaw], dtype=np.float32)


def goal_violation(achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """``[..., 3]`` normalised violations ``max(0, achieved - desired) / GOAL_SCALES``, each capped at
    `MAX_TERM` (0 = that component is met)."""
    over = np.asarray(achieved, dtype=np.float64) - np.asarray(desired, dtype=np.float64)
    return np.minimum(np.maximum(over, 0.0) / GOAL_SCALES, MAX_TERM)


def goal_reached(achieved: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """bool ``[...]``: every component of ``achieved`` is at most the desired one."""
    return np.all(np.asarray(achieved, dtype=np.float64) <= np.asarray(desired, dtype=np.float64) + 1e-6, axis=-1)


def goal_reward(achieved: np.ndarray, desired: np.ndarray, kind: str = "dense") -> np.ndarray:
    """Reward ``[...]`` float32: ``"dense"`` = minus the summed violation (0 when reached), ``"sparse"`` = 0 when
    reached else -1."""
    reached = goal_reached(achieved, desired)
    if kind == "sparse":
        return np.where(reached, 0.0, -1.0).astype(np.float32)
    if kind != "dense":
        raise ValueError(f"reward kind must be 'dense' or 'sparse', got {kind!r}")
    return np.where(reached, 0.0, -goal_violation(achieved, desired).sum(axis=-1)).astype(np.float32)
