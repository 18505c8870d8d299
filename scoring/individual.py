"""Individual (single-agent) SafeShift features and the individual score (thesis eq. 3.1, SafeShift code).

Per agent, over its valid steps (max over time unless noted):

* ``speed`` (m/s);
* ``speed_over_limit`` (m/s): speed minus the assigned lane's limit, over in-lane steps only (0 if never in lane);
* ``acc`` (m/s^2): norm of the acceleration vector (central differences of the velocity, one-sided at the ends);
  the SafeShift code combines per-axis maxima, the norm of the vector is the rotation-invariant version;
* ``jerk`` (m/s^3): norm of the derivative of the acceleration vector, same differences;
* ``waiting`` (s): total time of the steps moving less than 0.5 m (sum of all waiting intervals);
* ``in_lane``: mean over valid steps of being within half a lane width of the assigned lane's centre line;
* ``anomaly``: distance to the clustered motion primitives (`seal.scoring.primitives`).
"""

from __future__ import annotations

import numpy as np

from seal.core.scenario import DT_S
from seal.scoring.tracks import AgentTracks

WAIT_STEP_M = 0.5
INDIVIDUAL_FEATURES = ("speed", "speed_over_limit", "acc", "jerk", "waiting", "in_lane", "anomaly")


def finite_difference(values: np.ndarray, valid: np.ndarray, dt: float = DT_S) -> tuple[np.ndarray, np.ndarray]:
    """Time derivative of ``values [A, T, ...]`` over valid steps: central inside a valid block, one-sided at its
    ends. Returns the derivative (0 where undefined) and its validity ``[A, T]`` (needs 2 valid steps)."""
    fwd_ok = np.zeros_like(valid)
    fwd_ok[:, :-1] = valid[:, :-1] & valid[:, 1:]
    bwd_ok = np.zeros_like(valid)
    bwd_ok[:, 1:] = fwd_ok[:, :-1]
    diff = np.zeros_like(values)
    diff[:, :-1] = (values[:, 1:] - values[:, :-1]) / dt
    fwd = diff
    bwd = np.zeros_like(values)
    bwd[:, 1:] = diff[:, :-1]
    extra = (1,) * (values.ndim - 2)
    f, b = fwd_ok.reshape(fwd_ok.shape + extra), bwd_ok.reshape(bwd_ok.shape + extra)
    out = np.where(f & b, 0.5 * (fwd + bwd), np.where(f, fwd, np.where(b, bwd, 0.0)))
    return out, fwd_ok | bwd_ok


def _masked_max(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    return np.where(mask, values, -np.inf).max(axis=1, initial=-np.inf)


def individual_features(tr: AgentTracks, anomaly: np.ndarray | None = None, dt: float = DT_S) -> dict[str, np.ndarray]:
    """Features ``[A]`` named `INDIVIDUAL_FEATURES` (see the module docstring)."""
    valid = tr.valid
    speed = tr.speed
    acc_vec, acc_ok = finite_difference(tr.vel, valid, dt)
    jerk_vec, jerk_ok = finite_difference(acc_vec, acc_ok, dt)
    acc = np.linalg.norm(acc_vec, axis=-1)
    jerk = np.linalg.norm(jerk_vec, axis=-1)
    over = np.where(np.isfinite(tr.speed_limit), speed - tr.speed_limit, -np.inf)
    over_max = _masked_max(over, valid & tr.in_lane)
    step = np.linalg.norm(np.diff(tr.pos, axis=1), axis=-1)
    both = valid[:, 1:] & valid[:, :-1]
    n_valid = valid.sum(1)
    return {
        "speed": np.maximum(_masked_max(speed, valid), 0.0),
        "speed_over_limit": np.where(np.isfinite(over_max), over_max, 0.0),
        "acc": np.maximum(_masked_max(acc, acc_ok), 0.0),
        "jerk": np.maximum(_masked_max(jerk, jerk_ok), 0.0),
        "waiting": ((step < WAIT_STEP_M) & both).sum(1) * dt,
        "in_lane": np.where(n_valid > 0, (tr.in_lane & valid).sum(1) / np.maximum(n_valid, 1), 0.0),
        "anomaly": np.zeros(tr.n_agents) if anomaly is None else np.asarray(anomaly, dtype=np.float64),
    }


def individual_score(f: dict[str, np.ndarray]) -> np.ndarray:
    """``[A]`` individual score, weights of the SafeShift code (Table III of the "automated analysis" framework)."""
    return (
        np.minimum(10.0, np.maximum(0.0, f["speed_over_limit"]))
        + np.minimum(10.0, 0.1 * f["acc"])
        + np.minimum(10.0, 0.01 * f["jerk"])
        + np.minimum(10.0, 0.1 * f["speed"])
        + np.minimum(5.0, f["anomaly"])
        + np.minimum(7.75, np.sqrt(f["waiting"]))
        + (1.0 - f["in_lane"])
    )
