"""Counterfactual future-extrapolated (FE) tracks (thesis 3.3.2): "what if the agent kept its progress in lane".

For each agent valid at the current step the 11-step history is kept; from the current state it is projected
onto its lane (Frenet s, d) and continued with a constant ds per step (the current velocity projected on the lane
direction, negative values clipped to 0) and a constant lateral offset d, following the lane's successors (the
straightest one at a fork). Agents without a lane continue with constant Cartesian velocity. Agents not valid at
the current step have no history to extrapolate from and keep their logged track (their FE = GT).

FE agents valid at the current step are valid until the last step, even if the logged agent left earlier; past
the end of a lane without successors they drive straight on, off the map (no lane).
"""

from __future__ import annotations

import numpy as np

from seal.core.scenario import CURRENT_STEP, DT_S
from seal.scoring.frenet import RoadIndex
from seal.scoring.tracks import AgentTracks, lane_attributes


def future_extrapolate(gt: AgentTracks, index: RoadIndex, current: int = CURRENT_STEP, dt: float = DT_S) -> AgentTracks:
    """FE tracks of all agents of ``gt`` (see the module docstring); history steps ``<= current`` are copied."""
    n_agents, n_steps = gt.valid.shape
    n_fut = n_steps - 1 - current
    if n_fut <= 0:
        return gt
    pos, vel, heading = gt.pos.copy(), gt.vel.copy(), gt.heading.copy()
    valid, lane, in_lane, limit = gt.valid.copy(), gt.lane.copy(), gt.in_lane.copy(), gt.speed_limit.copy()
    k = np.arange(1, n_fut + 1, dtype=np.float64)
    fut = slice(current + 1, n_steps)
    cartesian: list[int] = []
    for a in np.flatnonzero(gt.valid[:, current]):
        p0, v0 = gt.pos[a, current], gt.vel[a, current]
        lane0 = int(gt.lane[a, current])
        valid[a, fut] = True
        if lane0 < 0:
            cartesian.append(int(a))
            continue
        # The chain starts at the start of the agent's lane, so it must cover the lane plus the drive.
        speed = float(np.hypot(v0[0], v0[1]))
        chain, seg_lane = index.chain(lane0, float(index.lane_lengths[lane0]) + speed * dt * n_fut + 1.0)
        s0, d0, tangent = chain.project(p0)
        # Progress per step: the current velocity projected on the lane direction (no reversing).
        ds = max(float(v0 @ tangent), 0.0) * dt
        s = s0 + ds * k
        pts, head = chain.at(s, d0)
        pos[a, fut] = pts
        heading[a, fut] = head
        vel[a, fut] = np.diff(np.concatenate([p0[None], pts]), axis=0) / dt
        seg = np.clip(np.searchsorted(chain.cum, s, side="right") - 1, 0, seg_lane.size - 1)
        on_map = s <= chain.length  # past the end of a lane without successors the agent leaves the map
        lanes_k = np.where(on_map, seg_lane[seg], -1)
        lane[a, fut] = lanes_k
        in_lane[a, fut] = on_map & (abs(d0) <= 0.5 * index.widths[np.maximum(lanes_k, 0)])
        limit[a, fut] = np.where(on_map, index.speed_limits[np.maximum(lanes_k, 0)], np.nan)
    if cartesian:
        idx = np.array(cartesian)
        p0, v0 = gt.pos[idx, current], gt.vel[idx, current]
        pos[idx, fut] = p0[:, None, :] + v0[:, None, :] * (k[None, :, None] * dt)
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
