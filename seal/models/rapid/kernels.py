"""Compiled (numba) kernel of the RAPID inputs: the closest point of a set of segments for many points at once.

Why compiled: the local map read-out and the map force ask it for every background agent (two points each) on
every env step; a numpy ``[points, segments]`` table or one kernel call per point made it the largest per-agent
cost at 120 agents. It does in float64 the textbook projection of `seal.core.kernels.closest_segment` (the same
first-segment-of-the-smallest-distance rule), for each point. Explicit signature: compiled (or loaded from
numba's on-disk cache) at import.
"""

from __future__ import annotations

import numpy as np
from numba import float64, int64, njit, types


@njit(types.Tuple((float64[:, ::1], int64[::1]))(float64[:, ::1], float64[::1], float64[:, ::1]),
      cache=True, nogil=True, error_model="numpy")
def closest_points(cols: np.ndarray, len2: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For points ``pts [m, 2]`` (m): the closest point ``[m, 2]`` on any of the segments ``cols [4, n]`` (rows a x,
    a y, e x, e y; squared lengths ``len2 [n]`` > 0) and that segment's index ``[m]``."""
    m = pts.shape[0]
    n = len2.shape[0]
    out = np.empty((m, 2))
    idx = np.zeros(m, dtype=np.int64)
    for i in range(m):
        x = pts[i, 0]
        y = pts[i, 1]
        best = np.inf
        for k in range(n):
            px = x - cols[0, k]
            py = y - cols[1, k]
            t = (px * cols[2, k] + py * cols[3, k]) / len2[k]
            t = min(max(t, 0.0), 1.0)
            dx = px - t * cols[2, k]
            dy = py - t * cols[3, k]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best = d2
                idx[i] = k
                out[i, 0] = cols[0, k] + t * cols[2, k]
                out[i, 1] = cols[1, k] + t * cols[3, k]
    return out, idx
