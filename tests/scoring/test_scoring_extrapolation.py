"""Lane projection, conflict points, future extrapolation (FE) and individual features."""

from __future__ import annotations

import numpy as np
import pytest
from scoring_builders import LENGTH_M, cross_road, scenario, straight_road, straight_track, track

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import CURRENT_STEP, DT_S, N_STEPS
from seal.scoring.extrapolation import future_extrapolate
from seal.scoring.frenet import RoadIndex
from seal.scoring.individual import INDIVIDUAL_FEATURES, individual_features, individual_score
from seal.scoring.tracks import from_tracks

R = 60.0


def circle_road() -> RoadDescription:
    """A counter-clockwise quarter circle of radius R around the origin, from angle -90 deg to 0 deg, continued by
    a straight lane north along x = R."""
    ang = np.linspace(-np.pi / 2, 0.0, 200)
    arc = LaneSpec("arc", np.stack([R * np.cos(ang), R * np.sin(ang)], axis=1), 4.0, successors=("north",))
    north = LaneSpec("north", np.array([[R, 0.0], [R, 300.0]]), 4.0)
    return RoadDescription("polylines", (arc, north))


def test_projection_on_straight_lane() -> None:
    index = RoadIndex(straight_road(x0=0.0, x1=100.0))
    proj = index.project(np.array([[10.0, 1.0], [50.0, -1.5], [20.0, 3.0], [30.0, 9.0]]), np.zeros(4))
    assert proj.lane.tolist() == [0, 0, 0, -1]  # 9 m off: farther than one lane width
    np.testing.assert_allclose(proj.s[:3], [10.0, 50.0, 20.0])
    np.testing.assert_allclose(proj.d[:3], [1.0, -1.5, 3.0])
    assert proj.in_lane.tolist() == [True, True, False, False]
    # Driving against the lane direction: no compatible lane.
    assert index.project(np.array([[10.0, 0.0]]), np.array([np.pi])).lane.tolist() == [-1]


def test_conflict_point_where_lanes_cross() -> None:
    np.testing.assert_allclose(RoadIndex(cross_road()).conflict_points, [[0.0, 0.0]], atol=1e-9)
    assert RoadIndex(straight_road()).conflict_points.shape == (0, 2)


def test_fe_follows_curved_lane_keeping_lateral_offset() -> None:
    # History: 10 m/s along the circle of radius R - 1 (1 m left of the centre line, counter-clockwise), the
    # agent reaches angle -60 deg at the current step; then (from step 12 on) it nearly stops in the log.
    v, r = 10.0, R - 1.0
    theta_now = np.deg2rad(-60.0)
    steps = np.arange(N_STEPS)
    theta = theta_now + (steps - CURRENT_STEP) * v * DT_S / r
    late = steps > CURRENT_STEP + 1
    theta[late] = theta[CURRENT_STEP + 1] + (steps[late] - CURRENT_STEP - 1) * 0.2 * DT_S / r
    agent = track(np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1))
    other = straight_track(R + 30.0, 1.0, y=250.0)
    s = scenario([agent, other], circle_road())
    index = RoadIndex(s.road)
    gt = from_tracks(s.tracks, index)
    fe = future_extrapolate(gt, index)
    np.testing.assert_array_equal(fe.pos[0, : CURRENT_STEP + 1], gt.pos[0, : CURRENT_STEP + 1])
    fut = fe.pos[0, CURRENT_STEP + 1 :]
    on_arc = np.arctan2(fut[:, 1], fut[:, 0]) < 0
    # Keeps the 1 m offset on the arc (radius R - 1) and after it on the straight successor (x = R - 1).
    np.testing.assert_allclose(np.hypot(fut[on_arc, 0], fut[on_arc, 1]), r, atol=0.02)
    np.testing.assert_allclose(fut[~on_arc, 0], R - 1.0, atol=0.02)
    assert (~on_arc).any()
    # Constant progress along the centre line: ds = the lane-tangential speed x dt (10 m/s x 0.1 s), whatever
    # the log does after the current step.
    s_now = R * (theta_now + np.pi / 2)
    ds = np.diff(np.concatenate([[s_now], R * (np.arctan2(fut[on_arc, 1], fut[on_arc, 0]) + np.pi / 2)]))
    np.testing.assert_allclose(ds, v * DT_S, rtol=2e-3)
    assert fe.valid[0].all() and fe.lane[0, -1] == 1  # ends on the successor lane "north"


