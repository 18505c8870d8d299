"""Numpy reference forms of the scoring's compiled kernels (`seal.scoring.kernels`), for the tests.

* `project_reference`: `seal.scoring.frenet.RoadIndex.project` (grid neighbour search with `close_pairs`, then
  the closest compatible candidate per point);
* `collisions_reference`: the contact count of a pair (``collisions``), with `segments_intersect`;
* `agent_mttcp_reference`: ``inv_mttcp_agents`` (grid neighbour search over all agents' collapsed path points,
  per-row time differences bucketed by window length, positions in float32).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from seal.core.geometry import box_corners, boxes_overlap
from seal.scoring.frenet import MAX_HEADING_DIFF_RAD, MAX_LANE_DIST_WIDTHS, Projection, RoadIndex
from seal.scoring.social import (
    AGENT_CP_DIST_M,
    COLLISION_DIST_M,
    TrackContext,
    _min_time_difference,
    _rows_min,
)
from seal.scoring.tracks import AgentTracks


def close_pairs(
    a: np.ndarray, b: np.ndarray, radius: float, allowed: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(ia, ib)`` of all point pairs with ``|a[ia] - b[ib]| <= radius``; ``a [Na, 2]``, ``b [Nb, 2]``.

    ``allowed(ia, ib) -> bool mask`` drops candidate pairs before the exact distance test (cheaper when most
    neighbours are of no interest, e.g. points of the same agent).
    """
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if a.shape[0] == 0 or b.shape[0] == 0:
        return empty
    lo = np.minimum(a.min(0), b.min(0))
    ca = np.floor((a - lo) / radius).astype(np.int64)
    cb = np.floor((b - lo) / radius).astype(np.int64)
    ny = int(max(ca[:, 1].max(), cb[:, 1].max())) + 3
    key_b = (cb[:, 0] + 1) * ny + (cb[:, 1] + 1)  # +1 keeps neighbour keys of cell 0 non-negative and distinct
    order = np.argsort(key_b, kind="stable")
    # Occupied cells of b with the start and size of their run in ``order``: one binary search per query.
    sorted_b = key_b[order]
    cell_start = np.concatenate([[0], np.flatnonzero(np.diff(sorted_b)) + 1])
    cells = sorted_b[cell_start]
    cell_count = np.diff(np.concatenate([cell_start, [sorted_b.size]]))
    key_a = (ca[:, 0] + 1) * ny + (ca[:, 1] + 1)
    offsets = np.array([dx * ny + dy for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
    queries = (key_a[:, None] + offsets[None, :]).ravel()  # [Na * 9]
    pos = np.minimum(np.searchsorted(cells, queries), cells.size - 1)
    hit = cells[pos] == queries
    start = np.where(hit, cell_start[pos], 0)
    count = np.where(hit, cell_count[pos], 0)
    total = int(count.sum())
    if total == 0:
        return empty
    ia = np.repeat(np.repeat(np.arange(a.shape[0]), 9), count)
    run_start = np.repeat(start, count)
    within = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
    ib = order[run_start + within]
    if allowed is not None:
        keep = allowed(ia, ib)
        ia, ib = ia[keep], ib[keep]
    ax, ay = np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1])  # 1-D gathers are the fast kind
    bx, by = np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1])
    dx, dy = ax[ia] - bx[ib], ay[ia] - by[ib]
    d2 = dx * dx + dy * dy
    keep = d2 <= radius * radius
    return ia[keep], ib[keep]


