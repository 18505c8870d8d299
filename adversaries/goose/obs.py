"""What the GOOSE agent observes: the last roll-out (a time series for the GRU), the curve state, and the
achieved / desired goals (the Dict layout SB3's HER buffer needs).

``observation`` = ``[n_time * N_ROLLOUT_FEATURES]`` roll-out features (row-major ``[n_time, F]``, the roll-out
sampled every ``obs_stride`` steps after the current step) followed by the curve state
(`GooseCurve.features`, 22), the closest approach (`CLOSEST_FEATURES`, 7), with ``spec.obs_targets`` the ego
relative to each control point at its time (`TARGET_FEATURES`, 12) and the share of the update budget used (1);
``achieved_goal`` / ``desired_goal``
are ``[3]`` in physical units (see `seal.adversaries.goose.goals`).
"""

from __future__ import annotations

import math

import numpy as np
from gymnasium import spaces

from seal.adversaries.goose.curve import N_CURVE_FEATURES, POS_SCALE_M, Frame, GooseCurve
from seal.adversaries.goose.goals import GOAL_SCALES, MAX_TERM, pair_gaps
from seal.adversaries.goose.nurbs import greville_abscissae
from seal.adversaries.goose.spec import GooseSpec
from seal.core.scenario import CURRENT_STEP, HEADING, VALID, VX, VY, X, Y
from seal.envs.rollout import Rollout

ROLLOUT_FEATURES = (
    "ego_x", "ego_y", "ego_cos_heading", "ego_sin_heading", "ego_speed", "adv_x", "adv_y", "adv_speed", "gap",
    "present",
)
"""Per-sample roll-out features, all in the adversary's initial frame: positions / `POS_SCALE_M`, speeds /
`SPEED_SCALE_MPS`, body gap / `GOAL_SCALES[0]` (capped at `MAX_TERM`), 1 where both are present (else the whole
row is 0)."""
N_ROLLOUT_FEATURES = len(ROLLOUT_FEATURES)
SPEED_SCALE_MPS = 20.0


def rollout_features(rollout: Rollout, frame: Frame, spec: GooseSpec) -> np.ndarray:
    """``[spec.n_time, N_ROLLOUT_FEATURES]`` float32 (see `ROLLOUT_FEATURES`)."""
    steps = CURRENT_STEP + spec.obs_stride * np.arange(1, spec.n_time + 1)
    out = np.zeros((spec.n_time, N_ROLLOUT_FEATURES), dtype=np.float32)
    n_cols = rollout.tracks.shape[1]
    inside = (steps <= rollout.last_step) & (steps < n_cols)
    if not inside.any():
        return out
    k = steps[inside]
    e = rollout.ego_track[k].astype(np.float64)
    a = rollout.adv_track[k].astype(np.float64)
    present = (e[:, VALID] > 0.5) & (a[:, VALID] > 0.5)
    gaps = pair_gaps(rollout)[k - CURRENT_STEP - 1]
    h = e[:, HEADING] - frame.h0
    rows = np.column_stack([
        frame.to_local(e[:, [X, Y]]) / POS_SCALE_M,
        np.cos(h), np.sin(h),
        np.hypot(e[:, VX], e[:, VY]) / SPEED_SCALE_MPS,
        frame.to_local(a[:, [X, Y]]) / POS_SCALE_M,
        np.hypot(a[:, VX], a[:, VY]) / SPEED_SCALE_MPS,
        np.minimum(np.nan_to_num(gaps, nan=math.inf) / GOAL_SCALES[0], MAX_TERM),
        np.ones(len(k)),
    ])
    out[np.flatnonzero(inside)] = np.where(present[:, None], rows, 0.0)
    return out


CLOSEST_FEATURES = ("time", "ego_x", "ego_y", "adv_x", "adv_y", "ego_speed", "adv_speed")
"""The closest approach of the last roll-out (exact step, unlike the sampled series): its time after the current
step / `obs_horizon`, positions (frame) / `POS_SCALE_M`, speeds / `SPEED_SCALE_MPS`; all 0 if the pair is never
present together."""
N_CLOSEST_FEATURES = len(CLOSEST_FEATURES)


