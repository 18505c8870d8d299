"""Social (agent-pair) SafeShift features and the social score (thesis eq. 3.2, SafeShift code), vectorised over
pairs.

A pair is (agent ``I[p]`` of track set ``a``, agent ``J[p]`` of track set ``b``): the same set for the GT / FE
variants, FE for i and GT for j in the asymmetric one. Only steps where both are valid count. Pairs are skipped
(all features 0) when both agents are stationary (mean speed <= 0.25 m/s) or never within 50 m.

Features (larger = more safety-relevant; the inverse of a time is 0 when the time is undefined):

* ``inv_thw`` (1/s): max of 1/THW, THW = bumper gap / follower speed;
* ``inv_ttc`` (1/s): max of 1/TTC, TTC = bumper gap / closing speed (follower faster than leader);
* ``drac`` (m/s^2): max of closing speed^2 / (2 bumper gap);
  these three only at steps where both are in the same or directly connected lanes with headings within 45 deg;
  the leader is the one ahead along the other's heading; bumper gap = centre distance - half of both lengths
  (floored at 0.1 m; SafeShift uses centre distances, bumper gaps make a 2 m tailgater count as one);
* ``inv_mttcp_map`` (1/s): 1 / min over the lane conflict points both pass within 5 m of, over the steps up to
  the first of their closest approaches, of |time to the point of i - time to it of j| (time = distance / speed;
  a stationary agent's time is 0, it is already there);
* ``inv_mttcp_agents`` (1/s): the same with the points where i's path comes within 1 m of j's path (at any two
  steps), the point being i's position there;
* ``collisions`` (contacts): number of contacts, a contact being a run of consecutive steps where the per-step
  motion segments of the two centres intersect, the centres are within 0.25 m (SafeShift's centre-based
  definition), or the two bodies' oriented boxes overlap (added: in simulated traffic crashing cars are pushed
  apart, so their centres never meet). Contacts, not contact steps: an extrapolated track that drives through a
  slower vehicle overlaps it for many steps, and a step count would outweigh every other feature of the pair;
* ``pair_anomaly``: distance of the pair's motion to the clustered pair primitives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.core.geometry import wrap_angle
from seal.scoring.frenet import RoadIndex
from seal.scoring.kernels import agent_mttcp, pair_contacts
from seal.scoring.primitives import Primitives, agent_windows, pair_anomaly
from seal.scoring.tracks import AgentTracks

SOCIAL_FEATURES = (
    "inv_thw", "inv_ttc", "drac", "inv_mttcp_map", "inv_mttcp_agents", "collisions", "pair_anomaly",
)
STATIONARY_MPS = 0.25
PAIR_DIST_M = 50.0
HEADING_MAX_RAD = np.deg2rad(45.0)
MAP_CP_DIST_M = 5.0
AGENT_CP_DIST_M = 1.0
COLLISION_DIST_M = 0.25
MIN_GAP_M = 0.1
MIN_TIME_S = 1e-3
SPEED_EPS = 1e-3


class TrackContext:
    """Per-track-set arrays reused by every pair: speeds, coordinate planes, collapsed path points and distances
    to the road's conflict points."""

    def __init__(self, tracks: AgentTracks, index: RoadIndex) -> None:
        self.tracks = tracks
        self.speed = tracks.speed
        self.windows = agent_windows(tracks.pos, tracks.heading, tracks.valid)  # motion-primitive windows
        # Separate x / y planes: hypot on [.., T] arrays is much faster than norms over a trailing axis of 2.
        self.x, self.y = np.ascontiguousarray(tracks.pos[..., 0]), np.ascontiguousarray(tracks.pos[..., 1])
        self.heading = np.ascontiguousarray(tracks.heading, dtype=np.float64)
        self.length = np.ascontiguousarray(tracks.length, dtype=np.float64)
        self.width = np.ascontiguousarray(tracks.width, dtype=np.float64)
        # Path points for conflict search. A standing agent repeats its position up to 91 times, which would
        # make the neighbour search quadratic; runs of consecutive positions in the same 1 cm grid cell are
        # collapsed to one point: the last step of the run where the agent is "i" (the latest conflict step gives
        # the longest window, hence the smallest time difference) and the first where it is "j" (SafeShift takes
        # j's first close step). A grid cell (not "within 1 cm of the previous step") keeps slow drifts apart.
        valid = tracks.valid
        q = np.floor(tracks.pos / 0.01).astype(np.int64)
        same = (q[:, 1:] == q[:, :-1]).all(-1) & valid[:, 1:] & valid[:, :-1]  # [A, T-1]: t+1 repeats t
        first = valid.copy()
        first[:, 1:] &= ~same
        last = valid.copy()
        last[:, :-1] &= ~same
        # Both masks enumerate the same runs in the same (agent, step) order, so entry k of the first_* and
        # last_* arrays is one run: its first and last step.
        self.last_agent, self.last_step = (np.ascontiguousarray(v, dtype=np.int64) for v in np.nonzero(last))
        self.last_points = tracks.pos[self.last_agent, self.last_step]  # [N, 2]
        self.first_agent, self.first_step = (np.ascontiguousarray(v, dtype=np.int64) for v in np.nonzero(first))
        self.first_points = tracks.pos[self.first_agent, self.first_step]
        self.last_run_start = self.first_step  # run k's first step, aligned with last_* (same run order)
        self.first_run_end = self.last_step
        n_steps = valid.shape[1]
        self.valid_start = np.argmax(valid, axis=1).astype(np.int64)
        self.valid_end = (n_steps - 1 - np.argmax(valid[:, ::-1], axis=1)).astype(np.int64)
        # For the compiled path-conflict search: each agent's range of runs, and its "first" runs sorted by x.
        agents = np.arange(tracks.n_agents + 1)
        self.last_runs = np.searchsorted(self.last_agent, agents).astype(np.int64)
        self.first_runs = np.searchsorted(self.first_agent, agents).astype(np.int64)
        self.last_points_x = np.ascontiguousarray(self.last_points[:, 0])
        order = np.lexsort((self.first_points[:, 0], self.first_agent))
        self.first_sorted_x = np.ascontiguousarray(self.first_points[order, 0])
        self.first_sorted_run = order.astype(np.int64)
        cps = index.conflict_points
        if cps.shape[0]:
            d = np.hypot(self.x[..., None] - cps[:, 0], self.y[..., None] - cps[:, 1])  # [A, T, C]
            self.cp_dist = np.where(tracks.valid[..., None], d, np.inf)
            self.cp_near: np.ndarray = np.any(self.cp_dist < MAP_CP_DIST_M, axis=1)  # [A, C]
            self.cp_argmin = np.argmin(self.cp_dist, axis=1)  # [A, C] step of closest approach
        else:
            self.cp_dist = np.zeros(tracks.valid.shape + (0,))
            self.cp_near = np.zeros((tracks.n_agents, 0), dtype=bool)
            self.cp_argmin = np.zeros((tracks.n_agents, 0), dtype=np.int64)


