"""Road projection of decoded candidates: futures that leave the road are re-driven along the road.

Why: the prior decodes bounded controls, so every candidate is within the acceleration and yaw-rate limits by
construction (`seal.models.prior.kinematics`), but nothing makes it follow the map. On the 2,500-scene pool all of
the 8.5 % of candidates that fail the drivability check (`seal.models.prior.metrics`) fail on the road part, two
thirds of them in roundabouts, where candidates cut across the central island or run straight past the ring
(issue 20 note). Steering the latents cannot fix that; a map-aware projection after decoding can.

The projection (on the feasible set: kinematically valid *and* on the lanes):

1. A candidate needs projecting when its centre leaves every lane, i.e. a sample (every ``sample_every`` steps)
   lies farther than half a lane width from every lane centreline (the map's crop edges opened,
   `seal.models.prior.lanes.open_map_edges`). Other candidates are returned bit-for-bit unchanged.
2. Its samples become a reference (`chain_reference`): each reference point is the previous one plus the
   candidate's own move between the two samples; when that lies outside every lane it is pulled toward the
   closest centreline point until it is ``margin_m`` inside that lane, and the move is stretched back to its own
   length in the pulled direction (pulled in once more), so a move that leaves the road turns along it. Up to
   the candidate's first departure the reference is its samples; after it, the chained moves keep its progress
   along the road (the closest lane point of a sample far off the road can lie behind the agent). The reference
   is linear between samples, from the agent's current position.
3. The candidate is driven again from the agent's current position and direction of travel with a unicycle: its
   own speed at every step (so its longitudinal acceleration is unchanged), and the yaw rate of pure pursuit
   toward the reference ``lookahead_steps`` ahead, clipped to the prior's yaw-rate limit. Heading and speed
   recovered from the new positions are exactly the integrated ones, so the kinematic limits still hold.

Units: metres, seconds, radians; 10 Hz steps.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from numba import float64, int64, njit, types

from seal.core.road import RoadDescription
from seal.core.scenario import DT_S
from seal.models.prior.lanes import open_map_edges


@dataclass(frozen=True)
class RoadProjection:
    """Settings of the road projection (module docstring).

    Attributes:
        yaw_rate_limit_rps: |yaw rate| bound of the re-driven candidates (rad/s); the prior's own limit.
        margin_m: how far inside the lane an off-road reference sample is moved (m).
        lookahead_steps: pure-pursuit look-ahead along the reference (steps of 0.1 s).
        sample_every: steps between the samples tested and used as the reference (5 = 0.5 s).
        min_speed_mps: below this speed the heading is held (steering a near-still vehicle is noise).
    """

    yaw_rate_limit_rps: float = 0.98
    margin_m: float = 0.5
    lookahead_steps: int = 10
    sample_every: int = 5
    min_speed_mps: float = 0.3

    def __post_init__(self) -> None:
        if self.yaw_rate_limit_rps <= 0 or self.margin_m < 0 or self.min_speed_mps < 0:
            raise ValueError(f"road projection: need yaw_rate_limit_rps > 0, margin_m >= 0, min_speed_mps >= 0; got "
                             f"{self.yaw_rate_limit_rps}, {self.margin_m}, {self.min_speed_mps}")
        if self.lookahead_steps < 1 or self.sample_every < 1:
            raise ValueError(f"road projection: need lookahead_steps >= 1 and sample_every >= 1; got "
                             f"{self.lookahead_steps}, {self.sample_every}")


GRID_CELL_M = 8.0
"""Cell size of the per-road lookup grid (m): smaller cells hold fewer segments but cost more to fill."""
GRID_PAD_M = 20.0
"""The grid covers the lanes' bounding box grown by this much (m); points beyond it are tested against every
segment."""


@dataclass
class LaneGrid:
    """Every lane centreline segment of a road (crop edges opened) and a uniform grid listing, per cell, the
    segments that can be the least-outside lane of a point in that cell (exact: see `_fill_cell`). Cells are filled
    on first use (a road's candidates touch a few hundred of its thousands of cells), so the kernels that query
    it return the item buffer, which `closest_on_grid` / `project_to_road` store back.

    Attributes:
        a, b: ``[S, 2]`` segment starts and ends (m).
        half_width: ``[S]`` half width of each segment's lane (m).
        origin: ``[2]`` the grid's lower-left corner (m); ``cell_m`` its cell size (m); ``shape`` (nx, ny).
        span: ``[nx * ny, 2]`` where each cell's segments lie in ``items`` (cell ``ix * ny + iy``; -1: not filled).
        items: the segment indices of the filled cells, one after the other (a buffer: ``fill[0]`` are used).
        fill: ``[1]`` the used length of ``items``.
    """

    a: np.ndarray
    b: np.ndarray
    half_width: np.ndarray
    origin: np.ndarray
    cell_m: float
    shape: tuple[int, int]
    span: np.ndarray
    items: np.ndarray
    fill: np.ndarray


def lane_grid(road: RoadDescription, cell_m: float = GRID_CELL_M) -> LaneGrid:
    """`LaneGrid` of ``road`` with the lanes that leave the map continued (`open_map_edges`), no cell filled."""
    a_parts, b_parts, hw_parts = [], [], []
    for lane in open_map_edges(road).lanes:
        c = np.asarray(lane.centerline, np.float64)
        a_parts.append(c[:-1])
        b_parts.append(c[1:])
        hw_parts.append(np.full(len(c) - 1, lane.width_m / 2.0))
    a = np.ascontiguousarray(np.concatenate(a_parts))
    b = np.ascontiguousarray(np.concatenate(b_parts))
    hw = np.ascontiguousarray(np.concatenate(hw_parts))
    lo = np.minimum(a.min(0), b.min(0)) - GRID_PAD_M
    size = np.maximum(a.max(0), b.max(0)) + GRID_PAD_M - lo
    nx, ny = (int(v) for v in np.ceil(size / cell_m).astype(np.int64))
    return LaneGrid(a, b, hw, lo, float(cell_m), (nx, ny), np.full((nx * ny, 2), -1, np.int64),
                    np.empty(1024, np.int64), np.zeros(1, np.int64))


def _road_key(road: RoadDescription) -> bytes:
    """Content key of a road's lanes: scenarios of one traffic run carry equal roads as different objects."""
    h = hashlib.blake2b(digest_size=16)
    for lane in road.lanes:
        h.update(np.ascontiguousarray(lane.centerline, np.float64).tobytes())
        h.update(np.float64(lane.width_m).tobytes())
        h.update(b"|" if lane.successors else b".")
    return h.digest()


class GridCache:
    """Small LRU cache of `lane_grid` keyed by the road's content (`_road_key`), so a generator builds one grid per
    distinct road and not per scenario (26 distinct roads among the 100 eval scenes of the default pool)."""

    def __init__(self, max_roads: int = 256) -> None:
        self.max_roads = max_roads
        self._entries: OrderedDict[bytes, LaneGrid] = OrderedDict()
        self._last: tuple[RoadDescription, LaneGrid] | None = None

    def get(self, road: RoadDescription) -> LaneGrid:
        if self._last is not None and self._last[0] is road:  # the K passes of one scenario: skip the hash
            return self._last[1]
        key = _road_key(road)
        grid = self._entries.get(key)
        if grid is None:
            grid = lane_grid(road)
            self._entries[key] = grid
            if len(self._entries) > self.max_roads:
                self._entries.popitem(last=False)
        else:
            self._entries.move_to_end(key)
        self._last = (road, grid)
        return grid


@njit(float64(float64, float64, float64[:, ::1], float64[:, ::1], float64[::1], int64), cache=True, nogil=True,
      error_model="numpy")
def _excess(x: float, y: float, a: np.ndarray, b: np.ndarray, half_width: np.ndarray, k: int) -> float:
    """How far (x, y) lies outside segment ``k``'s lane: distance to the segment minus the half width (m)."""
    ex = b[k, 0] - a[k, 0]
    ey = b[k, 1] - a[k, 1]
    px = x - a[k, 0]
    py = y - a[k, 1]
    len2 = ex * ex + ey * ey
    t = 0.0 if len2 <= 1e-18 else min(max((px * ex + py * ey) / len2, 0.0), 1.0)
    dx = px - t * ex
    dy = py - t * ey
    return math.sqrt(dx * dx + dy * dy) - half_width[k]


_GRID_ARGS = (float64[:, ::1], float64[:, ::1], float64[::1], float64, float64, float64, int64, int64, int64[:, ::1],
              int64[::1], int64[::1])
"""Numba types of a `LaneGrid` passed to the kernels: a, b, half_width, x0, y0, cell, nx, ny, span, items, fill."""


@njit(int64[::1](int64, float64[:, ::1], float64[:, ::1], float64[::1], float64, float64, float64, int64,
                 int64[:, ::1], int64[::1], int64[::1]), cache=True, nogil=True, error_model="numpy")
def _fill_cell(c: int, a: np.ndarray, b: np.ndarray, half_width: np.ndarray, x0: float, y0: float, cell: float,
               ny: int, span: np.ndarray, items: np.ndarray, fill: np.ndarray) -> np.ndarray:
    """List cell ``c``'s segments: those whose excess at the cell centre is within ``2 r`` of the smallest (``r`` the
    half diagonal). A point of the cell is at most ``r`` from the centre and each excess is 1-Lipschitz, so its
    least-outside segment is among them. Returns the item buffer (a new one when it had to grow)."""
    cx = x0 + (c // ny + 0.5) * cell
    cy = y0 + (c % ny + 0.5) * cell
    n_seg = a.shape[0]
    tmp = np.empty(n_seg)
    best = math.inf
    for k in range(n_seg):
        tmp[k] = _excess(cx, cy, a, b, half_width, k)
        best = min(best, tmp[k])
    band = best + cell * math.sqrt(2.0) + 1e-9
    n = fill[0]
    for k in range(n_seg):
        if tmp[k] <= band:
            if n == items.shape[0]:
                grown = np.empty(2 * n, np.int64)
                grown[:n] = items
                items = grown
            items[n] = k
            n += 1
    span[c, 0] = fill[0]
    span[c, 1] = n
    fill[0] = n
    return items


@njit(types.Tuple((float64, float64, float64, int64[::1]))(float64, float64, *_GRID_ARGS), cache=True, nogil=True,
      error_model="numpy")
def _closest_one(x: float, y: float, a: np.ndarray, b: np.ndarray, half_width: np.ndarray, x0: float, y0: float,
                 cell: float, nx: int, ny: int, span: np.ndarray, items: np.ndarray, fill: np.ndarray
                 ) -> tuple[float, float, float, np.ndarray]:
    """`closest_lane_points` of one point: ``(qx, qy, excess, items)`` (the item buffer, see `_fill_cell`)."""
    ix = int(math.floor((x - x0) / cell))
    iy = int(math.floor((y - y0) / cell))
    if 0 <= ix < nx and 0 <= iy < ny:
        c = ix * ny + iy
        if span[c, 0] < 0:
            items = _fill_cell(c, a, b, half_width, x0, y0, cell, ny, span, items, fill)
        cands = items[span[c, 0]:span[c, 1]]
    else:  # beyond the grid: every segment
        cands = np.arange(a.shape[0])
    best = math.inf
    best_k = -1
    for k in cands:
        e = _excess(x, y, a, b, half_width, k)
        if e < best:
            best, best_k = e, k
    ex = b[best_k, 0] - a[best_k, 0]
    ey = b[best_k, 1] - a[best_k, 1]
    len2 = ex * ex + ey * ey
    t = 0.0 if len2 <= 1e-18 else min(max(((x - a[best_k, 0]) * ex + (y - a[best_k, 1]) * ey) / len2, 0.0), 1.0)
    return a[best_k, 0] + t * ex, a[best_k, 1] + t * ey, best, items


@njit(types.Tuple((float64[:, ::1], float64[::1], int64[::1]))(float64[:, ::1], *_GRID_ARGS), cache=True,
      nogil=True, error_model="numpy")
def closest_lane_points(points: np.ndarray, a: np.ndarray, b: np.ndarray, half_width: np.ndarray, x0: float,
                        y0: float, cell: float, nx: int, ny: int, span: np.ndarray, items: np.ndarray,
                        fill: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each point ``[N, 2]``: the closest centreline point ``[N, 2]`` of the lane it is least outside of, and
    how far it is outside that lane ``[N]`` (distance minus half width, m; <= 0 means on the lane). The first such
    segment in segment order wins a tie (cell lists are in segment order), as a scan of every segment would. Also
    returns the grid's item buffer (`_fill_cell`)."""
    n = points.shape[0]
    q = np.empty((n, 2))
    excess = np.empty(n)
    for i in range(n):
        q[i, 0], q[i, 1], excess[i], items = _closest_one(points[i, 0], points[i, 1], a, b, half_width, x0, y0, cell,
                                                          nx, ny, span, items, fill)
    return q, excess, items


@njit(types.Tuple((float64, float64, int64[::1]))(float64, float64, float64, *_GRID_ARGS), cache=True,
      nogil=True, error_model="numpy")
def _pull_in(x: float, y: float, margin: float, a: np.ndarray, b: np.ndarray, half_width: np.ndarray, x0: float,
             y0: float, cell: float, nx: int, ny: int, span: np.ndarray, items: np.ndarray, fill: np.ndarray
             ) -> tuple[float, float, np.ndarray]:
    """(x, y) when it lies on a lane, else moved toward the closest centreline point to ``margin`` m inside that
    lane; and the grid's item buffer."""
    cx, cy, e, items = _closest_one(x, y, a, b, half_width, x0, y0, cell, nx, ny, span, items, fill)
    if e <= 0.0:
        return x, y, items
    dist = math.sqrt((x - cx) ** 2 + (y - cy) ** 2)
    keep = max(dist - e - margin, 0.0) / max(dist, 1e-12)  # distance - excess = the half width
    return cx + (x - cx) * keep, cy + (y - cy) * keep, items


@njit(types.Tuple((float64[:, :, ::1], int64[::1]))(float64[:, :, ::1], int64[::1], float64, float64, float64,
                                                     *_GRID_ARGS), cache=True, nogil=True, error_model="numpy")
def chain_reference(samples: np.ndarray, rows: np.ndarray, x0: float, y0: float, margin: float, a: np.ndarray,
                    b: np.ndarray, half_width: np.ndarray, gx: float, gy: float, cell: float, nx: int, ny: int,
                    span: np.ndarray, items: np.ndarray, fill: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """References ``[len(rows), S, 2]`` of the candidates ``rows`` of ``samples [K, S, 2]`` starting at (x0, y0):
    each reference point is the previous one plus the candidate's own move between the two samples; when that lies
    outside every lane it is pulled toward the closest centreline point until it is ``margin`` m inside that lane
    (`_pull_in`), then the move is stretched back to its own length in the pulled direction and pulled in once more
    (so a move that leaves the road turns along it instead of shrinking).

    Chaining the moves keeps the candidate's progress: a sample far off the road has its closest lane point
    somewhere behind, which a point-wise projection would make the reference go back to. Also returns the grid's
    item buffer (`_fill_cell`)."""
    out = np.empty((rows.shape[0], samples.shape[1], 2))
    for m in range(rows.shape[0]):
        r = rows[m]
        px = x0
        py = y0
        qx_prev = x0
        qy_prev = y0
        for j in range(samples.shape[1]):
            dx = samples[r, j, 0] - qx_prev
            dy = samples[r, j, 1] - qy_prev
            qx_prev = samples[r, j, 0]
            qy_prev = samples[r, j, 1]
            step = math.sqrt(dx * dx + dy * dy)
            rx, ry, items = _pull_in(px + dx, py + dy, margin, a, b, half_width, gx, gy, cell, nx, ny, span, items,
                                     fill)
            moved = math.sqrt((rx - px) ** 2 + (ry - py) ** 2)
            if moved > 1e-9 and abs(moved - step) > 1e-9:  # pulled in: restore the move's length along the road
                rx, ry, items = _pull_in(px + (rx - px) * step / moved, py + (ry - py) * step / moved, margin, a, b,
                                         half_width, gx, gy, cell, nx, ny, span, items, fill)
            px = rx
            py = ry
            out[m, j, 0] = px
            out[m, j, 1] = py
    return out, items


def _grid_args(grid: LaneGrid) -> tuple:
    return (grid.a, grid.b, grid.half_width, float(grid.origin[0]), float(grid.origin[1]), grid.cell_m,
            grid.shape[0], grid.shape[1], grid.span, grid.items, grid.fill)


def closest_on_grid(points: np.ndarray, grid: LaneGrid) -> tuple[np.ndarray, np.ndarray]:
    """`closest_lane_points` of ``points [N, 2]`` (m) on ``grid`` (filling its cells as needed)."""
    q, excess, grid.items = closest_lane_points(np.ascontiguousarray(points, np.float64), *_grid_args(grid))
    return q, excess


@njit(float64[:, :, ::1](float64[:, :, ::1], int64[::1], float64[:, ::1], int64[::1], float64, float64, float64,
                         int64, float64, float64, float64), cache=True, nogil=True, error_model="numpy")
def pursue(reference: np.ndarray, sample_steps: np.ndarray, speed: np.ndarray, rows: np.ndarray, x0: float,
           y0: float, course: float, lookahead: int, yaw_limit: float, min_speed: float, dt: float) -> np.ndarray:
    """Positions ``[len(rows), T, 2]`` of unicycles from ``(x0, y0)`` heading ``course`` (rad), one per row of
    ``rows``: at ``speed[row] [T]`` (m/s, step ``t``'s speed), steering by pure pursuit toward the reference
    ``lookahead`` steps ahead, |yaw rate| <= ``yaw_limit`` (rad/s); below ``min_speed`` (m/s) the heading is held.

    The reference of a row is ``reference[row] [S, 2]`` at steps ``sample_steps [S]`` (increasing), linear in
    between and from the start point at step -1. Step ``t`` is ``(t + 1) dt`` s ahead.
    """
    n = speed.shape[1]
    n_s = sample_steps.shape[0]
    out = np.empty((rows.shape[0], n, 2))
    for m in range(rows.shape[0]):
        r = rows[m]
        x = x0
        y = y0
        theta = course
        seg = 0  # reference segment: between sample seg - 1 (the start when 0) and sample seg
        for t in range(n):
            j = min(t + lookahead - 1, sample_steps[n_s - 1])
            while sample_steps[seg] < j:
                seg += 1
            t0 = -1.0 if seg == 0 else float(sample_steps[seg - 1])
            ax = x0 if seg == 0 else reference[r, seg - 1, 0]
            ay = y0 if seg == 0 else reference[r, seg - 1, 1]
            w = (j - t0) / (sample_steps[seg] - t0)
            dx = ax + w * (reference[r, seg, 0] - ax) - x
            dy = ay + w * (reference[r, seg, 1] - ay) - y
            dist = math.sqrt(dx * dx + dy * dy)
            v = speed[r, t]
            if v > min_speed and dist > 1e-3:
                alpha = math.atan2(dy, dx) - theta
                alpha = math.atan2(math.sin(alpha), math.cos(alpha))
                omega = min(max(2.0 * v * math.sin(alpha) / dist, -yaw_limit), yaw_limit)
                theta += omega * dt
            x += v * dt * math.cos(theta)
            y += v * dt * math.sin(theta)
            out[m, t, 0] = x
            out[m, t, 1] = y
    return out


def project_to_road(xy: np.ndarray, start_xy: np.ndarray, course_rad: float, grid: LaneGrid,
                    cfg: RoadProjection, dt_s: float = DT_S) -> tuple[np.ndarray, np.ndarray]:
    """Candidates ``xy [K, T, 2]`` (world, m) of one agent at ``start_xy`` moving along ``course_rad`` projected on
    the road (module docstring).

    Returns:
        the projected candidates ``[K, T, 2]`` (rows that needed no projection are the input rows) and ``[K]``
        True where a candidate was re-driven.
    """
    xy = np.asarray(xy, np.float64)
    k, t, _ = xy.shape
    start = np.asarray(start_xy, np.float64)
    idx = np.arange(cfg.sample_every - 1, t, cfg.sample_every)
    if idx.size == 0 or idx[-1] != t - 1:
        idx = np.append(idx, t - 1)  # the end of the horizon is always tested
    samples = xy[:, idx].reshape(-1, 2)
    _, excess = closest_on_grid(samples, grid)
    moved: np.ndarray = np.asarray((excess > 0.0).reshape(k, -1).any(axis=1))
    if not moved.any():
        return xy, moved
    out = xy.copy()
    rows = np.flatnonzero(moved).astype(np.int64)
    ref, grid.items = chain_reference(np.ascontiguousarray(samples.reshape(k, -1, 2)), rows, float(start[0]),
                                      float(start[1]), cfg.margin_m, *_grid_args(grid))
    prev = np.concatenate([np.broadcast_to(start, (k, 1, 2)), xy[:, :-1]], axis=1)
    speed = np.ascontiguousarray(np.linalg.norm(xy - prev, axis=-1)[rows] / dt_s)
    out[rows] = pursue(ref, idx.astype(np.int64), speed, np.arange(len(rows), dtype=np.int64), float(start[0]),
                       float(start[1]), float(course_rad), cfg.lookahead_steps, cfg.yaw_rate_limit_rps,
                       cfg.min_speed_mps, dt_s)
    return out, moved
