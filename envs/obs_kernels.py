"""Compiled (numba) kernels of the observation (`seal.envs.observation`): the ray casts against road edges and lane
lines, the box lidar and the nearest-vehicle search, fused into one call per viewer (`observe_viewer`).

Why compiled: the observation is built every env step for the ego (and a reactive adversary); as numpy it took ~40
calls on arrays of a few hundred elements, so call overhead, not arithmetic, set its cost. Here one call does all
of it in float64 with the same operations in the same order as the numpy reference kept in the tests
(``tests/envs/obs_reference.py``), so observations agree with it bit for bit on recorded states (the tests check
that; ``np.cos`` / ``math.cos`` of the box headings may differ in the last float64 bit, which the float32
observation almost never shows, hence the tests' 1e-6 bound).

Every kernel has an explicit signature, so numba compiles it (or loads it from its on-disk cache, ``cache=True``)
when this module is imported: a training run never stalls on a first call. ``error_model="numpy"``: a ray parallel
to a segment or a box side divides by zero and gets inf / NaN, which the hit tests reject, as in numpy.

The sensor constants and slot indices below are the observation's layout (documented in
`seal.envs.observation`, which re-exports them); they are compile-time constants of the kernels.
"""

from __future__ import annotations

import math

import numpy as np
from numba import float32, float64, int64, njit, void

from seal.envs.kinematics import MAX_SPEED_MPS
from seal.envs.rays import ray_angles

N_EDGE_RAYS = 30
EDGE_RANGE_M = 50.0
N_LINE_RAYS = 12
LINE_RANGE_M = 20.0
N_LIDAR_RAYS = 30
LIDAR_RANGE_M = 50.0
N_NEAREST = 3
REL_SPEED_SCALE = 30.0
NEAREST_SLOTS = 5
OBS_DIM = 100
VALID_COL = 7
"""Column of the valid flag in the track layout (`seal.core.scenario.TRACK_FIELDS`)."""
CHECKPOINT_SPACING_M = 8.0
NAV_SCALE_M = 20.0
LATERAL_SCALE_M = 10.0
YAW_RATE_SCALE = 2.0

# First slot of each array block (see `seal.envs.observation`).
EDGE_START = 0
LINE_START = 36
LIDAR_START = 55
NEAREST_START = 85

OBS_LOW = np.full(OBS_DIM, -1.0, dtype=np.float32)
OBS_HIGH = np.ones(OBS_DIM, dtype=np.float32)
OBS_LOW[EDGE_START : EDGE_START + N_EDGE_RAYS] = 0.0
OBS_LOW[LINE_START : LINE_START + N_LINE_RAYS] = 0.0
OBS_LOW[LIDAR_START : LIDAR_START + N_LIDAR_RAYS] = 0.0
for _i in (31, 53, 54):  # speed, speed limit, route reference speed
    OBS_LOW[_i] = 0.0
OBS_LOW[NEAREST_START::NEAREST_SLOTS] = 0.0  # presence flags

assert N_LIDAR_RAYS == N_EDGE_RAYS  # the lidar reuses the edge rays' directions
EDGE_COS, EDGE_SIN = np.cos(ray_angles(N_EDGE_RAYS)), np.sin(ray_angles(N_EDGE_RAYS))
LINE_COS, LINE_SIN = np.cos(ray_angles(N_LINE_RAYS)), np.sin(ray_angles(N_LINE_RAYS))
LIDAR_RANGE2 = LIDAR_RANGE_M * LIDAR_RANGE_M
LIDAR_REACH2 = (LIDAR_RANGE_M + 8.0) ** 2
"""Vehicles whose centre is farther than this (squared, m^2) cannot reach into lidar range (8 m > half the
diagonal of a 15 m truck)."""