def social_features(
    ca: TrackContext, cb: TrackContext, I: np.ndarray, J: np.ndarray, index: RoadIndex,
    prim: Primitives | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Features ``[P]`` named `SOCIAL_FEATURES` for pairs ``(I[p] in a, J[p] in b)`` and the active mask ``[P]``."""
    a, b = ca.tracks, cb.tracks
    n = I.size
    out = {k: np.zeros(n) for k in SOCIAL_FEATURES}
    if n == 0:
        return out, np.zeros(0, dtype=bool)
    mask = a.valid[I] & b.valid[J]
    n_both = mask.sum(1)
    si, sj = ca.speed[I], cb.speed[J]
    mean_i = (si * mask).sum(1) / np.maximum(n_both, 1)
    mean_j = (sj * mask).sum(1) / np.maximum(n_both, 1)
    dist = np.hypot(ca.x[I] - cb.x[J], ca.y[I] - cb.y[J])
    min_dist = np.where(mask, dist, np.inf).min(1)
    active = (n_both > 0) & ~((mean_i <= STATIONARY_MPS) & (mean_j <= STATIONARY_MPS)) & (min_dist < PAIR_DIST_M)
    act = np.flatnonzero(active)
    if act.size == 0:
        return out, active
    I, J, mask, si, sj, dist = I[act], J[act], mask[act], si[act], sj[act], dist[act]
    st_i, st_j = mean_i[act] <= STATIONARY_MPS, mean_j[act] <= STATIONARY_MPS
    pi, pj = a.pos[I], b.pos[J]

    out["collisions"][act] = _collisions(ca, cb, I, J, mask)
    thw, ttc, drac = _following(a, b, I, J, pi, pj, si, sj, dist, mask, index)
    out["inv_thw"][act], out["inv_ttc"][act], out["drac"][act] = thw, ttc, drac
    out["inv_mttcp_agents"][act] = _agent_mttcp(ca, cb, I, J, st_i, st_j, mask)
    out["inv_mttcp_map"][act] = _map_mttcp(ca, cb, I, J, si, sj, st_i, st_j, mask)
    out["pair_anomaly"][act] = pair_anomaly(prim, ca.windows, I, cb.windows, J)
    return out, active


def social_score(f: dict[str, np.ndarray]) -> np.ndarray:
    """``[P]`` social score, weights of the SafeShift code."""
    return (
        np.minimum(2.0, f["inv_thw"])
        + np.minimum(4.0, f["inv_mttcp_map"])
        + np.minimum(4.0, f["inv_mttcp_agents"])
        + np.minimum(2.0, f["inv_ttc"])
        + np.minimum(2.0, f["drac"] / 5.0)
        + f["collisions"]
        + np.minimum(5.0, 0.1 * f["pair_anomaly"])
    )


# ------------------------------------------------------------------------------------------------ measures
def _collisions(ca: TrackContext, cb: TrackContext, I: np.ndarray, J: np.ndarray, mask: np.ndarray) -> np.ndarray:
    # Count contacts, not contact steps: an extrapolated track driving through a slower vehicle overlaps it for
    # many steps, which as a step count would outweigh every other feature of the pair (compiled kernel;
    # tests/scoring_reference.py keeps the numpy form).
    return pair_contacts(
        I.astype(np.int64), J.astype(np.int64), np.ascontiguousarray(mask),
        ca.x, ca.y, ca.heading, ca.length, ca.width, cb.x, cb.y, cb.heading, cb.length, cb.width,
        COLLISION_DIST_M,
    )


@dataclass(frozen=True)
class FollowingSteps:
    """Per-step car-following measures of the pairs that follow each other at least once.

    Attributes:
        rows: ``[R]`` indices into the pairs given to `following_per_step` (pairs with no following step are left
            out: most pairs never share a lane).
        ok: ``[R, T]`` both valid, in the same or directly connected lanes, headings within 45 deg.
        j_leads: ``[R, T]`` agent j is ahead along i's heading (j leads, i follows); else i leads.
        gap: ``[R, T]`` bumper gap (m): centre distance - half of both lengths, floored at `MIN_GAP_M`.
        v_follow, v_lead: ``[R, T]`` speeds of the follower and the leader (m/s).
        inv_thw: ``[R, T]`` 1/THW = follower speed / gap (1/s).
        inv_ttc: ``[R, T]`` 1/TTC = closing speed / gap (1/s), 0 when the gap opens.
        drac: ``[R, T]`` closing speed^2 / (2 gap) (m/s^2), the deceleration that stops the closing before contact.
    The measures are computed at every step; they mean something only where ``ok``.
    """

    rows: np.ndarray
    ok: np.ndarray
    j_leads: np.ndarray
    gap: np.ndarray
    v_follow: np.ndarray
    v_lead: np.ndarray
    inv_thw: np.ndarray
    inv_ttc: np.ndarray
    drac: np.ndarray


def following_per_step(
    a: AgentTracks, b: AgentTracks, I: np.ndarray, J: np.ndarray, index: RoadIndex,
) -> FollowingSteps:
    """Per-step THW / TTC / DRAC (`FollowingSteps`) of pairs ``(I[p] in a, J[p] in b)`` (``[P]`` each).

    The same numbers `social_features` reduces over the steps (it also skips pairs that are far apart or both
    stationary, which this function does not); for cross-checks against other implementations.
    """
    pi, pj = a.pos[I], b.pos[J]
    dist = np.hypot(pi[..., 0] - pj[..., 0], pi[..., 1] - pj[..., 1])
    return _following_steps(a, b, I, J, pi, pj, a.speed[I], b.speed[J], dist, a.valid[I] & b.valid[J], index)


def _following_steps(
    a: AgentTracks, b: AgentTracks, I: np.ndarray, J: np.ndarray, pi: np.ndarray, pj: np.ndarray,
    si: np.ndarray, sj: np.ndarray, dist: np.ndarray, mask: np.ndarray, index: RoadIndex,
) -> FollowingSteps:
    n_lanes = index.n_lanes
    li = np.where(a.lane[I] >= 0, a.lane[I], n_lanes)
    lj = np.where(b.lane[J] >= 0, b.lane[J], n_lanes)
    ok = mask & index.connected[li, lj]
    rows = np.flatnonzero(ok.any(1))  # most pairs never share a lane: skip them early
    ok, pi, pj, si, sj, dist = ok[rows], pi[rows], pj[rows], si[rows], sj[rows], dist[rows]
    hi, hj = a.heading[I[rows]], b.heading[J[rows]]
    ok &= np.abs(wrap_angle(hi - hj)) < HEADING_MAX_RAD
    rel_x, rel_y = pj[..., 0] - pi[..., 0], pj[..., 1] - pi[..., 1]
    j_leads = rel_x * np.cos(hi) + rel_y * np.sin(hi) > 0
    v_f = np.where(j_leads, si, sj)
    v_l = np.where(j_leads, sj, si)
    gap = np.maximum(dist - 0.5 * (a.length[I[rows]] + b.length[J[rows]])[:, None], MIN_GAP_M)
    closing = np.maximum(v_f - v_l, 0.0)
    return FollowingSteps(rows, ok, j_leads, gap, v_f, v_l, v_f / gap, closing / gap, closing**2 / (2.0 * gap))


def _following(
    a: AgentTracks, b: AgentTracks, I: np.ndarray, J: np.ndarray, pi: np.ndarray, pj: np.ndarray,
    si: np.ndarray, sj: np.ndarray, dist: np.ndarray, mask: np.ndarray, index: RoadIndex,
) -> np.ndarray:
    """``[3, P]``: max over the steps of 1/THW, 1/TTC and DRAC (0 for pairs that never follow)."""
    out = np.zeros((3, I.size))
    st = _following_steps(a, b, I, J, pi, pj, si, sj, dist, mask, index)
    if st.rows.size == 0:
        return out
    out[0, st.rows] = np.where(st.ok, st.inv_thw, 0.0).max(1)
    out[1, st.rows] = np.where(st.ok, st.inv_ttc, 0.0).max(1)
    out[2, st.rows] = np.where(st.ok, st.drac, 0.0).max(1)
    return out


def _min_time_difference(d_i, d_j, v_i, v_j, st_i, st_j, window) -> np.ndarray:
    """``[R]`` min over the window of |d_i / v_i - d_j / v_j| (rows ``[R, T]``); stationary agents take 0 s."""
    t_i = d_i / (v_i + SPEED_EPS)
    t_i[st_i] = 0.0
    t_j = d_j / (v_j + SPEED_EPS)
    t_j[st_j] = 0.0
    diff = np.abs(t_i - t_j)
    diff[~window] = np.inf
    return diff.min(1).astype(np.float64)


def _rows_min(values: np.ndarray, rows: np.ndarray, n: int) -> np.ndarray:
    """Per-pair minimum of row values (inf where a pair has no row), inverted to 1/time."""
    best = np.full(n, np.inf)
    np.minimum.at(best, rows, values)
    return np.where(np.isfinite(best), 1.0 / np.maximum(best, MIN_TIME_S), 0.0)


def _agent_mttcp(ca: TrackContext, cb: TrackContext, I, J, st_i, st_j, mask) -> np.ndarray:
    # Path points of i (set a) within 1 m of path points of j (set b), at any two steps; each step of i with a
    # conflict is one row, j's step is the first one close to it (as in SafeShift); the compiled kernel does the
    # search and the per-row minimum (tests/scoring_reference.py keeps the numpy form).
    return agent_mttcp(
        I.astype(np.int64), J.astype(np.int64), np.ascontiguousarray(st_i), np.ascontiguousarray(st_j),
        np.ascontiguousarray(mask),
        ca.x, ca.y, ca.speed, ca.last_runs, ca.last_step, ca.last_run_start, ca.last_points_x, ca.valid_start,
        ca.valid_end,
        cb.x, cb.y, cb.speed, cb.first_runs, cb.first_step, cb.first_run_end, cb.first_sorted_x, cb.first_sorted_run,
        cb.valid_start, cb.valid_end,
        AGENT_CP_DIST_M, SPEED_EPS, MIN_TIME_S,
    )


def _map_mttcp(ca: TrackContext, cb: TrackContext, I, J, si, sj, st_i, st_j, mask) -> np.ndarray:
    n, t_steps = mask.shape
    if ca.cp_near.shape[1] == 0:
        return np.zeros(n)
    shared = ca.cp_near[I] & cb.cp_near[J]  # [P, C]
    rp, rc = np.nonzero(shared)
    if rp.size == 0:
        return np.zeros(n)
    ai, aj = I[rp], J[rp]
    d_i = ca.cp_dist[ai, :, rc]  # [R, T]
    d_j = cb.cp_dist[aj, :, rc]
    t_min = np.minimum(ca.cp_argmin[ai, rc], cb.cp_argmin[aj, rc])
    window = (np.arange(t_steps)[None, :] <= t_min[:, None]) & mask[rp]
    d_i = np.where(window, d_i, 0.0)  # inf outside the valid steps; masked anyway
    d_j = np.where(window, d_j, 0.0)
    vals = _min_time_difference(d_i, d_j, si[rp], sj[rp], st_i[rp], st_j[rp], window)
    return _rows_min(vals, rp, n)