def test_fe_constant_velocity_without_lane_and_gt_copy_when_not_current() -> None:
    road = straight_road()
    off = straight_track(0.0, 12.0, y=40.0)  # far from the lane: no lane, Cartesian constant velocity
    late = straight_track(0.0, 10.0)
    late[: CURRENT_STEP + 5, :] = 0.0  # appears after the current step: nothing to extrapolate from
    s = scenario([straight_track(0.0, 10.0), off, late], road)
    index = RoadIndex(road)
    gt = from_tracks(s.tracks, index)
    fe = future_extrapolate(gt, index)
    k = np.arange(1, N_STEPS - CURRENT_STEP)
    np.testing.assert_allclose(fe.pos[1, CURRENT_STEP + 1 :, 0], gt.pos[1, CURRENT_STEP, 0] + 12.0 * k * DT_S)
    np.testing.assert_array_equal(fe.pos[2], gt.pos[2])
    np.testing.assert_array_equal(fe.valid[2], gt.valid[2])


def test_individual_features() -> None:
    road = straight_road(limit=10.0)
    steps = np.arange(N_STEPS) * DT_S
    # Accelerates at 2 m/s^2 from 5 m/s: max speed 23 m/s, 13 m/s over the limit.
    speed = 5.0 + 2.0 * steps
    accel = track(np.stack([5.0 * steps + steps**2, np.zeros(N_STEPS)], axis=1),
                  vel=np.stack([speed, np.zeros(N_STEPS)], axis=1))
    stand = straight_track(50.0, 0.0)
    s = scenario([accel, stand], road)
    f = individual_features(from_tracks(s.tracks, RoadIndex(road)))
    assert f["speed"][0] == pytest.approx(23.0)
    assert f["speed_over_limit"][0] == pytest.approx(f["speed"][0] - 10.0)
    assert f["acc"][0] == pytest.approx(2.0, abs=1e-3)
    assert f["jerk"][0] == pytest.approx(0.0, abs=1e-3)
    assert f["waiting"].tolist() == pytest.approx([0.0, (N_STEPS - 1) * DT_S])  # stands all 9 s
    assert f["in_lane"].tolist() == [1.0, 1.0]
    score = individual_score(f)
    expected = min(10, f["speed_over_limit"][0]) + 0.1 * 2.0 + 0.1 * f["speed"][0]  # + jerk 0, waiting 0
    assert score[0] == pytest.approx(expected, abs=1e-3)
    assert score[1] == pytest.approx(np.sqrt(9.0))
    assert len(INDIVIDUAL_FEATURES) == 7


def fork_road() -> RoadDescription:
    """Lane "in" east along y = 0 up to x = 0, forking into "straight" (east) and "left" (a quarter circle of
    radius 30 m to the north, then north along x = 30)."""
    ang = np.linspace(-np.pi / 2, 0.0, 60)
    arc = np.stack([30.0 * np.cos(ang), 30.0 + 30.0 * np.sin(ang)], axis=1)
    arc = np.concatenate([arc, [[30.0, 200.0]]])
    lanes = (
        LaneSpec("in", np.array([[-200.0, 0.0], [0.0, 0.0]]), 4.0, successors=("straight", "left")),
        LaneSpec("straight", np.array([[0.0, 0.0], [300.0, 0.0]]), 4.0),
        LaneSpec("left", arc, 4.0),
    )
    return RoadDescription("polylines", lanes)


