"""Counterfactual future-extrapolated (FE) tracks (thesis 3.3.2): "what if the agent kept its progress in lane".

For each agent valid at the current step the 11-step history is kept; from the current state it is projected
onto its lane (Frenet s, d) and continued with a constant lateral offset d along its route:

* **Route.** The lane chain starts at the agent's current lane and, at every fork, takes the successor the agent
  drives on in its logged future (the lane sequence it really takes; of several, the one it spends the most
  steps on); where the log does not decide (the agent leaves the map, changes lanes or its log ends) the
  straightest successor.
* **Progress.** An agent that is not decelerating keeps a constant ds per step: the current velocity projected
  on the lane direction (negative values clipped to 0). An agent that is decelerating at the current step
  (speed change over the last 0.5 s below -`DECEL_THRESHOLD_MPS2`) keeps decelerating to a stop instead of
  driving on: at its current deceleration, or, where its route has a stop point ahead that it would otherwise
  overrun and can still reach at no more than `MAX_STOP_DECEL_MPS2`, at the constant deceleration that stops
  it there. The stop point is the first conflict point of the route ahead of the agent's front (a crossing,
  merge or lane drop: where a driver yields; `seal.scoring.conflict_points`) less `STOP_CLEARANCE_M`, or the
  end of the route where it has no successor. Once stopped the agent stays.

Agents without a lane continue with constant Cartesian velocity. Agents not valid at the current step have no
history to extrapolate from and keep their logged track (their FE = GT). FE agents valid at the current step are
valid until the last step, even if the logged agent left earlier; past the end of a lane without successors a
non-decelerating agent drives straight on, off the map (no lane).
"""

from __future__ import annotations

import numpy as np

from seal.core.scenario import CURRENT_STEP, DT_S
from seal.scoring.frenet import LaneChain, RoadIndex
from seal.scoring.kernels import polyline_at, polyline_project, rank_by_dwell
from seal.scoring.tracks import AgentTracks, lane_attributes

DECEL_THRESHOLD_MPS2 = 0.5
"""An agent whose speed fell faster than this over the last `DECEL_WINDOW_STEPS` is decelerating (m/s^2)."""
DECEL_WINDOW_STEPS = 5
"""History steps (0.5 s) over which the current deceleration is measured (smooths the noise of real logs)."""
MAX_STOP_DECEL_MPS2 = 8.0
"""A decelerating agent stops at its route's stop point only if that needs at most this deceleration (m/s^2)."""
STOP_CLEARANCE_M = 2.0
"""Distance (m) between the front of an agent stopped for a conflict point and the point (half a lane width)."""


