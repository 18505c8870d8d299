"""Hand-built roads and scenarios for the scoring tests (plain `seal` data, no simulator)."""

from __future__ import annotations

import numpy as np

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import DT_S, N_STEPS, Scenario

LENGTH_M, WIDTH_M = 4.5, 2.0


def straight_road(x0: float = -100.0, x1: float = 500.0, y: float = 0.0, limit: float = 30.0) -> RoadDescription:
    """One straight lane along +x at height ``y``, 4 m wide."""
    lane = LaneSpec("a:b:0", np.array([[x0, y], [x1, y]]), 4.0, ("continuous", "continuous"), limit)
    return RoadDescription("polylines", (lane,))


def cross_road() -> RoadDescription:
    """Two unconnected straight lanes crossing at the origin: along +x and along +y."""
    ew = LaneSpec("w:e:0", np.array([[-200.0, 0.0], [200.0, 0.0]]), 4.0, ("continuous", "continuous"), 30.0)
    sn = LaneSpec("s:n:0", np.array([[0.0, -200.0], [0.0, 200.0]]), 4.0, ("continuous", "continuous"), 30.0)
    return RoadDescription("polylines", (ew, sn))


def track(
    xy: np.ndarray, valid: np.ndarray | None = None, length: float = LENGTH_M, vel: np.ndarray | None = None,
    width: float = WIDTH_M,
) -> np.ndarray:
    """``[T, 8]`` track from positions ``[T, 2]``: velocity (unless given) and heading from finite differences."""
    xy = np.asarray(xy, dtype=np.float64)
    vel = np.gradient(xy, DT_S, axis=0) if vel is None else np.asarray(vel, dtype=np.float64)
    heading = np.arctan2(vel[:, 1], vel[:, 0])
    valid = np.ones(xy.shape[0], dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    out = np.zeros((xy.shape[0], 8), dtype=np.float32)
    out[:, 0:2] = xy
    out[:, 2] = heading
    out[:, 3:5] = vel
    out[:, 5] = length
    out[:, 6] = width
    out[:, 7] = valid
    out[~valid] = 0.0
    return out


def straight_track(x0: float, speed: float, y: float = 0.0) -> np.ndarray:
    """Constant speed along +x starting at ``x0`` (m) at step 0."""
    t = np.arange(N_STEPS) * DT_S
    return track(np.stack([x0 + speed * t, np.full(N_STEPS, y)], axis=1))


def scenario(tracks: list[np.ndarray], road: RoadDescription, sid: str = "s0", ego: int = 0, adv: int = 1) -> Scenario:
    arr = np.stack(tracks)
    return Scenario(sid, arr, np.arange(arr.shape[0]), ("vehicle",) * arr.shape[0], ego, adv, road, source="test")


def following_scenario(sid: str, gap_m: float, v_follow: float, v_lead: float, n_extra: int = 2) -> Scenario:
    """Ego follows the adversary in one lane (centre distance ``gap_m`` at step 0) plus far-away extras."""
    tracks = [straight_track(0.0, v_follow), straight_track(gap_m, v_lead)]
    tracks += [straight_track(-90.0 - 5.0 * k, 0.5 * v_follow) for k in range(n_extra)]
    return scenario(tracks, straight_road(), sid)