def closest_approach_features(rollout: Rollout, frame: Frame, spec: GooseSpec) -> np.ndarray:
    """``[N_CLOSEST_FEATURES]`` float32 (see `CLOSEST_FEATURES`)."""
    gaps = pair_gaps(rollout)
    if not np.isfinite(gaps).any():
        return np.zeros(N_CLOSEST_FEATURES, dtype=np.float32)
    i = int(np.nanargmin(gaps))
    k = CURRENT_STEP + 1 + i
    e, a = rollout.ego_track[k].astype(np.float64), rollout.adv_track[k].astype(np.float64)
    return np.concatenate([
        [(i + 1) / spec.obs_horizon],
        frame.to_local(e[[X, Y]]) / POS_SCALE_M,
        frame.to_local(a[[X, Y]]) / POS_SCALE_M,
        [np.hypot(e[VX], e[VY]) / SPEED_SCALE_MPS, np.hypot(a[VX], a[VY]) / SPEED_SCALE_MPS],
    ]).astype(np.float32)


TARGET_FEATURES = ("dx", "dy", "present")
"""Per control point 1..4 (`GooseSpec.obs_targets`): where the ego was in the last roll-out at the time the point
stands for (its Greville abscissa times the logged duration), relative to the point (frame, / `POS_SCALE_M`), and 1
if the ego was present then (else all 0). On a timed curve (``timing="curve"``) moving a point by this offset puts
the adversary where the ego was at that time: the edit that aims at the ego, given directly rather than left for
the networks to work out from two coordinate lists."""
N_TARGET_FEATURES = 4 * len(TARGET_FEATURES)


def target_features(rollout: Rollout, curve: GooseCurve) -> np.ndarray:
    """``[N_TARGET_FEATURES]`` float32 (see `TARGET_FEATURES`)."""
    out = np.zeros((4, len(TARGET_FEATURES)), dtype=np.float32)
    steps = CURRENT_STEP + np.rint(greville_abscissae(len(curve.ctrl))[1:] * curve.n_future).astype(int)
    for i, k in enumerate(np.minimum(steps, rollout.last_step)):
        e = rollout.ego_track[k].astype(np.float64)
        if k > CURRENT_STEP and e[VALID] > 0.5:
            out[i, :2] = (curve.frame.to_local(e[[X, Y]]) - curve.ctrl[i + 1]) / POS_SCALE_M
            out[i, 2] = 1.0
    return out.ravel()


def observation_size(spec: GooseSpec) -> int:
    targets = N_TARGET_FEATURES if spec.obs_targets else 0
    return spec.n_time * N_ROLLOUT_FEATURES + N_CURVE_FEATURES + N_CLOSEST_FEATURES + targets + 1


def observation_space(spec: GooseSpec) -> spaces.Dict:
    goal = spaces.Box(-np.inf, np.inf, shape=(3,), dtype=np.float32)
    return spaces.Dict({
        "observation": spaces.Box(-np.inf, np.inf, shape=(observation_size(spec),), dtype=np.float32),
        "achieved_goal": goal,
        "desired_goal": goal,
    })


def build_observation(
    spec: GooseSpec, curve: GooseCurve, rollout: Rollout, n_updates: int, achieved: np.ndarray,
    desired: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The Dict observation after ``n_updates`` curve updates, ``rollout`` being the last observed roll-out and
    ``achieved`` its achieved goal; ``desired`` defaults to the spec's goal."""
    obs = np.concatenate([
        rollout_features(rollout, curve.frame, spec).ravel(),
        curve.features(spec),
        closest_approach_features(rollout, curve.frame, spec),
        target_features(rollout, curve) if spec.obs_targets else np.zeros(0, dtype=np.float32),
        np.array([n_updates / spec.max_updates], dtype=np.float32),
    ]).astype(np.float32)
    return {
        "observation": obs,
        "achieved_goal": np.asarray(achieved, dtype=np.float32).copy(),
        "desired_goal": (spec.goal_array if desired is None else np.asarray(desired, dtype=np.float32)).copy(),
    }