def future_extrapolate(gt: AgentTracks, index: RoadIndex, current: int = CURRENT_STEP, dt: float = DT_S) -> AgentTracks:
    """FE tracks of all agents of ``gt`` (see the module docstring); history steps ``<= current`` are copied."""
    n_agents, n_steps = gt.valid.shape
    n_fut = n_steps - 1 - current
    if n_fut <= 0:
        return gt
    pos, vel, heading = gt.pos.copy(), gt.vel.copy(), gt.heading.copy()
    valid, lane, in_lane, limit = gt.valid.copy(), gt.lane.copy(), gt.in_lane.copy(), gt.speed_limit.copy()
    t = np.arange(1, n_fut + 1, dtype=np.float64) * dt
    fut = slice(current + 1, n_steps)
    cartesian: list[int] = []
    for a in (int(k) for k in np.flatnonzero(gt.valid[:, current])):
        p0, v0 = gt.pos[a, current], gt.vel[a, current]
        lane0 = int(gt.lane[a, current])
        valid[a, fut] = True
        if lane0 < 0:
            cartesian.append(a)
            continue
        # The chain starts at the start of the agent's lane, so it must cover the lane plus the drive.
        speed = float(np.hypot(v0[0], v0[1]))
        chain = index.chain(lane0, float(index.lane_lengths[lane0]) + speed * t[-1] + 1.0, logged_route(gt, a, current))
        line = chain.polyline
        s0, d0, k0 = polyline_project(line.points, line.cum, line.tang, line.seg_len, float(p0[0]), float(p0[1]))
        tangent = line.tang[int(k0)]
        v_lane = max(float(v0 @ tangent), 0.0)  # progress along the lane, no reversing
        decel = current_deceleration(gt, a, current, dt)
        if decel > DECEL_THRESHOLD_MPS2 and v_lane > 0.0:
            decel = stopping_deceleration(chain, s0, float(gt.length[a]), v_lane, decel)
            s = s0 + np.where(t < v_lane / decel, v_lane * t - 0.5 * decel * t**2, 0.5 * v_lane**2 / decel)
        else:
            s = s0 + v_lane * t
        pts, head, seg = polyline_at(line.points, line.cum, line.tang, line.vertex_tang, s, d0)
        pos[a, fut] = pts
        heading[a, fut] = head
        vel[a, fut] = np.diff(np.concatenate([p0[None], pts]), axis=0) / dt
        on_map = s <= line.length  # past the end of a lane without successors the agent leaves the map
        lanes_k = np.where(on_map, chain.seg_lane[seg], -1)
        lane[a, fut] = lanes_k
        in_lane[a, fut] = on_map & (abs(d0) <= 0.5 * index.widths[np.maximum(lanes_k, 0)])
        limit[a, fut] = np.where(on_map, index.speed_limits[np.maximum(lanes_k, 0)], np.nan)
    if cartesian:
        idx = np.array(cartesian)
        p0, v0 = gt.pos[idx, current], gt.vel[idx, current]
        pos[idx, fut] = p0[:, None, :] + v0[:, None, :] * t[None, :, None]
        vel[idx, fut] = v0[:, None, :]
        heading[idx, fut] = gt.heading[idx, current][:, None]
        sub_valid = np.zeros((idx.size, n_steps), dtype=bool)
        sub_valid[:, fut] = True
        ln, il, lim = lane_attributes(index, pos[idx], heading[idx], sub_valid)
        lane[idx, fut], in_lane[idx, fut], limit[idx, fut] = ln[:, fut], il[:, fut], lim[:, fut]
    return AgentTracks(
        pos=pos, vel=vel, heading=heading, length=gt.length, width=gt.width, valid=valid, lane=lane,
        in_lane=in_lane, speed_limit=limit,
    )


def logged_route(gt: AgentTracks, agent: int, current: int = CURRENT_STEP) -> tuple[int, ...]:
    """The lanes agent ``agent`` is on from the current step on in its log, most logged steps first (ties: first
    visited first). Ranking by time spent, not by first visit, keeps a step or two on the wrong branch right at a
    diverge (where both branches start at the same point) from deciding the route."""
    lanes = gt.lane[agent, current:][gt.valid[agent, current:]]
    return tuple(rank_by_dwell(np.ascontiguousarray(lanes, dtype=np.int64)).tolist())


def current_deceleration(gt: AgentTracks, agent: int, current: int = CURRENT_STEP, dt: float = DT_S) -> float:
    """Speed lost per second (m/s^2, positive = decelerating) over the last `DECEL_WINDOW_STEPS` valid steps."""
    k = DECEL_WINDOW_STEPS
    while k > 0 and not gt.valid[agent, current - k]:
        k -= 1
    if k == 0:
        return 0.0
    before, now = gt.vel[agent, current - k], gt.vel[agent, current]
    return float(np.hypot(before[0], before[1]) - np.hypot(now[0], now[1])) / (k * dt)


def stopping_deceleration(chain: LaneChain, s0: float, length_m: float, v_mps: float, decel_mps2: float) -> float:
    """Deceleration (m/s^2) of a decelerating agent at arc length ``s0`` on ``chain`` (see the module docstring):
    ``decel_mps2``, or more if that would overrun the route's stop point and stopping there needs at most
    `MAX_STOP_DECEL_MPS2`."""
    front = s0 + 0.5 * length_m
    ahead = chain.conflict_s[chain.conflict_s > front]
    stop_front = ahead[0] - STOP_CLEARANCE_M if ahead.size else np.inf
    if chain.dead_end:
        stop_front = min(stop_front, chain.polyline.length)
    room = stop_front - front
    if not np.isfinite(room) or room <= 0.0:
        return decel_mps2
    needed = v_mps**2 / (2.0 * room)
    return max(decel_mps2, needed) if needed <= MAX_STOP_DECEL_MPS2 else decel_mps2
