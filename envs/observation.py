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

import numpy as np
from gymnasium import spaces

from envs.kinematics import MAX_SPEED_MPS, AgentState
from envs.rays import _cast, ray_angles
from envs.road_geometry import RoadGeometry
from envs.route import Route, RouteProjection

N_EDGE_RAYS = 30
EDGE_RANGE_M = 50.0
N_LINE_RAYS = 12
LINE_RANGE_M = 20.0
N_LIDAR_RAYS = 30
LIDAR_RANGE_M = 50.0
N_NEAREST = 3
CHECKPOINT_SPACING_M = 8.0
NAV_SCALE_M = 20.0
LATERAL_SCALE_M = 10.0
YAW_RATE_SCALE = 2.0
REL_SPEED_SCALE = 30.0

# Slot indices.
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
NEAREST_SLOTS = 5
OBS_DIM = 100

OBS_LOW = np.full(OBS_DIM, -1.0, dtype=np.float32)
OBS_HIGH = np.ones(OBS_DIM, dtype=np.float32)
for _sl in (EDGE_RAYS, LINE_RAYS, LIDAR):
    OBS_LOW[_sl] = 0.0
for _i in (SPEED, SPEED_LIMIT, REF_SPEED):
    OBS_LOW[_i] = 0.0
OBS_LOW[NEAREST.start :: NEAREST_SLOTS] = 0.0  # presence flags

_EDGE_ANG = ray_angles(N_EDGE_RAYS)
_EDGE_COS, _EDGE_SIN = np.cos(_EDGE_ANG), np.sin(_EDGE_ANG)
_LINE_ANG = ray_angles(N_LINE_RAYS)
_LINE_COS, _LINE_SIN = np.cos(_LINE_ANG), np.sin(_LINE_ANG)
_LIDAR_ANG = ray_angles(N_LIDAR_RAYS)
_LIDAR_COS, _LIDAR_SIN = np.cos(_LIDAR_ANG), np.sin(_LIDAR_ANG)
assert np.allclose(_LIDAR_ANG, _EDGE_ANG)  # the lidar reuses the edge rays' directions
_RAY_COS = np.concatenate([_EDGE_COS, _LINE_COS])
_RAY_SIN = np.concatenate([_EDGE_SIN, _LINE_SIN])
# Box corners FL, FR, RR, RL as multiples of the half-length / half-width vectors, and the edge vectors
# corner k -> corner k + 1 (FL->FR, FR->RR, RR->RL, RL->FL).
_SL = np.array([1.0, 1.0, -1.0, -1.0])
_SW = np.array([1.0, -1.0, -1.0, 1.0])
_EL = np.array([0.0, -2.0, 0.0, 2.0])
_EW = np.array([-2.0, 0.0, 2.0, 0.0])
_LIDAR_REACH2 = (LIDAR_RANGE_M + 8.0) ** 2
"""Vehicles whose centre is farther than this (squared, m^2) cannot reach into lidar range (8 m > half the
diagonal of a 15 m truck)."""


def observation_space() -> spaces.Box:
    """``Box(OBS_LOW, OBS_HIGH, (100,), float32)``."""
    return spaces.Box(OBS_LOW.copy(), OBS_HIGH.copy(), dtype=np.float32)


