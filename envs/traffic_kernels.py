"""Compiled (numba) kernels of base-scenario generation (issue 23): the per-step collision pre-check and the road
rules' conflict test of `seal.envs.traffic`, and the path-crossing test of `seal.envs.windows`.

Why compiled: each replaced a loop of small numpy calls (one per vehicle pair and step, a few to a few hundred
elements each) whose per-call overhead cost more than the arithmetic; together they were about a third of the
generator's CPU time. Each kernel does in float64 the operations of the numpy code it replaced, in the same
order (products and sums of two terms, ``sqrt``, ``cos`` / ``sin`` from the same libm, Python's float ``%``), so
the generated data stay bit-identical; their numpy forms live on as the reference in
``tests/envs/test_traffic_kernels.py``.

Explicit signatures: numba compiles each kernel (or loads it from its on-disk cache, ``cache=True``) when this
module is imported, so no run stalls on a first call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import boolean, float64, int64, njit, types

from seal.core.interaction import CONFLICT_DIST_M, CONFLICT_DT_S, CROSSING_TURN_RAD
from seal.core.kernels import corner_boxes_overlap
from seal.core.scenario import DT_S

_TWO_PI = 2 * math.pi


@njit(types.Tuple((int64[::1], int64[::1]))(float64[:, :, :, ::1], int64[:], int64[:], boolean[:, :, ::1]),
      cache=True, nogil=True, error_model="numpy")
def first_overlaps(
    corners: np.ndarray, ii: np.ndarray, jj: np.ndarray, close: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """When each vehicle of a predicted pair first enters the conflict (`seal.envs.traffic.TrafficRoad`'s road
    rules).

    Args:
        corners: ``[n, K, 4, 2]`` corners (m) of the enlarged boxes of ``n`` predicted paths at ``K`` samples.
        ii, jj: ``[P]`` the paths of each pair.
        close: ``[P, K, K]`` the sample pairs ``(ka, kb)`` to test (close enough in space and time).

    Returns:
        ``ka [P]``, ``kb [P]``: over the tested sample pairs whose boxes overlap, the smallest sample of
        ``ii[p]``'s path and the smallest of ``jj[p]``'s (each minimised on its own); -1 where none overlaps.
    """
    n_p = ii.shape[0]
    n_k = close.shape[1]
    out_a = np.full(n_p, -1, dtype=np.int64)
    out_b = np.full(n_p, -1, dtype=np.int64)
    for p in range(n_p):
        ca = corners[ii[p]]
        cb = corners[jj[p]]
        best_a = n_k
        best_b = n_k
        for ka in range(n_k):
            for kb in range(n_k):
                if close[p, ka, kb] and (ka < best_a or kb < best_b) and corner_boxes_overlap(ca[ka], cb[kb]):
                    best_a = min(best_a, ka)
                    best_b = min(best_b, kb)
        if best_a < n_k:
            out_a[p] = best_a
            out_b[p] = best_b
    return out_a, out_b


@njit(float64(float64[:, ::1], float64[:, ::1]), cache=True, nogil=True, error_model="numpy")
def _separation(a: np.ndarray, b: np.ndarray) -> float:
    """Largest gap (m) between the projections of two rectangles ``[4, 2]`` on their (normalised) edge normals:
    a lower bound of their distance, <= 0 when they overlap."""
    best = -math.inf
    for k in range(4):
        src = a if k < 2 else b
        e = k % 2
        ax = src[e + 1, 0] - src[e, 0]
        ay = src[e + 1, 1] - src[e, 1]
        norm = math.sqrt(ax * ax + ay * ay)
        ax /= norm
        ay /= norm
        a_min = a_max = ax * a[0, 0] + ay * a[0, 1]
        b_min = b_max = ax * b[0, 0] + ay * b[0, 1]
        for c in range(1, 4):
            pa = ax * a[c, 0] + ay * a[c, 1]
            pb = ax * b[c, 0] + ay * b[c, 1]
            a_min = min(a_min, pa)
            a_max = max(a_max, pa)
            b_min = min(b_min, pb)
            b_max = max(b_max, pb)
        best = max(best, max(b_min - a_max, a_min - b_max))
    return best


@njit(types.Tuple((int64[::1], int64[::1]))(float64[:, ::1], float64), cache=True, nogil=True,
      error_model="numpy")
def contact_pairs(state: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle pairs ``(i, j)``, ``i < j`` in row-major order, that may touch within a step of ``dt`` s: the
    pre-check of `seal.envs.traffic.TrafficRoad.step` (a superset of highway-env's own collision test).

    Args:
        state: ``[n, 6]`` rows ``x, y (m), heading (rad), length, width (m), speed (m/s)``.

    A pair is kept when the centres are within the summed half diagonals plus each one's travel plus 0.5 m, and
    the separating-axis gap of the two boxes (edge normals normalised) is at most the relative displacement in a
    step plus 0.1 m.
    """
    n = state.shape[0]
    reach = np.empty(n)
    corners = np.empty((n, 4, 2))
    vel = np.empty((n, 2))
    sl = (0.5, 0.5, -0.5, -0.5)
    sw = (0.5, -0.5, -0.5, 0.5)
    for i in range(n):
        reach[i] = math.hypot(state[i, 3], state[i, 4]) / 2 + abs(state[i, 5]) * dt
        c = math.cos(state[i, 2])
        s = math.sin(state[i, 2])
        for k in range(4):
            dl = sl[k] * state[i, 3]
            dw = sw[k] * state[i, 4]
            corners[i, k, 0] = state[i, 0] + dl * c - dw * s
            corners[i, k, 1] = state[i, 1] + dl * s + dw * c
        vel[i, 0] = state[i, 5] * c
        vel[i, 1] = state[i, 5] * s
    out_i = np.empty(n * (n - 1) // 2, dtype=np.int64)
    out_j = np.empty(n * (n - 1) // 2, dtype=np.int64)
    m = 0
    for i in range(n):
        for j in range(i + 1, n):
            dx = state[i, 0] - state[j, 0]
            dy = state[i, 1] - state[j, 1]
            if not math.sqrt(dx * dx + dy * dy) <= reach[i] + reach[j] + 0.5:
                continue
            rx = vel[i, 0] - vel[j, 0]
            ry = vel[i, 1] - vel[j, 1]
            rel = math.sqrt(rx * rx + ry * ry) * dt
            if _separation(corners[i], corners[j]) <= rel + 0.1:
                out_i[m] = i
                out_j[m] = j
                m += 1
    return out_i[:m], out_j[:m]


@njit(types.Tuple((int64[::1], float64[::1]))(float64[:, :, ::1], boolean[:, ::1], int64, int64, int64, int64),
      cache=True, nogil=True, error_model="numpy")
def path_crossings(
    states: np.ndarray, valid: np.ndarray, i: int, j: int, lo: int, hi: int
) -> tuple[np.ndarray, np.ndarray]:
    """Path crossings of rows ``i`` and ``j`` of a run log in steps ``lo .. hi - 1`` (every 2nd step): the step
    when the second passes and the time (s) between the passages, in row-major order of (step of ``i``, step of
    ``j``); `seal.envs.windows._conflicts` with `seal.core.interaction.crossing_hits`.

    Args:
        states: ``[N, T, >=3]`` x, y (m), heading (rad); NaN where a vehicle does not exist.
        valid: ``[N, T]``.
    """
    n = (hi - lo + 1) // 2 if hi > lo else 0
    any_i = False
    any_j = False
    for a in range(n):
        any_i = any_i or valid[i, lo + 2 * a]
        any_j = any_j or valid[j, lo + 2 * a]
    if not (any_i and any_j):
        return np.empty(0, dtype=np.int64), np.empty(0)
    steps = np.empty(n * n, dtype=np.int64)
    dts = np.empty(n * n)
    m = 0
    for a in range(n):
        sa = lo + 2 * a
        if not valid[i, sa]:
            continue
        for b in range(n):
            sb = lo + 2 * b
            if not valid[j, sb]:
                continue
            dx = states[i, sa, 0] - states[j, sb, 0]
            dy = states[i, sa, 1] - states[j, sb, 1]
            dt = abs(sa - sb) * DT_S
            turn = abs((states[i, sa, 2] - states[j, sb, 2] + math.pi) % _TWO_PI - math.pi)
            if math.sqrt(dx * dx + dy * dy) < CONFLICT_DIST_M and dt <= CONFLICT_DT_S and turn > CROSSING_TURN_RAD:
                steps[m] = max(sa, sb)
                dts[m] = dt
                m += 1
    return steps[:m], dts[:m]
