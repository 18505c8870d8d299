"""Observation slots against hand-computed geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scenario_factory as sf
import shapely
from kernel_reference import cast_rays

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import CURRENT_STEP
from seal.envs import observation as ob
from seal.envs.behaviors import PolicyBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import AgentState
from seal.envs.road_geometry import RoadGeometry
from seal.envs.route import Route
from seal.envs.scenario_env import ScenarioEnv

ROAD = sf.straight_road(3)  # lanes at y = 0, 4, 8 (width 4): edges at y = -2 and y = 10, lines at y = 2, 6
GEOM = RoadGeometry(ROAD)
ROUTE = Route(np.array([[-50.0, 4.0], [300.0, 4.0]]), speeds=np.array([12.0, 12.0]))
NO_OTHERS = np.zeros((0, 7))
RAY84 = math.sin(math.radians(84))  # 30 rays: ray 7 is 84 deg left, ray 23 84 deg right


def _obs(state: AgentState, others: np.ndarray = NO_OTHERS, geom: RoadGeometry = GEOM) -> np.ndarray:
    obs = ob.ObservationBuilder(geom).build(state, ROUTE, others)
    assert obs.dtype == np.float32 and obs.shape == (ob.OBS_DIM,)
    assert ob.observation_space().contains(obs)
    return obs


def _car(x: float, y: float, heading: float = 0.0, vx: float = 0.0, vy: float = 0.0) -> np.ndarray:
    return np.array([[x, y, heading, vx, vy, 5.0, 2.0]])


def test_vehicle_ahead_in_forward_lidar_ray_and_nearest_slot() -> None:
    obs = _obs(AgentState(0.0, 4.0, 0.0, 15.0), _car(20.0, 4.0, vx=10.0))
    lidar = obs[ob.LIDAR]
    assert lidar[0] == pytest.approx((20.0 - 2.5) / 50.0, abs=1e-6)
    assert lidar[15] == 1.0 and lidar[7] == 1.0
    near = obs[ob.NEAREST].reshape(3, 5)
    np.testing.assert_allclose(near[0], [1.0, 20 / 50, 0.0, (10 - 15) / 30, 0.0], atol=1e-6)
    np.testing.assert_array_equal(near[1:], 0.0)


def test_lidar_is_in_the_vehicle_frame() -> None:
    # Facing +y, a car 20 m ahead (at +y) and one 10 m behind.
    state = AgentState(0.0, 4.0, math.pi / 2, 0.0)
    obs = _obs(state, np.vstack([_car(0.0, 24.0, math.pi / 2), _car(0.0, -6.0, math.pi / 2)]))
    assert obs[ob.LIDAR][0] == pytest.approx(17.5 / 50, abs=1e-6)
    assert obs[ob.LIDAR][15] == pytest.approx(7.5 / 50, abs=1e-6)
    near = obs[ob.NEAREST].reshape(3, 5)
    np.testing.assert_allclose(near[0, :3], [1.0, -10 / 50, 0.0], atol=1e-6)  # nearest first
    np.testing.assert_allclose(near[1, :3], [1.0, 20 / 50, 0.0], atol=1e-6)


def test_vehicle_beside_hits_the_side_ray() -> None:
    # A car alongside, centre 4 m to the left and its broad side facing us: ray 7 (84 deg) meets its near side
    # (y = 3 m) at 3 / sin(84 deg).
    obs = _obs(AgentState(0.0, 0.0, 0.0, 10.0), _car(0.0, 4.0))
    assert obs[ob.LIDAR][7] == pytest.approx(3.0 / RAY84 / 50, abs=1e-6)


def test_far_vehicles_are_not_seen() -> None:
    obs = _obs(AgentState(0.0, 4.0, 0.0, 10.0), _car(60.0, 4.0))
    assert (obs[ob.LIDAR] == 1.0).all() and (obs[ob.NEAREST] == 0.0).all()


def test_road_edges_left_and_right() -> None:
    obs = _obs(AgentState(0.0, 4.0, 0.0, 10.0))
    edges = obs[ob.EDGE_RAYS]
    assert edges[7] == pytest.approx(6.0 / RAY84 / 50, abs=1e-5)  # left edge 6 m away (y = 10)
    assert edges[23] == pytest.approx(6.0 / RAY84 / 50, abs=1e-5)  # right edge 6 m away (y = -2)
    assert edges[0] == 1.0 and edges[15] == 1.0  # road continues > 50 m ahead and behind
    # In the left lane the left edge is 2 m away.
    assert _obs(AgentState(0.0, 8.0, 0.0, 10.0))[ob.EDGE_RAYS][7] == pytest.approx(2.0 / RAY84 / 50, abs=1e-5)
    # Turned 0.2 rad left, the forward ray meets the left edge at 6 / sin(0.2).
    assert _obs(AgentState(0.0, 4.0, 0.2, 10.0))[ob.EDGE_RAYS][0] == pytest.approx(6 / math.sin(0.2) / 50, abs=1e-5)


def test_road_end_is_an_edge() -> None:
    # The road starts at x = -100: 20 m behind a car at x = -80.
    assert _obs(AgentState(-80.0, 4.0, 0.0, 10.0))[ob.EDGE_RAYS][15] == pytest.approx(20.05 / 50, abs=1e-4)


def test_unpainted_road_still_has_edges() -> None:
    lane = LaneSpec("x", np.array([[-100.0, 0.0], [300.0, 0.0]]), 4.0, ("none", "none"))
    road = RoadDescription("polylines", (lane,))
    obs = _obs(AgentState(0.0, 0.0, 0.0, 10.0), geom=RoadGeometry(road))
    # Drivable-area edge 2 m away (plus the 5 cm the lane polygons are grown by before their union).
    assert obs[ob.EDGE_RAYS][7] == pytest.approx(2.05 / RAY84 / 50, abs=1e-5)
    assert (obs[ob.LINE_RAYS] == 1.0).all()  # nothing painted


def test_lane_line_rays() -> None:
    lines = _obs(AgentState(0.0, 4.0, 0.0, 10.0))[ob.LINE_RAYS]  # 12 rays: ray 3 left, ray 9 right
    assert lines[3] == pytest.approx(2.0 / 20) and lines[9] == pytest.approx(2.0 / 20)
    assert lines[0] == 1.0 and lines[6] == 1.0
    # 1 m left of the lane centre: the striped line at y = 6 is 1 m away, the one at y = 2 is 3 m away.
    lines = _obs(AgentState(0.0, 5.0, 0.0, 10.0))[ob.LINE_RAYS]
    assert lines[3] == pytest.approx(1.0 / 20) and lines[9] == pytest.approx(3.0 / 20)


def test_route_slots() -> None:
    h = 0.1
    obs = _obs(AgentState(0.0, 5.0, h, 16.0, steering=0.25, accel=-0.5, yaw_rate=0.4))
    assert obs[ob.HEADING_ERROR] == pytest.approx(-h / math.pi)
    assert obs[ob.LATERAL] == pytest.approx(1.0 / 10)  # 1 m left of the route
    c, s = math.cos(h), math.sin(h)
    expected = []
    for dx in (8.0, 16.0):  # checkpoints on the route (y = 4) 8 and 16 m ahead of the projection (x = 0)
        rx, ry = dx, -1.0
        expected += [(rx * c + ry * s) / 20, (-rx * s + ry * c) / 20]
    np.testing.assert_allclose(obs[ob.NAV], expected, atol=1e-6)
    assert obs[ob.SPEED] == pytest.approx(16 / 40)
    assert obs[ob.STEERING] == pytest.approx(0.25)
    np.testing.assert_allclose(obs[ob.LAST_ACTION], [0.25, -0.5])
    assert obs[ob.YAW_RATE] == pytest.approx(0.4 / 2)
    assert obs[ob.SPEED_LIMIT] == pytest.approx(30 / 40)
    assert obs[ob.REF_SPEED] == pytest.approx(12 / 40)


def test_env_fills_control_slots(lane_change) -> None:
    env = ScenarioEnv([lane_change])
    env.reset()
    obs, *_ = env.step(np.array([0.2, -0.5]))
    assert obs[ob.STEERING] == pytest.approx(0.2)
    np.testing.assert_allclose(obs[ob.LAST_ACTION], [0.2, -0.5])
    assert obs[ob.YAW_RATE] == pytest.approx(env._ego.yaw_rate / 2, rel=1e-5) and env._ego.yaw_rate > 0


def test_adversary_sees_from_its_own_viewpoint() -> None:
    road = sf.straight_road(2)
    ego = sf.simulate_track(road.lanes[0].centerline, 80.0, 20.0)
    adv = sf.simulate_track(road.lanes[0].centerline, 100.0, 20.0)
    scenario = sf.make_scenario(road, [ego, adv], "pair")
    seen: list[np.ndarray] = []

    class Spy(HeuristicDriver):
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            seen.append(observation)
            return super().predict(observation, state, episode_start, deterministic)

    env = ScenarioEnv([scenario], adversary=PolicyBehavior(Spy()))
    ego_obs, _ = env.reset()
    env.step(np.zeros(2))
    adv_obs = seen[0]
    gap = scenario.tracks[1, CURRENT_STEP, 0] - scenario.tracks[0, CURRENT_STEP, 0]
    # Centre-to-centre gap minus the other car's half length (rays start at the viewer's centre).
    assert ego_obs[ob.LIDAR][0] == pytest.approx((gap - 2.5) / 50, abs=1e-4)  # ego sees the adversary ahead
    assert adv_obs[ob.LIDAR][15] == pytest.approx((gap - 2.5) / 50, abs=1e-4)  # the adversary sees the ego behind
    assert adv_obs[ob.NEAREST][1] == pytest.approx(-gap / 50, abs=1e-4)


def test_ray_caster_matches_shapely() -> None:
    rng = np.random.default_rng(0)
    a = rng.uniform(-30, 30, (40, 2))
    e = rng.uniform(-10, 10, (40, 2))
    ang = ob._EDGE_ANG + 0.05
    got = cast_rays(np.cos(ang), np.sin(ang), a[:, 0], a[:, 1], e[:, 0], e[:, 1], 50.0)
    segs = shapely.MultiLineString([[p, p + d] for p, d in zip(a, e, strict=True)])
    for k, th in enumerate(ang):
        hit = shapely.LineString([(0, 0), (50 * math.cos(th), 50 * math.sin(th))]).intersection(segs)
        expected = 50.0 if hit.is_empty else shapely.distance(shapely.Point(0, 0), hit)
        assert got[k] == pytest.approx(expected, abs=1e-6)


def test_observations_stay_in_the_space(curve) -> None:
    env = ScenarioEnv([curve])
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, _ = env.reset()
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2))
            assert env.observation_space.contains(obs)
            done = terminated or truncated


def test_fine_ray_grid_gives_the_distances_of_all_road_segments(all_scenarios) -> None:
    """The observation's 5 m ray grid only drops segments out of ray range: edge and line rays equal a cast against
    every segment of the road, bit for bit."""
    rng = np.random.default_rng(3)
    checked = 0
    for scenario in all_scenarios[:6]:
        geom = RoadGeometry(scenario.road)
        builder = ob.ObservationBuilder(geom)
        track = scenario.tracks[scenario.ego_index]
        for row in track[track[:, 7] > 0.5][::7]:
            x, y = row[0] + rng.normal(0.0, 3.0), row[1] + rng.normal(0.0, 3.0)
            heading = row[2] + rng.normal(0.0, 0.5)
            obs = builder.build(AgentState(x, y, heading, 10.0, 4.5, 1.8), ROUTE, NO_OTHERS)
            c, s = math.cos(heading), math.sin(heading)
            for grid, ang, rng_m, sl in (
                (geom.edges, ob._EDGE_ANG, ob.EDGE_RANGE_M, ob.EDGE_RAYS),
                (geom.lines, ob._LINE_ANG, ob.LINE_RANGE_M, ob.LINE_RAYS),
            ):
                seg = grid.segments
                dx, dy = c * np.cos(ang) - s * np.sin(ang), s * np.cos(ang) + c * np.sin(ang)
                full = cast_rays(dx, dy, seg.ax - x, seg.ay - y, seg.ex, seg.ey, rng_m) / rng_m
                np.testing.assert_array_equal(obs[sl], np.clip(full, 0.0, 1.0).astype(np.float32))
            checked += 1
    assert checked > 20


def test_route_projection_matches_the_textbook_form() -> None:
    """`Route.project` (in-place numpy) equals clip((p . e) / |e|^2, 0, 1) on the windowed segments, bit for bit."""
    rng = np.random.default_rng(0)
    pts = np.cumsum(rng.normal(0.0, 3.0, (40, 2)) + [4.0, 0.0], axis=0)
    route = Route(pts, speeds=np.full(40, 10.0))
    a_all, e_all = route._cols[0:2].T, route._cols[2:4].T  # segment starts and vectors of the extended polyline
    s_all = np.concatenate([[0.0], np.cumsum(np.hypot(e_all[:, 0], e_all[:, 1]))]) - 50.0
    heading_all = np.arctan2(e_all[:, 1], e_all[:, 0])
    for _ in range(200):
        x, y = pts[rng.integers(40)] + rng.normal(0.0, 4.0, 2)
        hint = None if rng.random() < 0.3 else int(rng.integers(route.n_segments))
        lo, hi = (0, route.n_segments) if hint is None else (max(0, hint - 8), min(route.n_segments, hint + 40))
        a, e = a_all[lo:hi], e_all[lo:hi]
        seg_len = np.hypot(e[:, 0], e[:, 1])
        px, py = x - a[:, 0], y - a[:, 1]
        t = np.clip((px * e[:, 0] + py * e[:, 1]) / seg_len**2, 0.0, 1.0)
        k = int(np.argmin((px - t * e[:, 0]) ** 2 + (py - t * e[:, 1]) ** 2))
        s0 = s_all[lo + k]
        p = route.project(x, y, hint)
        assert p.segment == lo + k
        assert p.s == pytest.approx(s0 + float(t[k]) * float(seg_len[k]), abs=1e-9)
        assert p.lateral == (float(e[k, 0]) * float(py[k]) - float(e[k, 1]) * float(px[k])) / float(seg_len[k])
        assert p.heading == heading_all[lo + k]
