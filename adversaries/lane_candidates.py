"""Map-based candidate futures without a learned model: follow the lanes (and their successors) near the agent at a
few constant accelerations, staying in the current lane or changing into a neighbouring one.

This is a heuristic stand-in for the trajectory prior pi_gen (``candidates: lanes`` in configs, ``--candidates
lanes`` on the command line): useful before a prior is trained, on imported maps, and as a baseline. Its
"probabilities" are a hand-set preference (gentle accelerations, keeping the lane, likely branches), not learned.

Per start lane (aligned with the agent's heading, within 1.5 lane widths): every successor chain long enough for
8 s, times every acceleration in ``accelerations_mps2`` (speed clipped to ``[0, max(v0, 1.2 x limit)]``). The
agent's lateral offset from the lane fades out over ``max(20 m, 3 s x v0)`` (a lane change for a neighbouring
lane). With no lane nearby: constant turn rate and acceleration.
"""

from __future__ import annotations

import math

import numpy as np

from seal.core.geometry import wrap_angle_f
from seal.core.road import RoadDescription
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, N_FUTURE, VX, VY, Scenario, X, Y
from seal.models.prior.candidates import Candidates

ACCELERATIONS_MPS2 = (-4.0, -2.0, -1.0, 0.0, 1.0, 2.0, 3.0)
YAW_RATES_RADPS = (-0.2, -0.1, 0.0, 0.1, 0.2)
MAX_HEADING_GAP_RAD = math.radians(50.0)
LANE_CHANGE_PENALTY = 1.0
ACCEL_SCALE_MPS2 = 1.5
_MAX_CHAINS = 4


class _LaneTable:
    """Centre lines with cumulative arc lengths and successor indices of one road."""

    def __init__(self, road: RoadDescription) -> None:
        self.road = road  # keeps the road alive so its id() is not reused while cached
        self.lines = [lane.centerline for lane in road.lanes]
        self.cum = [np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(c, axis=0).T))]) for c in self.lines]
        index = {lane.lane_id: i for i, lane in enumerate(road.lanes)}
        self.succ = [[index[s] for s in lane.successors] for lane in road.lanes]
        self.width = np.array([lane.width_m for lane in road.lanes])
        self.limit = np.array([lane.speed_limit_mps for lane in road.lanes])


_TABLES: dict[int, _LaneTable] = {}


def _table(road: RoadDescription) -> _LaneTable:
    table = _TABLES.get(id(road))
    if table is None or table.road is not road:
        if len(_TABLES) > 256:
            _TABLES.clear()
        table = _TABLES[id(road)] = _LaneTable(road)
    return table


def _project(line: np.ndarray, cum: np.ndarray, p: np.ndarray) -> tuple[float, float, float, float]:
    """Arc length, signed lateral offset (left +), tangent heading and distance past the end of ``p`` on a line."""
    a, e = line[:-1], np.diff(line, axis=0)
    seg2 = np.maximum((e * e).sum(1), 1e-12)
    raw = ((p - a) * e).sum(1) / seg2
    u = np.clip(raw, 0.0, 1.0)
    d2 = ((a + u[:, None] * e - p) ** 2).sum(1)
    k = int(np.argmin(d2))
    seg = math.sqrt(seg2[k])
    tx, ty = e[k] / seg
    rel = p - a[k]
    lateral = float(tx * rel[1] - ty * rel[0])
    beyond = max(0.0, (raw[k] - 1.0) * seg) if k == len(e) - 1 else 0.0
    beyond = max(beyond, -raw[k] * seg) if k == 0 else beyond
    return float(cum[k] + u[k] * seg), lateral, math.atan2(ty, tx), beyond


def _chains(table: _LaneTable, start: int, need_m: float) -> list[tuple[list[int], float]]:
    """Successor chains from lane ``start`` covering ``need_m`` (or ending where the road ends), with their
    branch probability (1 / number of successors at every fork)."""
    out: list[tuple[list[int], float]] = []
    stack = [([start], 1.0, float(table.cum[start][-1]))]
    while stack and len(out) < _MAX_CHAINS:
        chain, prob, length = stack.pop()
        nxt = table.succ[chain[-1]]
        if length >= need_m or not nxt or len(chain) > 12:
            out.append((chain, prob))
            continue
        for s in reversed(nxt):
            stack.append((chain + [s], prob / len(nxt), length + float(table.cum[s][-1])))
    return out