@njit(cache=True, nogil=True, error_model="numpy")
def cast_rays_into(
    x: float, y: float, c: float, s: float, ray_cos: np.ndarray, ray_sin: np.ndarray, segments: np.ndarray,
    max_range: float, out: np.ndarray, start: int,
) -> None:
    """Ray casts from (x, y) (m) with heading cos / sin ``c, s``: ray ``k`` at angle ``heading + a_k`` (``ray_cos``,
    ``ray_sin``: cos / sin of ``a_k``, ``[K]``) against ``segments [4, M]`` (rows: start x, start y, vector x,
    vector y; m, world frame; NaN segments never hit). Writes ``distance / max_range`` of the first hit (1 when none
    within ``max_range``; values above 1 are left for the observation's clip) to ``out[start : start + K]``.

    Ray ``t d`` meets segment ``a + u e`` at ``t = (a x e) / (d x e)``, ``u = (d x a) / (d x e)``
    (`seal.envs.rays`); a hit needs ``t >= 0`` and ``0 <= u <= 1``.
    """
    n_rays = ray_cos.shape[0]
    n_seg = segments.shape[1]
    for k in range(n_rays):
        # World-frame ray direction, written as the reference writes it (c cos + s (-sin), s cos + c sin).
        dx = c * ray_cos[k] + s * (-ray_sin[k])
        dy = s * ray_cos[k] + c * ray_sin[k]
        best = max_range
        for m in range(n_seg):
            ax = segments[0, m] - x
            ay = segments[1, m] - y
            ex = segments[2, m]
            ey = segments[3, m]
            inv = 1.0 / (dx * ey - dy * ex)
            t = (ax * ey - ay * ex) * inv
            u = (dy * ax - dx * ay) * inv
            if t >= 0.0 and u >= 0.0 and u <= 1.0 and t < best:
                best = t
        out[start + k] = best / max_range


@njit(inline="always", cache=True, nogil=True, error_model="numpy")
def _fmin(a: float, b: float) -> float:
    """``np.minimum`` of two floats (NaN when either is NaN)."""
    if a != a or b != b:
        return math.nan
    return a if a <= b else b


@njit(inline="always", cache=True, nogil=True, error_model="numpy")
def _fmax(a: float, b: float) -> float:
    """``np.maximum`` of two floats (NaN when either is NaN)."""
    if a != a or b != b:
        return math.nan
    return a if a >= b else b


@njit(cache=True, nogil=True, error_model="numpy")
def ray_box_distance(
    dx: float, dy: float, rx: float, ry: float, cos_h: float, sin_h: float, half_length: float, half_width: float,
) -> float:
    """Distance (m) along the unit ray ``(dx, dy)`` from the origin to the oriented box centred at ``(rx, ry)``
    (relative to the origin, m) with heading cos / sin ``cos_h, sin_h``; inf when the ray misses it.

    Slab test in the box's frame: the ray enters the box at the larger of its two entry distances (one per box
    axis) and leaves at the smaller exit distance; it hits when it enters before it leaves and leaves ahead of the
    origin. From inside the box (overlapping vehicles) the exit distance is returned, as a ray cast against the
    box edges would give.
    """
    px = -(rx * cos_h + ry * sin_h)  # the origin in the box's frame
    py = rx * sin_h - ry * cos_h
    inv_x = 1.0 / (dx * cos_h + dy * sin_h)  # the ray direction in the box's frame, inverted
    inv_y = 1.0 / (dy * cos_h - dx * sin_h)
    a = (-half_length - px) * inv_x
    b = (half_length - px) * inv_x
    c = (-half_width - py) * inv_y
    d = (half_width - py) * inv_y
    enter = _fmax(_fmin(a, b), _fmin(c, d))
    leave = _fmin(_fmax(a, b), _fmax(c, d))
    if enter <= leave and leave >= 0.0:
        return enter if enter >= 0.0 else leave
    return math.inf