def _drive(path_xy: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """Positions ``[T, 2]`` along polyline ``path_xy`` at per-step speeds ``[T]`` (m/s), from its start."""
    seg = np.diff(path_xy, axis=0)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    s = np.concatenate([[0.0], np.cumsum(speeds[:-1] * DT_S)])
    return np.stack([np.interp(s, cum, path_xy[:, 0]), np.interp(s, cum, path_xy[:, 1])], axis=1)


def test_fe_follows_the_branch_the_agent_takes_not_the_straightest() -> None:
    road = fork_road()
    left_path = np.concatenate([np.array([[-40.0, 0.0]]), road.lanes[2].centerline])
    turner = track(_drive(left_path, np.full(N_STEPS, 10.0)))  # reaches the fork at step 40, turns left
    goer = track(_drive(np.array([[-40.0, 0.0], [300.0, 0.0]]), np.full(N_STEPS, 10.0)))
    other = straight_track(200.0, 5.0, y=0.0)
    s = scenario([turner, goer, other], road)
    index = RoadIndex(road)
    gt = from_tracks(s.tracks, index)
    assert 2 in gt.lane[0, CURRENT_STEP:] and 2 not in gt.lane[1]
    fe = future_extrapolate(gt, index)
    # Same speed, same start: the turner's counterfactual turns north with the log, the other goes straight.
    assert fe.lane[0, -1] == 2 and fe.pos[0, -1, 1] > 20.0
    assert fe.lane[1, -1] == 1 and abs(fe.pos[1, -1, 1]) < 1e-6
    np.testing.assert_allclose(fe.pos[0, -1], gt.pos[0, -1], atol=0.5)  # constant speed: FE = the log


def _braking_towards_crossing(x_now: float, v_now: float, decel: float) -> np.ndarray:
    """East-bound track on `cross_road` at ``x_now`` (m) and ``v_now`` (m/s) at the current step, braking at
    ``decel`` (m/s^2) in its history (and in its log after, which FE does not read)."""
    t = (np.arange(N_STEPS) - CURRENT_STEP) * DT_S
    speed = np.maximum(v_now - decel * t, 0.0)
    x = x_now + v_now * t - 0.5 * decel * t**2
    x = np.where(speed > 0, x, x_now + v_now**2 / (2 * decel))
    return track(np.stack([x, np.zeros(N_STEPS)], axis=1), vel=np.stack([speed, np.zeros(N_STEPS)], axis=1))


def test_fe_of_a_decelerating_agent_stops_before_the_conflict_point() -> None:
    from seal.scoring.extrapolation import STOP_CLEARANCE_M

    road = cross_road()  # conflict point at the origin
    index = RoadIndex(road)
    braking = _braking_towards_crossing(-30.0, 10.0, 1.0)  # at 1 m/s^2 it would stop 20 m past the crossing
    cruising = straight_track(-30.0 - 10.0 * CURRENT_STEP * DT_S, 10.0)  # same place and speed, not braking
    crossing = track(np.stack([np.zeros(N_STEPS), -150.0 + 5.0 * np.arange(N_STEPS) * DT_S], axis=1))
    s = scenario([braking, crossing, cruising], road)
    fe = future_extrapolate(from_tracks(s.tracks, index), index)
    front = fe.pos[0, :, 0] + 0.5 * LENGTH_M
    stop = -STOP_CLEARANCE_M
    assert front[-1] == pytest.approx(stop, abs=0.05)  # stopped with its front 2 m before the crossing
    assert np.all(front <= stop + 1e-6) and np.all(np.diff(fe.pos[0, CURRENT_STEP:, 0]) >= -1e-9)
    # Constant deceleration v^2 / (2 room) = 100 / (2 x (30 - 2.25 - 2)) m/s^2, stopped after v / decel s.
    decel = 100.0 / (2.0 * (30.0 - 0.5 * LENGTH_M - STOP_CLEARANCE_M))
    speed = np.hypot(fe.vel[0, :, 0], fe.vel[0, :, 1])
    k = CURRENT_STEP + 20  # 2 s in, still braking
    assert speed[k] == pytest.approx(10.0 - decel * 2.0 + 0.5 * decel * DT_S, abs=0.05)
    # The cruising agent keeps its speed through the crossing (the old rule, unchanged).
    assert fe.pos[2, -1, 0] == pytest.approx(-30.0 + 10.0 * 8.0, abs=1e-3)


def test_fe_of_a_gently_decelerating_agent_without_stop_point_keeps_its_deceleration() -> None:
    road = straight_road(x0=-100.0, x1=2000.0)
    index = RoadIndex(road)
    gentle = _braking_towards_crossing(0.0, 20.0, 1.0)  # no conflict point, road end far away
    s = scenario([gentle, straight_track(300.0, 20.0)], road)
    fe = future_extrapolate(from_tracks(s.tracks, index), index)
    # 8 s at 1 m/s^2 from 20 m/s: 20 x 8 - 0.5 x 64 = 128 m.
    assert fe.pos[0, -1, 0] == pytest.approx(128.0, abs=0.2)
    # A car that brakes hard can stop short of a point it cannot reach: it keeps its own (larger) deceleration.
    hard = _braking_towards_crossing(0.0, 20.0, 6.0)
    s = scenario([hard, straight_track(300.0, 20.0)], road)
    fe = future_extrapolate(from_tracks(s.tracks, index), index)
    assert fe.pos[0, -1, 0] == pytest.approx(400.0 / 12.0, abs=0.2)
