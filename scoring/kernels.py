"""Compiled (numba) kernels of the scoring's per-agent loops: polyline projection and evaluation (Frenet <-> world
for the future-extrapolated tracks) and the dwell ranking of an agent's logged lanes.

Why compiled: `seal.scoring.extrapolation` handles each agent on its own lane chain, about 20 agents per scenario,
with a dozen small numpy calls each; the call overhead cost more than the arithmetic. The kernels do in float64
the operations of the numpy code they replace (`seal.scoring.frenet.Polyline`'s ``project`` / ``at``), which the
tests keep as the reference.

Explicit signatures: numba compiles each kernel (or loads it from its on-disk cache, ``cache=True``) when this
module is imported, so no scoring worker stalls on a first call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import float64, int64, njit, types

from seal.core.kernels import corner_boxes_overlap


@njit(types.UniTuple(float64, 3)(float64[:, ::1], float64[::1], float64[:, ::1], float64[::1], float64, float64),
      cache=True, nogil=True, error_model="numpy")
def polyline_project(
    points: np.ndarray, cum: np.ndarray, tang: np.ndarray, seg_len: np.ndarray, x: float, y: float,
) -> tuple[float, float, float]:
    """Arc length ``s`` (m), signed lateral offset ``d`` (m, left positive) and the index (as a float) of the
    closest segment of the polyline ``points [P, 2]`` (arc lengths ``cum [P]``, unit tangents ``tang [P-1, 2]``,
    segment lengths ``seg_len [P-1]``) to the point ``(x, y)``; the first of equally close segments."""
    best = np.inf
    best_k = 0
    best_t = 0.0
    for k in range(seg_len.shape[0]):
        rx = x - points[k, 0]
        ry = y - points[k, 1]
        t = (rx * tang[k, 0] + ry * tang[k, 1]) / seg_len[k]
        t = min(max(t, 0.0), 1.0)
        ex = rx - t * seg_len[k] * tang[k, 0]
        ey = ry - t * seg_len[k] * tang[k, 1]
        dist2 = ex * ex + ey * ey
        if dist2 < best:
            best = dist2
            best_k = k
            best_t = t
    rx = x - points[best_k, 0]
    ry = y - points[best_k, 1]
    cross = tang[best_k, 0] * ry - tang[best_k, 1] * rx
    sign = 1.0 if cross > 0 else (-1.0 if cross < 0 else 0.0)
    return cum[best_k] + best_t * seg_len[best_k], sign * math.sqrt(best), float(best_k)


@njit(types.Tuple((float64[:, ::1], float64[::1], int64[::1]))(
    float64[:, ::1], float64[::1], float64[:, ::1], float64[:, ::1], float64[::1], float64),
    cache=True, nogil=True, error_model="numpy")
def polyline_at(
    points: np.ndarray, cum: np.ndarray, tang: np.ndarray, vertex_tang: np.ndarray, s: np.ndarray, d: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points ``[K, 2]`` at arc lengths ``s [K]`` (m) shifted ``d`` metres to the left, their headings ``[K]``
    (rad) and the segment index ``[K]`` each lies on (clipped to the polyline's segments).

    Positions and tangents are interpolated linearly between vertices (vertex tangents ``vertex_tang [P, 2]``);
    beyond the ends the first / last segment is extended as a straight line.
    """
    n = s.shape[0]
    n_pts = cum.shape[0]
    out = np.empty((n, 2))
    heading = np.empty(n)
    seg = np.empty(n, dtype=np.int64)
    length = cum[n_pts - 1]
    for i in range(n):
        inside = min(max(s[i], 0.0), length)
        k = np.searchsorted(cum, s[i], side="right") - 1
        k = min(max(k, 0), n_pts - 2)
        seg[i] = k
        kk = np.searchsorted(cum, inside, side="right") - 1
        kk = min(max(kk, 0), n_pts - 2)
        frac = (inside - cum[kk]) / (cum[kk + 1] - cum[kk])
        x = points[kk, 0] + frac * (points[kk + 1, 0] - points[kk, 0])
        y = points[kk, 1] + frac * (points[kk + 1, 1] - points[kk, 1])
        tx = vertex_tang[kk, 0] + frac * (vertex_tang[kk + 1, 0] - vertex_tang[kk, 0])
        ty = vertex_tang[kk, 1] + frac * (vertex_tang[kk + 1, 1] - vertex_tang[kk, 1])
        over = s[i] - inside
        if over != 0.0:
            e = tang.shape[0] - 1 if s[i] > length else 0
            x += over * tang[e, 0]
            y += over * tang[e, 1]
            tx = tang[e, 0]
            ty = tang[e, 1]
        norm = max(math.hypot(tx, ty), 1e-12)
        tx /= norm
        ty /= norm
        out[i, 0] = x - d * ty
        out[i, 1] = y + d * tx
        heading[i] = math.atan2(ty, tx)
    return out, heading, seg