def project_reference(self: RoadIndex, xy: np.ndarray, heading: np.ndarray | None = None) -> Projection:
    """Project points ``xy [N, 2]`` (m) with headings ``[N]`` (rad, optional) onto the closest compatible lane."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    lane = np.full(n, -1, dtype=np.int64)
    s = np.full(n, np.nan)
    d = np.full(n, np.nan)
    in_lane = np.zeros(n, dtype=bool)
    # Candidate (point, segment) pairs from a grid search against points sampled every <= 4 m along the
    # segments: any segment within the assignment distance of a point has a sample within the search radius,
    # and a point only meets the few segments around it instead of all of them.
    ip, isamp = close_pairs(xy, self._samples, self._search_radius)
    if ip.size == 0:
        return Projection(lane=lane, s=s, d=d, in_lane=in_lane)
    seg = self._sample_seg[isamp]  # duplicates (several samples of one segment) are harmless
    a, sd = self.seg_a[seg], self.seg_d[seg]
    rx, ry = xy[ip, 0] - a[:, 0], xy[ip, 1] - a[:, 1]
    t = np.clip((rx * sd[:, 0] + ry * sd[:, 1]) / self.seg_len2[seg], 0.0, 1.0)
    ex, ey = rx - t * sd[:, 0], ry - t * sd[:, 1]
    dist2 = ex * ex + ey * ey
    if heading is not None:
        h = np.asarray(heading, dtype=np.float64).reshape(-1)[ip]
        # Compatible direction: cos(heading - segment heading) >= cos(max difference).
        cos_diff = np.cos(h) * self._seg_cos[seg] + np.sin(h) * self._seg_sin[seg]
        dist2 = np.where(cos_diff < np.cos(MAX_HEADING_DIFF_RAD), np.inf, dist2)
    order = np.lexsort((dist2, ip))  # per point (ip sorted), closest candidate first
    first = order[np.concatenate([[True], ip[order][1:] != ip[order][:-1]])]
    pt, k, best2 = ip[first], seg[first], dist2[first]
    best = np.sqrt(np.where(np.isfinite(best2), best2, 0.0))
    seg_lane = self.seg_lane[k]
    ok = np.isfinite(best2) & (best <= MAX_LANE_DIST_WIDTHS * self.widths[seg_lane])
    cross = (sd[first, 0] * ry[first] - sd[first, 1] * rx[first]) / self.seg_len[k]
    lane[pt] = np.where(ok, seg_lane, -1)
    s[pt] = np.where(ok, self.seg_s0[k] + t[first] * self.seg_len[k], np.nan)
    # Past a lane's end the closest point is the end point: the lateral offset is then the full distance.
    d[pt] = np.where(ok, np.sign(cross) * best, np.nan)
    in_lane[pt] = ok & (best <= 0.5 * self.widths[seg_lane])
    return Projection(lane=lane, s=s, d=d, in_lane=in_lane)


def _buckets(t_end: np.ndarray, t_steps: int, width: int = 16) -> list[tuple[int, int]]:
    """Column ranges ``(lo, hi]`` of window lengths, in steps of ``width``, that contain rows."""
    edges = np.unique(np.minimum(-(-t_end // width) * width, t_steps))
    return list(zip(np.concatenate([[0], edges[:-1]]).tolist(), edges.tolist(), strict=True))




def agent_mttcp_reference(ca: TrackContext, cb: TrackContext, I, J, st_i, st_j, mask) -> np.ndarray:
    n, t_steps = mask.shape
    ax32, ay32, as32 = ca.x.astype(np.float32), ca.y.astype(np.float32), ca.speed.astype(np.float32)
    bx32, by32, bs32 = cb.x.astype(np.float32), cb.y.astype(np.float32), cb.speed.astype(np.float32)
    # Path points of i (set a) within 1 m of path points of j (set b), at any two steps: grid neighbour search
    # over all agents at once, then keep the (i, j) combinations that are active pairs.
    pair_of = np.full((ca.tracks.n_agents, cb.tracks.n_agents), -1, dtype=np.int64)
    pair_of[I, J] = np.arange(n)
    ia, ib = close_pairs(
        ca.last_points, cb.first_points, AGENT_CP_DIST_M,
        allowed=lambda ia, ib: pair_of[ca.last_agent[ia], cb.first_agent[ib]] >= 0,
    )
    ai, bj = ca.last_agent[ia], cb.first_agent[ib]
    p = pair_of[ai, bj]
    # Latest step of i's run where j is valid too, earliest step of j's run where i is valid too (validity is
    # one block per agent): the steps the uncollapsed rows would have used.
    ti = np.minimum(ca.last_step[ia], cb.valid_end[bj])
    tj = np.maximum(cb.first_step[ib], ca.valid_start[ai])
    keep = (ti >= np.maximum(ca.last_run_start[ia], cb.valid_start[bj])) & (
        tj <= np.minimum(cb.first_run_end[ib], ca.valid_end[ai])
    )
    p, ti, tj = p[keep], ti[keep], tj[keep]
    if p.size == 0:
        return np.zeros(n)
    # Each step of i with a conflict is one row; j's step is the first one close to it (as in SafeShift).
    first_j = np.full((n, t_steps), t_steps, dtype=np.int64)
    np.minimum.at(first_j, (p, ti), tj)
    rp, ti = np.nonzero(first_j < t_steps)
    tj = first_j[rp, ti]
    ri, rj = I[rp], J[rp]
    t_end = np.minimum(ti, tj) + 1  # rows only look at steps before the first of the two reaches the point
    vals = np.empty(rp.size)
    # Bucket rows by window length so that short windows do not pay for all T steps.
    for lo, hi in _buckets(t_end, t_steps):
        sel = np.flatnonzero((t_end > lo) & (t_end <= hi))
        if sel.size == 0:
            continue
        a_, b_, r_ = ri[sel], rj[sel], rp[sel]
        cx = ax32[a_, ti[sel]][:, None]  # conflict point = i's position at the conflict step
        cy = ay32[a_, ti[sel]][:, None]
        d_i = np.hypot(ax32[a_, :hi] - cx, ay32[a_, :hi] - cy)  # [R, hi]
        d_j = np.hypot(bx32[b_, :hi] - cx, by32[b_, :hi] - cy)
        window = (np.arange(hi)[None, :] < t_end[sel][:, None]) & mask[r_, :hi]
        vals[sel] = _min_time_difference(
            d_i, d_j, as32[a_, :hi], bs32[b_, :hi], st_i[r_], st_j[r_], window
        )
    return _rows_min(vals, rp, n)


def segments_intersect(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Whether segments ``p0-p1`` and ``q0-q1`` (``[..., 2]``, broadcast) intersect (touching counts)."""

    def orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
        return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])

    def on_segment(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:  # c within the box of a-b
        return (
            (np.minimum(a[..., 0], b[..., 0]) <= c[..., 0]) & (c[..., 0] <= np.maximum(a[..., 0], b[..., 0]))
            & (np.minimum(a[..., 1], b[..., 1]) <= c[..., 1]) & (c[..., 1] <= np.maximum(a[..., 1], b[..., 1]))
        )

    d1, d2 = orient(q0, q1, p0), orient(q0, q1, p1)
    d3, d4 = orient(p0, p1, q0), orient(p0, p1, q1)
    proper = (((d1 > 0) & (d2 < 0)) | ((d1 < 0) & (d2 > 0))) & (((d3 > 0) & (d4 < 0)) | ((d3 < 0) & (d4 > 0)))
    touch = (
        ((d1 == 0) & on_segment(q0, q1, p0)) | ((d2 == 0) & on_segment(q0, q1, p1))
        | ((d3 == 0) & on_segment(p0, p1, q0)) | ((d4 == 0) & on_segment(p0, p1, q1))
    )
    return proper | touch


def collisions_reference(
    a: AgentTracks, b: AgentTracks, I: np.ndarray, J: np.ndarray, pi: np.ndarray, pj: np.ndarray,
    dist: np.ndarray, mask: np.ndarray,
) -> np.ndarray:
    hit = (dist <= COLLISION_DIST_M) & mask
    # Box overlap, tested only where the circumscribed circles touch.
    reach_box = 0.5 * (np.hypot(a.length[I], a.width[I]) + np.hypot(b.length[J], b.width[J]))
    p, t = np.nonzero(mask & (dist <= reach_box[:, None]))
    if p.size:
        box_i = box_corners(pi[p, t, 0], pi[p, t, 1], a.heading[I[p], t], a.length[I[p]], a.width[I[p]])
        box_j = box_corners(pj[p, t, 0], pj[p, t, 1], b.heading[J[p], t], b.length[J[p]], b.width[J[p]])
        overlap = boxes_overlap(box_i, box_j)
        hit[p[overlap], t[overlap]] = True
    # Motion segments can only cross if the centres are closer than the two step lengths together: test exactly
    # only those (pair, step) candidates (few), not all P x T.
    step_i = np.hypot(*(pi[:, 1:] - pi[:, :-1]).transpose(2, 0, 1))
    step_j = np.hypot(*(pj[:, 1:] - pj[:, :-1]).transpose(2, 0, 1))
    reach = step_i + step_j + 1e-6
    cand = mask[:, 1:] & mask[:, :-1] & ((dist[:, 1:] <= reach) | (dist[:, :-1] <= reach))
    p, t = np.nonzero(cand)
    if p.size:
        seg_hit = segments_intersect(pi[p, t], pi[p, t + 1], pj[p, t], pj[p, t + 1])
        hit[p[seg_hit], t[seg_hit] + 1] = True
    # Count contacts, not contact steps: an extrapolated track driving through a slower vehicle overlaps it for
    # many steps, which as a step count would outweigh every other feature of the pair.
    onsets = hit[:, :1].sum(1) + (hit[:, 1:] & ~hit[:, :-1]).sum(1)
    return onsets.astype(np.float64)
