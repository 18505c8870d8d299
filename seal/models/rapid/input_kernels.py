"""Compiled (numba) input building of the RAPID step: the map read-out through a per-road segment grid
(`segment_grid`, `closest_points_grid`) and every per-agent input of `seal.models.rapid.features.agent_inputs`
but the neighbours in one pass (`own_inputs`).

Why compiled: the numpy form of the inputs (Fourier encoding, the local map read-out, a dozen ``column_stack`` /
``where`` tables per step) was ~0.25 ms of per-agent cost at 120 agents and ~0.15 ms of fixed cost at 5, on one
thread. `own_inputs` does in float64 the numpy code's operations, in its order, and rounds to float32 once at
the end, as ``astype(np.float32)`` did (a test holds the two equal). It calls `_nearest`, so both live in this
file (numba's on-disk cache checks only the caller's file for changes). Explicit signatures: compiled (or loaded
from the cache) at import.
"""

from __future__ import annotations

import math

import numpy as np
from numba import float32, float64, int64, njit, types

# Track columns (`seal.core.scenario`) and constants of `seal.models.rapid.features`, repeated here because numba
# freezes globals into its on-disk cache, which checks only this file for changes (a test holds them equal).
_X, _Y, _H, _VX, _VY = 0, 1, 2, 3, 4
_DT_S = 0.1
_ACC_SCALE_MPS2 = 3.0
_AHEAD_M = 15.0
"""Distance ahead (m) of the second lane-centre read-out (`seal.models.rapid.features.local_map`)."""
_NO_EDGE_M = 50.0
"""Offset (m, along x and y) of the stand-in edge point of a road without edges (`local_map`)."""
N_OPT = 8
"""Columns of `own_inputs`' optional-input table: previous acceleration (2), desired speed (1), destination (3),
leader (2): the `seal.models.rapid.features.AgentInputs` fields in `seal.models.rapid.fast.OPTIONAL`'s order."""


@njit(types.Tuple((float64[::1], int64[::1], int64[::1]))(float64[:, ::1], float64), cache=True, nogil=True,
      error_model="numpy")