@njit(int64[::1](int64[::1]), cache=True, nogil=True, error_model="numpy")
def rank_by_dwell(lanes: np.ndarray) -> np.ndarray:
    """The distinct non-negative values of ``lanes`` ordered by how often they occur (most first), ties by first
    occurrence."""
    values = np.empty(lanes.shape[0], dtype=np.int64)
    counts = np.zeros(lanes.shape[0], dtype=np.int64)
    n = 0
    for lane in lanes:
        if lane < 0:
            continue
        for k in range(n):
            if values[k] == lane:
                counts[k] += 1
                break
        else:
            values[n] = lane
            counts[n] = 1
            n += 1
    order = np.argsort(-counts[:n], kind="mergesort")  # stable: ties keep first-occurrence order
    return values[:n][order]


@njit(float64[::1](
    int64[::1], int64[::1], types.boolean[::1], types.boolean[::1], types.boolean[:, ::1],
    float64[:, ::1], float64[:, ::1], float64[:, ::1], int64[::1], int64[::1], int64[::1], float64[::1],
    int64[::1], int64[::1],
    float64[:, ::1], float64[:, ::1], float64[:, ::1], int64[::1], int64[::1], int64[::1], float64[::1],
    int64[::1], int64[::1], int64[::1],
    float64, float64, float64), cache=True, nogil=True, error_model="numpy")