@njit(cache=True, nogil=True, error_model="numpy")
def vehicles_into(
    x: float, y: float, c: float, s: float, speed: float, boxes: np.ndarray, self_row: int, out: np.ndarray,
) -> None:
    """Box lidar and nearest vehicles of a viewer at (x, y) (m), heading cos / sin ``c, s``, speed (m/s), among
    ``boxes [N, >=7]`` (track layout: x, y, heading, vx, vy, length, width, valid; m, rad, m/s), row ``self_row``
    (the viewer's own box, or -1) and, when there is a valid column, rows with valid < 0.5 (absent) left out.

    Writes the `N_LIDAR_RAYS` lidar readings (distance / `LIDAR_RANGE_M` to the first box hit along each of the edge
    rays' directions; 1 when none) and the `N_NEAREST` nearest vehicles with centres within `LIDAR_RANGE_M`, nearest
    first (ties: lower row first), 5 slots each (1, dx, dy in the vehicle frame / range, dvx, dvy relative velocity
    in the vehicle frame / `REL_SPEED_SCALE`; absent ones all 0) to their blocks of ``out``. Boxes whose centre is
    beyond `LIDAR_REACH2` cannot reach into range and are skipped.
    """
    n_rays = EDGE_COS.shape[0]
    dxs = np.empty(n_rays)
    dys = np.empty(n_rays)
    best = np.full(n_rays, LIDAR_RANGE_M)
    for k in range(n_rays):
        dxs[k] = c * EDGE_COS[k] + s * (-EDGE_SIN[k])
        dys[k] = s * EDGE_COS[k] + c * EDGE_SIN[k]
    near_row = np.full(N_NEAREST, -1)
    near_d2 = np.full(N_NEAREST, math.inf)
    has_valid = boxes.shape[1] > VALID_COL
    for i in range(boxes.shape[0]):
        if i == self_row or (has_valid and not boxes[i, VALID_COL] > 0.5):
            continue
        rx = boxes[i, 0] - x
        ry = boxes[i, 1] - y
        d2 = rx * rx + ry * ry
        if not d2 < LIDAR_REACH2:
            continue
        cos_h = math.cos(boxes[i, 2])
        sin_h = math.sin(boxes[i, 2])
        hl = 0.5 * boxes[i, 5]
        hw = 0.5 * boxes[i, 6]
        for k in range(n_rays):
            dist = ray_box_distance(dxs[k], dys[k], rx, ry, cos_h, sin_h, hl, hw)
            if dist < best[k]:
                best[k] = dist
        if d2 < LIDAR_RANGE2 and d2 < near_d2[N_NEAREST - 1]:  # insertion into the sorted nearest list
            j = N_NEAREST - 1
            while j > 0 and d2 < near_d2[j - 1]:
                near_d2[j] = near_d2[j - 1]
                near_row[j] = near_row[j - 1]
                j -= 1
            near_d2[j] = d2
            near_row[j] = i
    for k in range(n_rays):
        out[LIDAR_START + k] = best[k] / LIDAR_RANGE_M
    vx = speed * c
    vy = speed * s
    for j in range(N_NEAREST):
        o = NEAREST_START + NEAREST_SLOTS * j
        i = near_row[j]
        if i < 0:
            for q in range(NEAREST_SLOTS):
                out[o + q] = 0.0
            continue
        px = boxes[i, 0] - x
        py = boxes[i, 1] - y
        dvx = boxes[i, 3] - vx
        dvy = boxes[i, 4] - vy
        out[o] = 1.0
        out[o + 1] = (px * c + py * s) / LIDAR_RANGE_M
        out[o + 2] = (py * c - px * s) / LIDAR_RANGE_M
        out[o + 3] = (dvx * c + dvy * s) / REL_SPEED_SCALE
        out[o + 4] = (dvy * c - dvx * s) / REL_SPEED_SCALE


@njit(cache=True, nogil=True, error_model="numpy")
def clip_into_space(obs: np.ndarray) -> None:
    """Clip an observation ``[OBS_DIM]`` in place to the observation space's bounds (NaN stays NaN)."""
    for i in range(OBS_DIM):
        v = obs[i]
        if v < OBS_LOW[i]:
            obs[i] = OBS_LOW[i]
        elif v > OBS_HIGH[i]:
            obs[i] = OBS_HIGH[i]


@njit(cache=True, nogil=True, error_model="numpy")
def _route_at(nav: np.ndarray, s: float) -> tuple[float, float, float]:
    """Position (m) and reference speed (m/s) at arc length ``s`` of a route's ``nav [4, P]`` (rows: arc length
    of each extended vertex, x, y, speed), clamped to its ends (`seal.envs.route.Route.point_at` / ``speed_at``)."""
    cum = nav[0]
    i = min(max(np.searchsorted(cum, s, side="right") - 1, 0), cum.shape[0] - 2)
    u = min(1.0, max(0.0, (s - cum[i]) / (cum[i + 1] - cum[i])))
    xs, ys, vs = nav[1], nav[2], nav[3]
    return xs[i] + u * (xs[i + 1] - xs[i]), ys[i] + u * (ys[i + 1] - ys[i]), vs[i] + u * (vs[i + 1] - vs[i])


