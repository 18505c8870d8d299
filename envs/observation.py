"""The vehicle observation (CAT / MetaDrive style), computed from any vehicle's viewpoint.

`ObservationBuilder.build` needs only the viewer's `AgentState`, its `Route` (+ projection) and the other
agents' current boxes and velocities, so the same builder serves the ego and a reactive adversary.

Conventions: the *vehicle frame* has x forward (along the heading), y to the left. Rays start at the vehicle
centre; ray ``k`` of ``n`` points at ``heading + 2 pi k / n`` (ray 0 straight ahead, counter-clockwise, so with
30 rays ray 7 is 84 deg to the left and ray 15 straight behind; with 12 rays ray 3 is exactly left, ray 9
exactly right). A ray reading is ``distance / range`` in [0, 1] (1 = nothing within range), distances measured
from the vehicle centre. All slots are clipped to the bounds below (the observation space).

====== ======================================================================== ========= ======== =========
index  meaning                                                                  units     scale    bounds
====== ======================================================================== ========= ======== =========
0-29   road-edge rays (30, 360 deg): ``continuous`` borders + drivable-area edge m         / 50     [0, 1]
30     heading error: route tangent at the projection minus vehicle heading     rad       / pi     [-1, 1]
       (wrapped; > 0 = the route points to the left)
31     speed                                                                    m/s       / 40     [0, 1]
32     steering applied on the last step (delta / (pi/3))                       norm.     1        [-1, 1]
33-34  last action (steering, acceleration)                                     norm.     1        [-1, 1]
35     yaw rate                                                                 rad/s     / 2      [-1, 1]
36-47  lane-line rays (12, 360 deg): all painted borders (striped + continuous) m         / 20     [0, 1]
48     lateral offset from the route (> 0 = vehicle left of the route)          m         / 10     [-1, 1]
49-50  navigation checkpoint 1 (route point 8 m ahead of the projection): x, y  m         / 20     [-1, 1]
       in the vehicle frame
51-52  navigation checkpoint 2 (16 m ahead): x, y in the vehicle frame          m         / 20     [-1, 1]
53     speed limit of the closest lane                                          m/s       / 40     [0, 1]
54     route reference speed: the route owner's logged speed at the projection  m/s       / 40     [0, 1]
55-84  vehicle lidar (30 rays, 360 deg) against other vehicles' oriented boxes  m         / 50     [0, 1]
85-99  3 nearest vehicles (centre distance < 50 m), nearest first, 5 slots      m, m/s             [-1, 1]
       each: present (1/0), dx, dy (vehicle frame, / 50), dvx, dvy (velocity
       relative to the viewer, vehicle frame, / 30); absent vehicles are all 0
====== ======================================================================== ========= ======== =========

Extras beyond CAT's layout, and why: the lane speed limit and the route reference speed give a driver a
target speed without memory (the heuristic driver uses them); the presence flags make an absent neighbour
distinguishable from one at (0, 0). CAT's navigation also carries lane curvature; here the second checkpoint
carries the curve.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence

import numpy as np
from gymnasium import spaces

from seal.envs.kinematics import MAX_SPEED_MPS, AgentState
from seal.envs.obs_kernels import (  # the layout's constants live with the kernels that compile them in
    CHECKPOINT_SPACING_M,
    EDGE_RANGE_M,
    LATERAL_SCALE_M,
    LIDAR_RANGE2,
    LIDAR_RANGE_M,
    LIDAR_REACH2,
    LINE_RANGE_M,
    N_EDGE_RAYS,
    N_LIDAR_RAYS,
    N_LINE_RAYS,
    N_NEAREST,
    NAV_SCALE_M,
    NEAREST_SLOTS,
    OBS_DIM,
    OBS_HIGH,
    OBS_LOW,
    REL_SPEED_SCALE,
    YAW_RATE_SCALE,
    observe_viewer,
)
from seal.envs.rays import ray_angles
from seal.envs.road_geometry import RoadGeometry, SegmentGrid, Segments
from seal.envs.route import Route, RouteProjection

__all__ = [
    "CHECKPOINT_SPACING_M", "EDGE_RANGE_M", "LATERAL_SCALE_M", "LIDAR_RANGE2", "LIDAR_RANGE_M", "LIDAR_REACH2",
    "LINE_RANGE_M", "MAX_SPEED_MPS", "N_EDGE_RAYS", "N_LIDAR_RAYS", "N_LINE_RAYS", "N_NEAREST", "NAV_SCALE_M",
    "NEAREST_SLOTS", "OBS_DIM", "OBS_HIGH", "OBS_LOW", "REL_SPEED_SCALE", "YAW_RATE_SCALE", "ObservationBuilder",
    "observation_space",
]

# Slot indices (the array blocks' starts are the kernels' constants, `seal.envs.obs_kernels`).
EDGE_RAYS = slice(0, 30)
HEADING_ERROR = 30
SPEED = 31
STEERING = 32
LAST_ACTION = slice(33, 35)
YAW_RATE = 35
LINE_RAYS = slice(36, 48)
LATERAL = 48
NAV = slice(49, 53)
SPEED_LIMIT = 53
REF_SPEED = 54
LIDAR = slice(55, 85)
NEAREST = slice(85, 100)

_EDGE_ANG = ray_angles(N_EDGE_RAYS)
_LINE_ANG = ray_angles(N_LINE_RAYS)
_LIDAR_ANG = ray_angles(N_LIDAR_RAYS)


RAY_CELL_M = 5.0
"""Grid cell (m) of the ray casts' segment look-up (`_RayGrid`): finer than the road geometry's 20 m cells, so a
viewer casts against fewer segments (a superset of all it can hit: the same distances)."""


class _RayGrid:
    """Segments a ray of range ``reach`` cast from a point can hit, looked up per ``cell`` grid cell: those of the
    `SegmentGrid` (bounding box within ``reach`` of the cell) that also come within ``reach`` + half the cell
    diagonal of the cell centre (a point of the cell is at most that far from it): a superset of every segment
    within ``reach`` of the point, so the ray distances are the same as against all segments.

    A cell's segments are one contiguous ``[4, M]`` array (rows: start x, start y, vector x, vector y; m); a cell
    without segments holds one NaN segment (never hit), so ``M >= 1``."""

    def __init__(self, segments: Segments, reach: float, cell: float) -> None:
        self.cell = float(cell)
        self._grid = SegmentGrid(segments, reach=reach, cell=cell)
        self._limit2 = (reach + cell * math.sqrt(0.5) + 0.01) ** 2  # 1 cm against rounding

    def cell_segments(self, key: tuple[int, int]) -> np.ndarray:
        """The ``[4, M]`` segments of grid cell ``key`` (= ``floor(x / cell), floor(y / cell)``); not memoised here
        (`_RoadCache` keeps what it uses)."""
        x, y = (key[0] + 0.5) * self.cell, (key[1] + 0.5) * self.cell  # the centre: in the same cell
        s = self._grid.query(x, y)
        px, py = x - s.ax, y - s.ay
        t = np.clip((px * s.ex + py * s.ey) / np.maximum(s.ex * s.ex + s.ey * s.ey, 1e-18), 0.0, 1.0)
        m = (px - t * s.ex) ** 2 + (py - t * s.ey) ** 2 <= self._limit2
        return np.stack([s.ax[m], s.ay[m], s.ex[m], s.ey[m]]) if m.any() else np.full((4, 1), np.nan)


class _RoadCache:
    """Per-road state shared by every builder on that road (a `ScenarioEnv` makes a builder per episode): the edge
    and line rays' segment grids (`RAY_CELL_M` cells) and, memoised on first use, each viewer cell's edge and line
    segments (one dict lookup per viewer and step)."""

    def __init__(self, geometry: RoadGeometry) -> None:
        e, ln = geometry.edges, geometry.lines
        self.edges = _RayGrid(e.segments, reach=e.reach, cell=RAY_CELL_M)
        self.lines = _RayGrid(ln.segments, reach=ln.reach, cell=RAY_CELL_M)
        self._cells: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}

    def cell(self, key: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Edge and line segments ``[4, M]`` of viewer cell ``key`` (`_RayGrid.cell_segments`)."""
        hit = self._cells.get(key)
        if hit is None:
            hit = (self.edges.cell_segments(key), self.lines.cell_segments(key))
            self._cells[key] = hit
        return hit


