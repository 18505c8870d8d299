"""Compiled (numba) lane geometry of base-scenario generation (issue 23): the closest-lane lookup of every traffic
vehicle after each step, on a table of the network's lanes (`seal.envs.network_index.NetworkIndex.table`).

The operations are those of the scalar lane twins in `seal.envs.network_index` (``FastStraight``, ``FastSine``,
``FastCircle``: ``local``, ``heading_at`` and the distance with heading), in the same order, so the chosen lanes are
the same. ``math.hypot`` is the exception: numba's calls the C library's, which differs from CPython's own
algorithm in the last bit for about one input in 200; `py_hypot` is CPython 3.11's algorithm (lossless scaling,
Dekker splitting, compensated sums, one differential correction), equal to ``math.hypot`` on millions of inputs
(``tests/envs/test_traffic_kernels.py``).

Explicit signatures: numba compiles each kernel (or loads it from its on-disk cache, ``cache=True``) when this
module is imported, so no run stalls on a first call.
"""

from __future__ import annotations

import math

import numpy as np
from numba import float64, int64, njit, types

STRAIGHT, SINE, CIRCLE = 0, 1, 2
"""Lane kinds in column `KIND` of the lane table."""
KIND, SX, SY, DX, DY, HEADING, AMP, PULS, PHASE, CX, CY, RADIUS, START, DIR, LENGTH = range(15)
"""Columns of the lane table: kind; straight / sine lanes: start (m), unit direction, heading (rad), sine
amplitude (m), pulsation (rad/m), phase (rad); circular lanes: centre (m), radius (m), start phase (rad),
direction (+-1); every lane: length (m)."""
N_COLUMNS = 15

_SPLIT = 134217729.0  # 2^27 + 1: Dekker's split of a double into two 26-bit halves
_DBL_MIN = 2.2250738585072014e-308
_TWO_PI = 2 * math.pi


@njit(float64(float64, float64), cache=True, nogil=True, error_model="numpy")
def py_hypot(x: float, y: float) -> float:
    """CPython 3.11's ``math.hypot(x, y)`` (``vector_norm`` in ``Modules/mathmodule.c``), bit for bit."""
    ax = abs(x)
    ay = abs(y)
    mx = 0.0
    if ax > mx:
        mx = ax
    if ay > mx:
        mx = ay
    if math.isinf(mx):
        return mx
    if math.isnan(x) or math.isnan(y):
        return math.nan
    if mx == 0.0:
        return mx
    e = math.frexp(mx)[1]
    unscale = 1.0
    if e < -1023:  # subnormal: make the components normal first
        ax /= _DBL_MIN
        ay /= _DBL_MIN
        mx /= _DBL_MIN
        unscale = _DBL_MIN
        e = math.frexp(mx)[1]
    scale = math.ldexp(1.0, -e)
    csum = 1.0
    frac1 = 0.0
    frac2 = 0.0
    frac3 = 0.0
    for v in (ax, ay):
        v *= scale
        t = v * _SPLIT
        hi = t - (t - v)
        lo = v - hi
        v = hi * hi
        old = csum
        csum += v
        frac1 += (old - csum) + v
        v = 2.0 * hi * lo
        old = csum
        csum += v
        frac2 += (old - csum) + v
        frac3 += lo * lo
    h = math.sqrt(csum - 1.0 + (frac1 + frac2 + frac3))
    t = h * _SPLIT
    hi = t - (t - h)
    lo = h - hi
    v = -hi * hi
    old = csum
    csum += v
    frac1 += (old - csum) + v
    v = -2.0 * hi * lo
    old = csum
    csum += v
    frac2 += (old - csum) + v
    v = -lo * lo
    old = csum
    csum += v
    frac3 += (old - csum) + v
    v = csum - 1.0 + (frac1 + frac2 + frac3)
    return unscale * ((h + v / (2.0 * h)) / scale)


@njit(types.UniTuple(float64, 2)(float64[::1], float64, float64), cache=True, nogil=True, error_model="numpy")
def lane_local(lane: np.ndarray, x: float, y: float) -> tuple[float, float]:
    """(longitudinal s, lateral r) in m of the point (x, y) on the lane of table row ``lane``."""
    if lane[KIND] == CIRCLE:
        ex = x - lane[CX]
        ey = y - lane[CY]
        phi = math.atan2(ey, ex)
        phi = lane[START] + ((phi - lane[START] + math.pi) % _TWO_PI - math.pi)
        return lane[DIR] * (phi - lane[START]) * lane[RADIUS], lane[DIR] * (lane[RADIUS] - py_hypot(ex, ey))
    ex = x - lane[SX]
    ey = y - lane[SY]
    s = ex * lane[DX] + ey * lane[DY]
    r = ey * lane[DX] - ex * lane[DY]
    if lane[KIND] == SINE:
        r = r - lane[AMP] * math.sin(lane[PULS] * s + lane[PHASE])
    return s, r