@njit(cache=True, nogil=True, error_model="numpy")
def state_into(
    obs: np.ndarray, x: float, y: float, c: float, s: float, heading: float, speed: float, steering: float,
    accel: float, yaw_rate: float, proj_s: float, proj_lateral: float, proj_heading: float, nav: np.ndarray,
    speed_limit: float,
) -> None:
    """The scalar slots (30-35, 48-54): heading error, speed, steering, last action, yaw rate, lateral offset, the
    two navigation checkpoints in the vehicle frame, speed limit and route reference speed (see
    `seal.envs.observation`); ``c, s``: cos / sin of the heading."""
    herr = (proj_heading - heading + math.pi) % (2 * math.pi) - math.pi
    p1x, p1y, _ = _route_at(nav, proj_s + CHECKPOINT_SPACING_M)
    p2x, p2y, _ = _route_at(nav, proj_s + 2 * CHECKPOINT_SPACING_M)
    ref = _route_at(nav, proj_s)[2]
    p1x, p1y, p2x, p2y = p1x - x, p1y - y, p2x - x, p2y - y
    obs[30] = herr / math.pi
    obs[31] = speed / MAX_SPEED_MPS
    obs[32] = steering
    obs[33] = steering
    obs[34] = accel
    obs[35] = yaw_rate / YAW_RATE_SCALE
    obs[48] = proj_lateral / LATERAL_SCALE_M
    obs[49] = (p1x * c + p1y * s) / NAV_SCALE_M
    obs[50] = (p1y * c - p1x * s) / NAV_SCALE_M
    obs[51] = (p2x * c + p2y * s) / NAV_SCALE_M
    obs[52] = (p2y * c - p2x * s) / NAV_SCALE_M
    obs[53] = speed_limit / MAX_SPEED_MPS
    obs[54] = ref / MAX_SPEED_MPS


_F8 = float64


@njit(void(float32[::1], _F8, _F8, _F8, _F8, _F8, _F8, _F8, _F8, _F8, _F8, float64[:, ::1], _F8, float64[:, ::1],
           float64[:, ::1], float64[:, ::1], int64), cache=True, nogil=True, error_model="numpy")
def observe_viewer(
    obs: np.ndarray, x: float, y: float, heading: float, speed: float, steering: float, accel: float,
    yaw_rate: float, proj_s: float, proj_lateral: float, proj_heading: float, nav: np.ndarray, speed_limit: float,
    edges: np.ndarray, lines: np.ndarray, boxes: np.ndarray, self_row: int,
) -> None:
    """One viewer's whole observation ``obs [OBS_DIM]`` (float32): the scalar slots (`state_into`), the edge and line
    rays (`cast_rays_into`), the lidar and nearest vehicles (`vehicles_into`), then the clip of the row. Scalars, not
    small arrays, carry the viewer: building an array costs more than passing ten floats.

    Args:
        x, y, heading, speed: the viewer's centre (m), heading (rad) and speed (m/s).
        steering, accel: its last action (normalised); yaw_rate: rad/s.
        proj_s, proj_lateral, proj_heading: its projection on its route (m, m, rad).
        nav: ``[4, P]`` the route's arc length, x, y and reference speed per extended vertex (`_route_at`).
        speed_limit: of the closest lane (m/s).
        edges, lines: ``[4, M]`` road-edge and lane-line segments near the viewer (`cast_rays_into`).
        boxes: ``[N, >=7]`` vehicles in track layout (`vehicles_into`); ``self_row``: the viewer's own row, or -1.
    """
    c = math.cos(heading)
    s = math.sin(heading)
    state_into(obs, x, y, c, s, heading, speed, steering, accel, yaw_rate, proj_s, proj_lateral, proj_heading, nav,
               speed_limit)
    cast_rays_into(x, y, c, s, EDGE_COS, EDGE_SIN, edges, EDGE_RANGE_M, obs, EDGE_START)
    cast_rays_into(x, y, c, s, LINE_COS, LINE_SIN, lines, LINE_RANGE_M, obs, LINE_START)
    vehicles_into(x, y, c, s, speed, boxes, self_row, obs)
    clip_into_space(obs)