class ObservationBuilder:
    """Builds the `OBS_DIM` observation of one vehicle on one road (see the module docstring for the layout)."""

    def __init__(self, geometry: RoadGeometry) -> None:
        self.geometry = geometry

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
            others: ``[N, >=7]`` other present agents in the track layout (x, y, heading, vx, vy, length,
                width, ...), the viewer excluded.
            projection: the viewer's projection on ``route`` if already known (else computed, unhinted).
        """
        if projection is None:
            projection = route.project(state.x, state.y)
        # One error-state context for all ray casts (parallel rays divide by zero; those are rejected).
        with np.errstate(divide="ignore", invalid="ignore"):
            return self._build(state, route, others, projection)

    def _build(self, state: AgentState, route: Route, others: np.ndarray, projection: RouteProjection) -> np.ndarray:
        # Written for few numpy calls: at ~1 us each, call count, not array size, sets the cost here.
        geom = self.geometry
        x, y, h = state.x, state.y, state.heading
        c, s = math.cos(h), math.sin(h)
        obs = np.empty(OBS_DIM, dtype=np.float32)
        dx = c * _RAY_COS - s * _RAY_SIN  # world-frame directions of the 30 edge / lidar rays, then 12 line rays
        dy = s * _RAY_COS + c * _RAY_SIN
        dx30, dy30, dx12, dy12 = dx[:N_EDGE_RAYS], dy[:N_EDGE_RAYS], dx[N_EDGE_RAYS:], dy[N_EDGE_RAYS:]

        seg = geom.edges.query(x, y)
        obs[EDGE_RAYS] = _cast(dx30, dy30, seg.ax - x, seg.ay - y, seg.ex, seg.ey, EDGE_RANGE_M) / EDGE_RANGE_M
        seg = geom.lines.query(x, y)
        obs[LINE_RAYS] = _cast(dx12, dy12, seg.ax - x, seg.ay - y, seg.ex, seg.ey, LINE_RANGE_M) / LINE_RANGE_M

        # Ego state and route (scalar maths).
        herr = (projection.heading - h + math.pi) % (2 * math.pi) - math.pi
        p1x, p1y = route.point_at(projection.s + CHECKPOINT_SPACING_M)
        p2x, p2y = route.point_at(projection.s + 2 * CHECKPOINT_SPACING_M)
        p1x, p1y, p2x, p2y = p1x - x, p1y - y, p2x - x, p2y - y
        obs[HEADING_ERROR : LINE_RAYS.start] = (
            herr / math.pi,
            state.speed / MAX_SPEED_MPS,
            state.steering,
            state.steering,
            state.accel,
            state.yaw_rate / YAW_RATE_SCALE,
        )
        obs[LATERAL : LIDAR.start] = (
            projection.lateral / LATERAL_SCALE_M,
            (p1x * c + p1y * s) / NAV_SCALE_M,
            (p1y * c - p1x * s) / NAV_SCALE_M,
            (p2x * c + p2y * s) / NAV_SCALE_M,
            (p2y * c - p2x * s) / NAV_SCALE_M,
            geom.speed_limit_at(x, y) / MAX_SPEED_MPS,
            route.speed_at(projection.s) / MAX_SPEED_MPS,
        )

        # Other vehicles: lidar against the boxes of those that can reach into range, and the nearest three.
        nearest = [0.0] * (N_NEAREST * NEAREST_SLOTS)
        near = np.zeros(0, dtype=np.int64)
        if others.shape[0]:
            rx = others[:, 0] - x
            ry = others[:, 1] - y
            d2 = rx * rx + ry * ry
            near = np.flatnonzero(d2 < _LIDAR_REACH2)
        if near.size:
            o = others[near]
            rxn, ryn = rx[near], ry[near]
            co, so = np.cos(o[:, 2]), np.sin(o[:, 2])
            lx, ly = (0.5 * o[:, 5]) * co, (0.5 * o[:, 5]) * so  # half-length vector
            wx, wy = (-0.5 * o[:, 6]) * so, (0.5 * o[:, 6]) * co  # half-width vector (to the left)
            # Corners FL, FR, RR, RL [n, 4]; edge k runs from corner k to corner k + 1.
            lx, ly, wx, wy = lx[:, None], ly[:, None], wx[:, None], wy[:, None]
            cx = rxn[:, None] + lx * _SL + wx * _SW
            cy = ryn[:, None] + ly * _SL + wy * _SW
            ex = lx * _EL + wx * _EW
            ey = ly * _EL + wy * _EW
            hits = _cast(dx30, dy30, cx.ravel(), cy.ravel(), ex.ravel(), ey.ravel(), LIDAR_RANGE_M)
            obs[LIDAR] = hits / LIDAR_RANGE_M
            dn = d2[near]
            order = np.argsort(dn)[:N_NEAREST]
            vx, vy = state.speed * c, state.speed * s
            for k, i in enumerate(order.tolist()):
                if dn[i] >= LIDAR_RANGE_M * LIDAR_RANGE_M:
                    break
                px, py = float(rxn[i]), float(ryn[i])
                dvx, dvy = float(o[i, 3]) - vx, float(o[i, 4]) - vy
                nearest[k * NEAREST_SLOTS : (k + 1) * NEAREST_SLOTS] = (
                    1.0,
                    (px * c + py * s) / LIDAR_RANGE_M,
                    (py * c - px * s) / LIDAR_RANGE_M,
                    (dvx * c + dvy * s) / REL_SPEED_SCALE,
                    (dvy * c - dvx * s) / REL_SPEED_SCALE,
                )
        else:
            obs[LIDAR] = 1.0
        obs[NEAREST] = nearest
        np.clip(obs, OBS_LOW, OBS_HIGH, out=obs)
        return obs