@njit(float64(float64[::1], float64), cache=True, nogil=True, error_model="numpy")
def lane_heading_at(lane: np.ndarray, s: float) -> float:
    """Heading (rad) of the lane of table row ``lane`` at arc length ``s`` (m)."""
    if lane[KIND] == CIRCLE:
        return lane[DIR] * s / lane[RADIUS] + lane[START] + math.pi / 2 * lane[DIR]
    if lane[KIND] == SINE:
        return lane[HEADING] + math.atan(lane[AMP] * lane[PULS] * math.cos(lane[PULS] * s + lane[PHASE]))
    return lane[HEADING]


@njit(float64(float64[::1], float64, float64, float64), cache=True, nogil=True, error_model="numpy")
def lane_distance(lane: np.ndarray, x: float, y: float, heading: float) -> float:
    """highway-env's ``distance_with_heading`` (m + rad) of the pose (x, y, heading) to a lane table row."""
    s, r = lane_local(lane, x, y)
    angle = abs((heading - lane_heading_at(lane, s) + math.pi) % _TWO_PI - math.pi)
    return abs(r) + max(s - lane[LENGTH], 0.0) + max(-s, 0.0) + angle


@njit(int64[::1](float64[:, ::1], int64[::1], int64[::1], int64[::1], int64[::1], float64[::1], float64[::1],
                 float64[::1], int64[::1]), cache=True, nogil=True, error_model="numpy")
def closest_lanes(
    table: np.ndarray, sib_ptr: np.ndarray, sib: np.ndarray, nxt_ptr: np.ndarray, nxt: np.ndarray,
    x: np.ndarray, y: np.ndarray, heading: np.ndarray, current: np.ndarray,
) -> np.ndarray:
    """`seal.envs.network_index.NetworkIndex.closest_lane` of every vehicle: lane rows ``[n]``.

    Args:
        table: ``[L, N_COLUMNS]`` the lanes.
        sib_ptr, sib: the lanes leaving each lane's start node, CSR (``sib[sib_ptr[k]:sib_ptr[k + 1]]``).
        nxt_ptr, nxt: the lanes leaving each lane's end node, CSR.
        x, y, heading: ``[n]`` the vehicles' poses (m, rad).
        current: ``[n]`` each vehicle's current lane row.
    """
    n = x.shape[0]
    out = np.empty(n, dtype=np.int64)
    for v in range(n):
        c = current[v]
        best = c
        best_d = math.inf
        for k in range(sib_ptr[c], sib_ptr[c + 1]):
            d = lane_distance(table[sib[k]], x[v], y[v], heading[v])
            if d < best_d:
                best, best_d = sib[k], d
        if lane_local(table[c], x[v], y[v])[0] > table[c, LENGTH] - 6.0:
            for k in range(nxt_ptr[c], nxt_ptr[c + 1]):
                d = lane_distance(table[nxt[k]], x[v], y[v], heading[v])
                if d < best_d:
                    best, best_d = nxt[k], d
        if best_d > 4.0:  # pushed off its roads: every lane, the first of the smallest distance
            best_d = math.inf
            for k in range(table.shape[0]):
                d = lane_distance(table[k], x[v], y[v], heading[v])
                if d < best_d:
                    best, best_d = k, d
        out[v] = best
    return out


@njit(float64[::1](float64[:, ::1], int64[::1], float64[::1], float64[::1], float64[::1], float64[::1],
                   float64[::1], float64, float64, float64, float64), cache=True, nogil=True, error_model="numpy")
def steering_commands(
    table: np.ndarray, target: np.ndarray, x: np.ndarray, y: np.ndarray, heading: np.ndarray, speed: np.ndarray,
    length: np.ndarray, tau_pursuit: float, kp_lateral: float, kp_heading: float, max_steering: float,
) -> np.ndarray:
    """`seal.envs.drivers.Driver._steering` of every vehicle (highway-env's ``steering_control``): steering angles
    ``[n]`` (rad).

    Args:
        table: ``[L, N_COLUMNS]`` the lanes.
        target: ``[n]`` each vehicle's target lane row.
        x, y, heading, speed, length: ``[n]`` the vehicles' poses (m, rad), speeds (m/s) and lengths (m).
        tau_pursuit, kp_lateral, kp_heading, max_steering: highway-env's controller constants (s, 1/s, 1/s, rad).
    """
    n = x.shape[0]
    out = np.empty(n)
    for k in range(n):
        lane = table[target[k]]
        s, r = lane_local(lane, x[k], y[k])
        v = speed[k]
        nz = v if abs(v) > 1e-2 else (1e-2 if v >= 0 else -1e-2)  # highway-env's `not_zero`
        lane_heading = lane_heading_at(lane, s + v * tau_pursuit)
        heading_cmd = math.asin(max(-1.0, min(1.0, -kp_lateral * r / nz)))
        heading_ref = lane_heading + max(-math.pi / 4, min(math.pi / 4, heading_cmd))
        rate_cmd = kp_heading * ((heading_ref - heading[k] + math.pi) % _TWO_PI - math.pi)
        slip = math.asin(max(-1.0, min(1.0, length[k] / 2 / nz * rate_cmd)))
        steer = math.atan(2 * math.tan(slip))
        out[k] = max(-max_steering, min(max_steering, steer))
    return out