def segment_grid(cols: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A uniform grid over the segments ``cols [4, n]`` (rows a x, a y, e x, e y, m) with ``cell``-metre cells:
    ``meta [4]`` (x, y of the lower-left corner, cells along x, along y), ``start [cells + 1]`` and ``items``:
    the segments whose bounding box touches cell ``c`` are ``items[start[c]:start[c + 1]]`` (row-major, y
    outer)."""
    n = cols.shape[1]
    meta = np.zeros(4)
    if n == 0:
        return meta, np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    x0 = min(np.min(cols[0]), np.min(cols[0] + cols[2]))
    y0 = min(np.min(cols[1]), np.min(cols[1] + cols[3]))
    x1 = max(np.max(cols[0]), np.max(cols[0] + cols[2]))
    y1 = max(np.max(cols[1]), np.max(cols[1] + cols[3]))
    nx = int((x1 - x0) // cell) + 1
    ny = int((y1 - y0) // cell) + 1
    meta[0], meta[1], meta[2], meta[3] = x0, y0, nx, ny
    counts = np.zeros(nx * ny + 1, dtype=np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            for c in range(nx * ny):
                counts[c + 1] += counts[c]
            items = np.empty(counts[nx * ny], dtype=np.int64)
            fill = counts[:-1].copy()
        for k in range(n):
            ax, ay, bx, by = cols[0, k], cols[1, k], cols[0, k] + cols[2, k], cols[1, k] + cols[3, k]
            i0, i1 = int((min(ax, bx) - x0) // cell), int((max(ax, bx) - x0) // cell)
            j0, j1 = int((min(ay, by) - y0) // cell), int((max(ay, by) - y0) // cell)
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    if pass_ == 0:
                        counts[j * nx + i + 1] += 1
                    else:
                        items[fill[j * nx + i]] = k
                        fill[j * nx + i] += 1
    return meta, counts, items


@njit(types.Tuple((float64, float64, int64))(float64[:, ::1], float64[::1], float64, float64, float64[::1],
                                             int64[::1], int64[::1], float64),
      cache=True, nogil=True, error_model="numpy")
def _nearest(cols: np.ndarray, len2: np.ndarray, x: float, y: float, meta: np.ndarray, start: np.ndarray,
             items: np.ndarray, cell: float) -> tuple[float, float, int]:
    """The closest point (x, y) to (``x``, ``y``) on the segments of a `segment_grid` and that segment's index:
    rings of cells around the point, nearest first, until no farther cell can hold a closer segment; ties go to
    the lowest segment index (the brute-force `seal.models.rapid.kernels.closest_points`' answer)."""
    x0, y0, nx, ny = meta[0], meta[1], int(meta[2]), int(meta[3])
    ci, cj = int((x - x0) // cell), int((y - y0) // cell)
    r_max = max(max(abs(ci), abs(ci - nx + 1)), max(abs(cj), abs(cj - ny + 1)))
    best, best_k, qx, qy = np.inf, -1, 0.0, 0.0
    for r in range(r_max + 1):
        if best_k >= 0 and math.sqrt(best) < (r - 1) * cell:
            break
        for j in range(cj - r, cj + r + 1):
            if j < 0 or j >= ny:
                continue
            step = 1 if (j == cj - r or j == cj + r) else 2 * r
            i = ci - r
            while i <= ci + r:
                if 0 <= i < nx:
                    c = j * nx + i
                    for q in range(start[c], start[c + 1]):
                        k = items[q]
                        px, py = x - cols[0, k], y - cols[1, k]
                        t = min(max((px * cols[2, k] + py * cols[3, k]) / len2[k], 0.0), 1.0)
                        dx, dy = px - t * cols[2, k], py - t * cols[3, k]
                        d2 = dx * dx + dy * dy
                        if d2 < best or (d2 == best and k < best_k):
                            best, best_k = d2, k
                            qx, qy = cols[0, k] + t * cols[2, k], cols[1, k] + t * cols[3, k]
                i += max(step, 1)
    return qx, qy, max(best_k, 0)


@njit(types.Tuple((float64[:, ::1], int64[::1]))(float64[:, ::1], float64[::1], float64[:, ::1], float64[::1],
                                                  int64[::1], int64[::1], float64),
      cache=True, nogil=True, error_model="numpy")
def closest_points_grid(cols: np.ndarray, len2: np.ndarray, pts: np.ndarray, meta: np.ndarray, start: np.ndarray,
                        items: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray]:
    """`seal.models.rapid.kernels.closest_points` through a `segment_grid` (`_nearest` per point): the cost per
    point depends on the segments near it, not on the map's size."""
    m = pts.shape[0]
    out = np.empty((m, 2))
    idx = np.zeros(m, dtype=np.int64)
    for p in range(m):
        out[p, 0], out[p, 1], idx[p] = _nearest(cols, len2, pts[p, 0], pts[p, 1], meta, start, items, cell)
    return out, idx


@njit(types.Tuple((float32[:, ::1], float32[:, ::1], float32[:, ::1], float64[:, ::1]))(
    float64[:, ::1], int64[::1], float64[::1], float64[::1],
    float64[:, ::1], float64[::1], float64[::1], int64[::1], int64[::1],
    float64[:, ::1], float64[::1], float64[::1], int64[::1], int64[::1], float64,
    float64[:, ::1], types.boolean[::1], float64[::1], float64[:, ::1], float64[::1], float64[::1]),
    cache=True, nogil=True, error_model="numpy")
def own_inputs(cur: np.ndarray, rows: np.ndarray, origin: np.ndarray, freqs: np.ndarray,
               c_cols: np.ndarray, c_len2: np.ndarray, c_meta: np.ndarray, c_start: np.ndarray, c_items: np.ndarray,
               e_cols: np.ndarray, e_len2: np.ndarray, e_meta: np.ndarray, e_start: np.ndarray, e_items: np.ndarray,
               cell: float, prev_vel: np.ndarray, prev_ok: np.ndarray, desired: np.ndarray, dest: np.ndarray,
               lead_gap: np.ndarray, lead_v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`seal.models.rapid.features.agent_inputs` but the neighbours, for the agents ``rows`` of ``cur [A, 8]``.

    Args:
        origin: ``[2]`` the road's Fourier origin (m); freqs: ``[F]`` the Fourier frequencies (rad/m).
        c_*, e_*: lane-centre and road-edge segments (``cols``, ``len2``, `segment_grid`; ``cell`` m cells).
        prev_vel: ``[n, 2]`` map-frame velocity one step before (m/s), read where ``prev_ok [n]``; desired:
            ``[n]`` desired speed (m/s, NaN: none); dest: ``[n, 2]`` destination (m, NaN: none); lead_gap,
            lead_v: ``[n]`` leader gap (m, inf: none) and speed (m/s).

    Returns:
        ``own [n, 5 + 4F + 8]``; ``opt [n, N_OPT]`` (see `N_OPT`; absent inputs zero); ``masks [n, 4]`` prev,
        speed, destination, leader (1 = present); ``edge [n, 2]`` the nearest road-edge point (map frame, m;
        the map force reads it too).
    """
    n, nf = rows.shape[0], freqs.shape[0]
    own = np.empty((n, 5 + 4 * nf + 8), dtype=np.float32)
    opt = np.zeros((n, N_OPT), dtype=np.float32)
    masks = np.zeros((n, 4), dtype=np.float32)
    edge = np.empty((n, 2))
    has_edges = e_len2.shape[0] > 0
    for r in range(n):
        i = rows[r]
        x, y, vx, vy = cur[i, _X], cur[i, _Y], cur[i, _VX], cur[i, _VY]
        c, s = math.cos(cur[i, _H]), math.sin(cur[i, _H])
        speed = math.hypot(vx, vy)
        own[r, 0], own[r, 1], own[r, 2] = speed / 20.0, (c * vx + s * vy) / 20.0, (-s * vx + c * vy) / 20.0
        own[r, 3], own[r, 4] = c, s
        px, py = x - origin[0], y - origin[1]
        for f in range(nf):
            own[r, 5 + f], own[r, 5 + nf + f] = math.sin(px * freqs[f]), math.sin(py * freqs[f])
            own[r, 5 + 2 * nf + f], own[r, 5 + 3 * nf + f] = math.cos(px * freqs[f]), math.cos(py * freqs[f])
        col = 5 + 4 * nf
        for a in range(2):
            ahead = _AHEAD_M * a
            qx, qy, k = _nearest(c_cols, c_len2, x + ahead * c, y + ahead * s, c_meta, c_start, c_items, cell)
            norm = math.sqrt(c_len2[k])
            dx, dy = c_cols[2, k] / norm, c_cols[3, k] / norm
            own[r, col] = (-s * (qx - x) + c * (qy - y)) / 4.0
            own[r, col + 1], own[r, col + 2] = c * dx + s * dy, -s * dx + c * dy
            col += 3
        if has_edges:
            qx, qy, _ = _nearest(e_cols, e_len2, x, y, e_meta, e_start, e_items, cell)
        else:
            qx, qy = x + _NO_EDGE_M, y + _NO_EDGE_M
        edge[r, 0], edge[r, 1] = qx, qy
        own[r, col], own[r, col + 1] = (c * (qx - x) + s * (qy - y)) / 10.0, (-s * (qx - x) + c * (qy - y)) / 10.0
        if prev_ok[r]:
            ax, ay = (vx - prev_vel[r, 0]) / _DT_S, (vy - prev_vel[r, 1]) / _DT_S
            opt[r, 0], opt[r, 1] = (c * ax + s * ay) / _ACC_SCALE_MPS2, (-s * ax + c * ay) / _ACC_SCALE_MPS2
            masks[r, 0] = 1.0
        if math.isfinite(desired[r]):
            opt[r, 2] = (desired[r] - speed) / 20.0
            masks[r, 1] = 1.0
        if math.isfinite(dest[r, 0]) and math.isfinite(dest[r, 1]):
            rx, ry = dest[r, 0] - x, dest[r, 1] - y
            lx, ly = c * rx + s * ry, -s * rx + c * ry
            opt[r, 3], opt[r, 4], opt[r, 5] = lx / 100.0, ly / 100.0, math.log1p(math.hypot(lx, ly)) / 5.0
            masks[r, 2] = 1.0
        if math.isfinite(lead_gap[r]):
            opt[r, 6], opt[r, 7] = lead_gap[r] / 50.0, (speed - lead_v[r]) / 10.0
            masks[r, 3] = 1.0
    return own, opt, masks, edge