_ROAD_CACHE: weakref.WeakKeyDictionary[RoadGeometry, _RoadCache] = weakref.WeakKeyDictionary()


def observation_space() -> spaces.Box:
    """``Box(OBS_LOW, OBS_HIGH, (100,), float32)``."""
    return spaces.Box(OBS_LOW.copy(), OBS_HIGH.copy(), dtype=np.float32)


class ObservationBuilder:
    """Builds the `OBS_DIM` observation of one vehicle on one road (see the module docstring for the layout).

    The rays, lidar and nearest vehicles of each viewer are one compiled call (`seal.envs.obs_kernels.observe_viewer`)
    on the road segments of its ray-grid cell; the scalar slots (state, route) are Python float maths.
    `build_many` builds several viewers' observations of one world state (the ego and a reactive adversary in the
    same step): every viewer's result equals its own `build` (its own box, ``self_rows``, is left out).
    """

    def __init__(self, geometry: RoadGeometry) -> None:
        self.geometry = geometry
        cache = _ROAD_CACHE.get(geometry)
        if cache is None:
            cache = _RoadCache(geometry)
            _ROAD_CACHE[geometry] = cache
        self._road = cache

    def build(
        self,
        state: AgentState,
        route: Route,
        others: np.ndarray,
        projection: RouteProjection | None = None,
    ) -> np.ndarray:
        """Observation ``[OBS_DIM]`` float32 of the vehicle in ``state``.

        Args:
            state: the viewer (its ``steering`` / ``accel`` are the last action, ``yaw_rate`` its yaw rate).
            route: the route the viewer follows.
            others: ``[N, >=7]`` other agents in the track layout (x, y, heading, vx, vy, length, width, valid),
                the viewer excluded; with the valid column, rows with valid < 0.5 are left out.
            projection: the viewer's projection on ``route`` if already known (else computed, unhinted).
        """
        if projection is None:
            projection = route.project(state.x, state.y)
        return self._build((state,), (route,), (projection,), others, (-1,))[0]

    def build_many(
        self,
        states: Sequence[AgentState],
        routes: Sequence[Route],
        projections: Sequence[RouteProjection],
        boxes: np.ndarray,
        self_rows: Sequence[int],
    ) -> np.ndarray:
        """Observations ``[V, OBS_DIM]`` float32 of ``V`` viewers of the same world state.

        Args:
            states, routes, projections: per viewer, as in `build` (projections required).
            boxes: ``[N, >=7]`` every agent in the track layout, the viewers included; with the valid column
                (the 8th), rows with valid < 0.5 (absent agents) are left out.
            self_rows: per viewer, its own row in ``boxes`` (left out of its lidar and nearest slots), or -1.
        """
        if not (len(states) == len(routes) == len(projections) == len(self_rows)) or not states:
            raise ValueError("build_many: states, routes, projections and self_rows need one entry per viewer")
        return self._build(states, routes, projections, boxes, self_rows)

    def _build(
        self,
        states: Sequence[AgentState],
        routes: Sequence[Route],
        projections: Sequence[RouteProjection],
        boxes: np.ndarray,
        self_rows: Sequence[int],
    ) -> np.ndarray:
        speed_limit_at = self.geometry.speed_limit_at
        cell_of = self._road.cell
        boxes = np.ascontiguousarray(boxes, dtype=np.float64)
        obs = np.empty((len(states), OBS_DIM), dtype=np.float32)
        for v, (st, route, proj) in enumerate(zip(states, routes, projections, strict=True)):
            x, y = st.x, st.y
            edges, lines = cell_of((math.floor(x / RAY_CELL_M), math.floor(y / RAY_CELL_M)))
            observe_viewer(obs[v], x, y, st.heading, st.speed, st.steering, st.accel, st.yaw_rate, proj.s,
                           proj.lateral, proj.heading, route.nav, speed_limit_at(x, y), edges, lines, boxes,
                           self_rows[v])
        return obs