def agent_mttcp(
    I: np.ndarray, J: np.ndarray, st_i: np.ndarray, st_j: np.ndarray, mask: np.ndarray,
    ax: np.ndarray, ay: np.ndarray, aspeed: np.ndarray, a_runs: np.ndarray, a_step: np.ndarray,
    a_run_start: np.ndarray, a_points_x: np.ndarray, a_valid_start: np.ndarray, a_valid_end: np.ndarray,
    bx: np.ndarray, by: np.ndarray, bspeed: np.ndarray, b_runs: np.ndarray, b_step: np.ndarray,
    b_run_end: np.ndarray, b_sorted_x: np.ndarray, b_sorted_run: np.ndarray, b_valid_start: np.ndarray,
    b_valid_end: np.ndarray,
    radius_m: float, speed_eps: float, min_time_s: float,
) -> np.ndarray:
    """``[P]`` inverse minimum time difference to the agent-path conflict points of pairs ``(I[p] of set a,
    J[p] of set b)`` (`seal.scoring.social`'s ``inv_mttcp_agents``, whose numpy form the tests keep as the
    reference).

    Set a is seen through the *last* step of each run of repeated positions, set b through the *first* (see
    `seal.scoring.social.TrackContext`): ``a_runs [A+1]`` / ``b_runs [B+1]`` are each agent's range of runs,
    ``a_step`` / ``b_step`` the run's step (last / first), ``a_run_start`` / ``b_run_end`` its other end,
    ``a_points_x`` the run's x (m; y is read from ``ay``), and per agent of b its runs sorted by x
    (``b_sorted_x``, ``b_sorted_run``, within the agent's range) so that the 1 m neighbours of a point are a short
    scan. Tracks ``ax, ay, aspeed [A, T]`` (m, m/s), validity ranges per agent, stationary flags per pair and the
    both-valid mask ``[P, T]``.
    """
    n, n_steps = mask.shape
    out = np.zeros(n)
    first_j = np.empty(n_steps, dtype=np.int64)
    r2 = radius_m * radius_m
    for p in range(n):
        i = I[p]
        j = J[p]
        first_j[:] = n_steps
        lo_b = b_runs[j]
        hi_b = b_runs[j + 1]
        any_hit = False
        for ra in range(a_runs[i], a_runs[i + 1]):
            px = a_points_x[ra]
            py = ay[i, a_step[ra]]
            k = lo_b + np.searchsorted(b_sorted_x[lo_b:hi_b], px - radius_m)
            while k < hi_b and b_sorted_x[k] <= px + radius_m:
                rb = b_sorted_run[k]
                k += 1
                dx = px - bx[j, b_step[rb]]
                dy = py - by[j, b_step[rb]]
                if dx * dx + dy * dy > r2:
                    continue
                # Latest step of i's run where j is valid too, earliest step of j's run where i is valid too.
                ti = min(a_step[ra], b_valid_end[j])
                tj = max(b_step[rb], a_valid_start[i])
                inside = ti >= max(a_run_start[ra], b_valid_start[j]) and tj <= min(b_run_end[rb], a_valid_end[i])
                if inside and tj < first_j[ti]:
                    first_j[ti] = tj
                    any_hit = True
        if not any_hit:
            continue
        best = np.inf
        for ti in range(n_steps):
            tj = first_j[ti]
            if tj >= n_steps:
                continue
            cx = ax[i, ti]
            cy = ay[i, ti]
            for t in range(min(ti, tj) + 1):  # only steps before the first of the two reaches the point
                if not mask[p, t]:
                    continue
                t_i = 0.0 if st_i[p] else math.hypot(ax[i, t] - cx, ay[i, t] - cy) / (aspeed[i, t] + speed_eps)
                t_j = 0.0 if st_j[p] else math.hypot(bx[j, t] - cx, by[j, t] - cy) / (bspeed[j, t] + speed_eps)
                diff = abs(t_i - t_j)
                if diff < best:
                    best = diff
        if best < np.inf:
            out[p] = 1.0 / max(best, min_time_s)
    return out


_CELL_OFFSET = 1 << 20
"""Grid cell coordinates are shifted by this so that cell keys of any point within ~4,700 km are non-negative."""


def cell_keys(xy: np.ndarray, origin: np.ndarray, cell_m: float) -> np.ndarray:
    """``[N]`` int64 keys of the grid cells (side ``cell_m`` m, corner ``origin [2]``) of points ``xy [N, 2]``."""
    c = np.floor((xy - origin) / cell_m).astype(np.int64) + _CELL_OFFSET
    return c[:, 0] * (2 * _CELL_OFFSET) + c[:, 1]


@njit(types.Tuple((int64[::1], float64[::1], float64[::1], types.boolean[::1]))(
    float64[:, ::1], float64[::1], types.boolean, float64[::1], float64,
    int64[::1], int64[::1], int64[::1],
    float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64[::1], float64[::1], float64,
    int64[::1], float64[::1], float64[::1], float64), cache=True, nogil=True, error_model="numpy")