def _path(table: _LaneTable, chain: list[int], s0: float, need_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Polyline from arc length ``s0`` on the first lane along ``chain``, extended straight to ``need_m``."""
    first, cum = table.lines[chain[0]], table.cum[chain[0]]
    k = int(np.clip(np.searchsorted(cum, s0, side="right") - 1, 0, len(cum) - 2))
    u = (s0 - cum[k]) / max(cum[k + 1] - cum[k], 1e-9)
    start = first[k] + u * (first[k + 1] - first[k])
    pts = [start[None], first[k + 1 :]]
    for i in chain[1:]:
        line = table.lines[i]
        pts.append(line[1:] if np.hypot(*(line[0] - pts[-1][-1])) < 0.5 else line)
    path = np.concatenate(pts)
    keep = np.concatenate([[True], np.hypot(*np.diff(path, axis=0).T) > 1e-6])
    path = path[keep]
    if len(path) < 2:
        path = np.vstack([path, path[-1] + [1.0, 0.0]])
    cum_p = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
    if cum_p[-1] < need_m:
        d = (path[-1] - path[-2]) / max(cum_p[-1] - cum_p[-2], 1e-9)
        path = np.vstack([path, path[-1] + d * (need_m - cum_p[-1] + 1.0)])
        cum_p = np.append(cum_p, need_m + 1.0)
    return path, cum_p


def _along(path: np.ndarray, cum: np.ndarray, s: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """Points ``[..., 2]`` at arc lengths ``s`` shifted ``offset`` m to the left of the path."""
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(cum) - 2)
    seg = path[k + 1] - path[k]
    seg_len = np.maximum(np.hypot(seg[..., 0], seg[..., 1]), 1e-9)[..., None]
    t = seg / seg_len
    base = path[k] + t * (s - cum[k])[..., None]
    normal = np.stack([-t[..., 1], t[..., 0]], axis=-1)
    return base + normal * offset[..., None]


def _arc_lengths(v0: float, accelerations: np.ndarray, v_max: float) -> np.ndarray:
    """``[A, N_FUTURE]`` distance covered after each 0.1 s step at constant acceleration (speed in [0, v_max])."""
    speed = np.clip(v0 + accelerations[:, None] * DT_S * np.arange(N_FUTURE + 1)[None], 0.0, max(v_max, v0))
    return np.cumsum(0.5 * (speed[:, 1:] + speed[:, :-1]) * DT_S, axis=1)


def lane_candidates(
    scenario: Scenario,
    agent_index: int | None = None,
    n_candidates: int = 32,
    accelerations_mps2: tuple[float, ...] = ACCELERATIONS_MPS2,
) -> Candidates:
    """Up to ``n_candidates`` map-based futures of an agent (default: the adversary); see the module docstring."""
    agent = scenario.adv_index if agent_index is None else int(agent_index)
    row = scenario.tracks[agent, CURRENT_STEP].astype(np.float64)
    p = row[[X, Y]]
    h0 = float(row[HEADING])
    v0 = float(math.hypot(row[VX], row[VY]))
    acc = np.asarray(accelerations_mps2, dtype=np.float64)
    table = _table(scenario.road)

    futures: list[np.ndarray] = []
    logits: list[np.ndarray] = []
    for i, line in enumerate(table.lines):
        s0, lateral, tangent, beyond = _project(line, table.cum[i], p)
        gap = abs(wrap_angle_f(tangent - h0))
        if abs(lateral) > 1.5 * table.width[i] or gap > MAX_HEADING_GAP_RAD or beyond > 2.0:
            continue
        v_max = max(v0, 1.2 * float(table.limit[i]))
        dist = _arc_lengths(v0, acc, v_max)  # [A, T]
        need = float(dist.max()) + 5.0
        fade_m = max(20.0, 3.0 * v0)
        u = np.clip(dist / fade_m, 0.0, 1.0)
        offset = lateral * (1.0 - u * u * (3.0 - 2.0 * u))
        change = abs(lateral) > 0.5 * table.width[i]
        for chain, prob in _chains(table, i, need + s0):
            path, cum = _path(table, chain, s0, need)
            futures.append(_along(path, cum, dist, offset))
            logits.append(
                -0.5 * (acc / ACCEL_SCALE_MPS2) ** 2 + math.log(prob) - LANE_CHANGE_PENALTY * float(change)
            )
    if not futures:
        futures, logits = [_turning(p, h0, v0, acc)], [_turning_logits(acc)]
    xy = np.concatenate(futures)
    score = np.concatenate(logits)
    keep = _distinct(xy, np.argsort(-score, kind="stable"), n_candidates)
    probs = np.exp(score[keep] - score[keep].max())
    return Candidates.from_positions(xy[keep], probs, start_xy=p, start_heading=h0, agent_index=agent)


def _distinct(xy: np.ndarray, order: np.ndarray, n: int, tol_m: float = 0.5) -> np.ndarray:
    """First ``n`` indices of ``order`` whose future differs by more than ``tol_m`` (max over time) from every
    earlier kept one (lanes split into consecutive pieces give the same path twice)."""
    kept: list[int] = []
    for i in order:
        if kept:
            gap = np.abs(xy[kept] - xy[i]).max(axis=(1, 2))
            if gap.min() <= tol_m:
                continue
        kept.append(int(i))
        if len(kept) == n:
            break
    return np.asarray(kept)


def _turning(p: np.ndarray, h0: float, v0: float, acc: np.ndarray) -> np.ndarray:
    """``[R * A, T, 2]`` constant turn rate and acceleration futures (turn rates `YAW_RATES_RADPS`)."""
    speed = np.clip(v0 + acc[:, None] * DT_S * np.arange(1, N_FUTURE + 1)[None], 0.0, 40.0)  # [A, T]
    rates = np.asarray(YAW_RATES_RADPS)
    heading = h0 + rates[:, None] * DT_S * np.arange(1, N_FUTURE + 1)[None]  # [R, T]
    step = speed[None] * DT_S  # [1, A, T]
    dx = step * np.cos(heading)[:, None]
    dy = step * np.sin(heading)[:, None]
    xy = np.stack([p[0] + np.cumsum(dx, -1), p[1] + np.cumsum(dy, -1)], axis=-1)  # [R, A, T, 2]
    return xy.reshape(-1, N_FUTURE, 2)


def _turning_logits(acc: np.ndarray) -> np.ndarray:
    rates = np.asarray(YAW_RATES_RADPS)
    return (-0.5 * (rates[:, None] / 0.1) ** 2 - 0.5 * (acc[None] / ACCEL_SCALE_MPS2) ** 2).reshape(-1)
