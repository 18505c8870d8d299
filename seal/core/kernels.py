"""Compiled (numba) kernels of the env's per-step geometry: the oriented-box collision test of one box against rows
of a box table, the separating-axis test of two boxes given by their corners, and the closest point of a polyline.

Why compiled: each runs every env step for the ego (and a driven adversary) on arrays of a few to a few dozen rows,
where numpy's per-call overhead (~1 us a call, a dozen calls) costs more than the arithmetic. Both do in float64
the operations of the numpy code they replace (`seal.core.geometry.overlaps_one` and its pre-filter;
``seal.envs.route.Route.project``'s textbook form), which the tests keep as the reference.

Explicit signatures: numba compiles each kernel (or loads it from its on-disk cache, ``cache=True``) when this
module is imported, so no run stalls on a first call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import boolean, float64, int64, njit, types


@njit(int64[::1](float64, float64, float64, float64, float64, float64[:, ::1], int64[::1]), cache=True, nogil=True,
      error_model="numpy")
def box_hits_rows(
    x: float, y: float, heading: float, length: float, width: float, boxes: np.ndarray, rows: np.ndarray,
) -> np.ndarray:
    """Rows of ``boxes [A, >=7]`` (track layout: x, y, heading, vx, vy, length, width; m, rad) among ``rows``
    (in their order) whose box overlaps the box ``(x, y, heading, length, width)``; touching counts as overlapping.

    A row whose centre is farther than the two half diagonals summed cannot touch and is skipped; the others get the
    centre-form separating-axis test on the four box axes (`seal.core.geometry._separated`).
    """
    out = np.empty(rows.shape[0], dtype=np.int64)
    n = 0
    ca = math.cos(heading)
    sa = math.sin(heading)
    la = length / 2
    wa = width / 2
    diag_a = math.hypot(length, width)
    for j in range(rows.shape[0]):
        i = rows[j]
        dx = boxes[i, 0] - x
        dy = boxes[i, 1] - y
        reach = 0.5 * (diag_a + math.hypot(boxes[i, 5], boxes[i, 6]))
        if not dx * dx + dy * dy < reach * reach:
            continue
        cb = math.cos(boxes[i, 2])
        sb = math.sin(boxes[i, 2])
        lb = boxes[i, 5] / 2
        wb = boxes[i, 6] / 2
        cos_d = abs(ca * cb + sa * sb)  # |cos| of the angle between the boxes
        sin_d = abs(ca * sb - sa * cb)
        if abs(dx * ca + dy * sa) > la + lb * cos_d + wb * sin_d:  # a's heading axis
            continue
        if abs(dy * ca - dx * sa) > wa + lb * sin_d + wb * cos_d:  # a's normal
            continue
        if abs(dx * cb + dy * sb) > lb + la * cos_d + wa * sin_d:  # b's heading axis
            continue
        if abs(dy * cb - dx * sb) > wb + la * sin_d + wa * cos_d:  # b's normal
            continue
        out[n] = i
        n += 1
    return out[:n]


@njit(boolean(float64[:, ::1], float64[:, ::1]), cache=True, nogil=True, error_model="numpy")
def corner_boxes_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """`seal.core.geometry.boxes_overlap` of two rectangles ``[4, 2]`` (corners in cyclic order, m): the
    separating-axis test on the two edge normals of each (unnormalised edges, as there); touching overlaps."""
    for k in range(4):
        box = a if k < 2 else b
        e = k % 2
        ax = box[e + 1, 0] - box[e, 0]
        ay = box[e + 1, 1] - box[e, 1]
        lo_a = hi_a = ax * a[0, 0] + ay * a[0, 1]
        lo_b = hi_b = ax * b[0, 0] + ay * b[0, 1]
        for c in range(1, 4):
            pa = ax * a[c, 0] + ay * a[c, 1]
            pb = ax * b[c, 0] + ay * b[c, 1]
            lo_a = min(lo_a, pa)
            hi_a = max(hi_a, pa)
            lo_b = min(lo_b, pb)
            hi_b = max(hi_b, pb)
        if hi_a < lo_b or hi_b < lo_a:
            return False
    return True


@njit(types.Tuple((int64, float64, float64))(float64[:, ::1], float64[::1], float64, float64, int64, int64),
      cache=True, nogil=True, error_model="numpy")
def closest_segment(
    cols: np.ndarray, len2: np.ndarray, x: float, y: float, lo: int, hi: int,
) -> tuple[int, float, float]:
    """Closest of the polyline segments ``lo .. hi - 1`` to the point (x, y) (m): ``(k, t, cross)`` with ``k`` its
    index, ``t`` in [0, 1] the closest point's share along it and ``cross = e x (p - a)`` (m^2, > 0 when the point
    lies to its left; divide by the segment length for the signed distance to its line).

    Args:
        cols: ``[4, n]`` segment starts and vectors (rows: a x, a y, e x, e y; m).
        len2: ``[n]`` squared segment lengths (m^2), all > 0.

    The textbook form ``t = clip((p - a) . e / |e|^2, 0, 1)``, the first segment of the smallest ``|p - a - t e|^2``.
    """
    best_k = lo
    best_d2 = math.inf
    best_t = 0.0
    best_cross = 0.0
    for k in range(lo, hi):
        ex = cols[2, k]
        ey = cols[3, k]
        px = x - cols[0, k]
        py = y - cols[1, k]
        t = (px * ex + py * ey) / len2[k]
        t = min(max(t, 0.0), 1.0)
        dx = px - t * ex
        dy = py - t * ey
        d2 = dx * dx + dy * dy
        if d2 < best_d2:
            best_k, best_d2, best_t, best_cross = k, d2, t, ex * py - ey * px
    return best_k, best_t, best_cross