def project_points(
    xy: np.ndarray, heading: np.ndarray, use_heading: bool, origin: np.ndarray, cell_m: float,
    cells: np.ndarray, cell_start: np.ndarray, cell_seg: np.ndarray,
    seg_a: np.ndarray, seg_d: np.ndarray, seg_len2: np.ndarray, seg_len: np.ndarray, seg_cos: np.ndarray,
    seg_sin: np.ndarray, cos_max: float,
    seg_lane: np.ndarray, seg_s0: np.ndarray, widths: np.ndarray, max_dist_widths: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Closest compatible lane segment of each point ``xy [N, 2]`` (m): lane, arc length ``s`` (m), signed offset
    ``d`` (m, left positive) and in-lane flag (`seal.scoring.frenet.RoadIndex.project`, whose numpy form the tests
    keep as the reference).

    Candidates are the segments with a sample point (every <= 4 m along the segment) in the 3 x 3 grid cells
    (side ``cell_m`` >= the largest assignment distance plus half the sample spacing) around the point:
    ``cells [M]`` the sorted occupied cell keys (`cell_keys`), ``cell_start [M+1]`` each cell's range in
    ``cell_seg`` (the segment of each sample). With ``use_heading``,
    segments more than the maximum heading difference off the point's ``heading [N]`` (cosine below
    ``cos_max``) are not candidates. A point farther than ``max_dist_widths`` lane widths from its closest
    candidate gets lane -1 and NaN ``s`` / ``d``.
    """
    n = xy.shape[0]
    lane = np.full(n, -1, dtype=np.int64)
    s = np.full(n, np.nan)
    d = np.full(n, np.nan)
    in_lane = np.zeros(n, dtype=np.bool_)
    two = 2 * _CELL_OFFSET
    for p in range(n):
        px = xy[p, 0]
        py = xy[p, 1]
        cx = int(math.floor((px - origin[0]) / cell_m)) + _CELL_OFFSET
        cy = int(math.floor((py - origin[1]) / cell_m)) + _CELL_OFFSET
        if use_heading:
            ch = math.cos(heading[p])
            sh = math.sin(heading[p])
        best2 = np.inf
        best_k = -1
        best_t = 0.0
        for dx in range(-1, 2):
            for dy in range(-1, 2):
                key = (cx + dx) * two + (cy + dy)
                c = np.searchsorted(cells, key)
                if c >= cells.shape[0] or cells[c] != key:
                    continue
                for q in range(cell_start[c], cell_start[c + 1]):
                    k = cell_seg[q]
                    if use_heading and ch * seg_cos[k] + sh * seg_sin[k] < cos_max:
                        continue
                    rx = px - seg_a[k, 0]
                    ry = py - seg_a[k, 1]
                    t = (rx * seg_d[k, 0] + ry * seg_d[k, 1]) / seg_len2[k]
                    t = min(max(t, 0.0), 1.0)
                    ex = rx - t * seg_d[k, 0]
                    ey = ry - t * seg_d[k, 1]
                    dist2 = ex * ex + ey * ey
                    if dist2 < best2:
                        best2 = dist2
                        best_k = k
                        best_t = t
        if best_k < 0:
            continue
        best = math.sqrt(best2)
        w = widths[seg_lane[best_k]]
        if best > max_dist_widths * w:
            continue
        rx = px - seg_a[best_k, 0]
        ry = py - seg_a[best_k, 1]
        cross = (seg_d[best_k, 0] * ry - seg_d[best_k, 1] * rx) / seg_len[best_k]
        sign = 1.0 if cross > 0 else (-1.0 if cross < 0 else 0.0)
        lane[p] = seg_lane[best_k]
        s[p] = seg_s0[best_k] + best_t * seg_len[best_k]
        # Past a lane's end the closest point is the end point: the lateral offset is then the full distance.
        d[p] = sign * best
        in_lane[p] = best <= 0.5 * w
    return lane, s, d, in_lane


_CORNER_SIGNS = ((0.5, 0.5), (0.5, -0.5), (-0.5, -0.5), (-0.5, 0.5))
"""Corner order of `seal.core.geometry.box_corners` (front left, front right, rear right, rear left)."""


@njit(cache=True, nogil=True, error_model="numpy")
def _corners(x: float, y: float, heading: float, length: float, width: float, out: np.ndarray) -> None:
    """Corners ``out [4, 2]`` (m) of a box, as `seal.core.geometry.box_corners`."""
    c = math.cos(heading)
    s = math.sin(heading)
    for k in range(4):
        dl = _CORNER_SIGNS[k][0] * length
        dw = _CORNER_SIGNS[k][1] * width
        out[k, 0] = x + dl * c - dw * s
        out[k, 1] = y + dl * s + dw * c


@njit(cache=True, nogil=True, error_model="numpy")
def _orient(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> float:
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(cache=True, nogil=True, error_model="numpy")
def _on_segment(ax: float, ay: float, bx: float, by: float, cx: float, cy: float) -> bool:
    return min(ax, bx) <= cx <= max(ax, bx) and min(ay, by) <= cy <= max(ay, by)


@njit(cache=True, nogil=True, error_model="numpy")
def segments_cross(
    p0x: float, p0y: float, p1x: float, p1y: float, q0x: float, q0y: float, q1x: float, q1y: float,
) -> bool:
    """Whether segments p0-p1 and q0-q1 intersect, touching included (`seal.scoring.social.segments_intersect`)."""
    d1 = _orient(q0x, q0y, q1x, q1y, p0x, p0y)
    d2 = _orient(q0x, q0y, q1x, q1y, p1x, p1y)
    d3 = _orient(p0x, p0y, p1x, p1y, q0x, q0y)
    d4 = _orient(p0x, p0y, p1x, p1y, q1x, q1y)
    if ((d1 > 0 and d2 < 0) or (d1 < 0 and d2 > 0)) and ((d3 > 0 and d4 < 0) or (d3 < 0 and d4 > 0)):
        return True
    return (
        (d1 == 0 and _on_segment(q0x, q0y, q1x, q1y, p0x, p0y))
        or (d2 == 0 and _on_segment(q0x, q0y, q1x, q1y, p1x, p1y))
        or (d3 == 0 and _on_segment(p0x, p0y, p1x, p1y, q0x, q0y))
        or (d4 == 0 and _on_segment(p0x, p0y, p1x, p1y, q1x, q1y))
    )


@njit(float64[::1](
    int64[::1], int64[::1], types.boolean[:, ::1],
    float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[::1],
    float64[:, ::1], float64[:, ::1], float64[:, ::1], float64[::1], float64[::1], float64),
    cache=True, nogil=True, error_model="numpy")
def pair_contacts(
    I: np.ndarray, J: np.ndarray, mask: np.ndarray,
    ax: np.ndarray, ay: np.ndarray, ah: np.ndarray, alen: np.ndarray, awid: np.ndarray,
    bx: np.ndarray, by: np.ndarray, bh: np.ndarray, blen: np.ndarray, bwid: np.ndarray, centre_dist_m: float,
) -> np.ndarray:
    """``[P]`` contacts of pairs ``(I[p] of set a, J[p] of set b)`` over the steps where ``mask [P, T]`` (both
    valid): runs of consecutive contact steps, a contact step being one where the centres are within
    ``centre_dist_m``, the oriented boxes overlap, or the per-step motion segments of the centres cross
    (`seal.scoring.social`'s ``collisions``, whose numpy form the tests keep as the reference). Tracks: centres
    ``x, y [A, T]`` (m), headings ``[A, T]`` (rad), lengths and widths ``[A]`` (m)."""
    n, n_steps = mask.shape
    out = np.zeros(n)
    box_a = np.empty((4, 2))
    box_b = np.empty((4, 2))
    for p in range(n):
        i = I[p]
        j = J[p]
        reach_box = 0.5 * (math.hypot(alen[i], awid[i]) + math.hypot(blen[j], bwid[j]))
        prev_hit = False
        prev_dist = 0.0
        count = 0
        for t in range(n_steps):
            if not mask[p, t]:
                prev_hit = False
                continue
            dist = math.hypot(ax[i, t] - bx[j, t], ay[i, t] - by[j, t])
            hit = dist <= centre_dist_m
            if not hit and dist <= reach_box:
                _corners(ax[i, t], ay[i, t], ah[i, t], alen[i], awid[i], box_a)
                _corners(bx[j, t], by[j, t], bh[j, t], blen[j], bwid[j], box_b)
                hit = corner_boxes_overlap(box_a, box_b)
            if not hit and t > 0 and mask[p, t - 1]:
                # Motion segments can only cross if the centres are closer than the two step lengths together.
                step_i = math.hypot(ax[i, t] - ax[i, t - 1], ay[i, t] - ay[i, t - 1])
                step_j = math.hypot(bx[j, t] - bx[j, t - 1], by[j, t] - by[j, t - 1])
                reach = step_i + step_j + 1e-6
                if dist <= reach or prev_dist <= reach:
                    hit = segments_cross(ax[i, t - 1], ay[i, t - 1], ax[i, t], ay[i, t],
                                         bx[j, t - 1], by[j, t - 1], bx[j, t], by[j, t])
            if hit and not prev_hit:
                count += 1
            prev_hit = hit
            prev_dist = dist
        out[p] = count
    return out
