"""Lane projection, conflict points, future extrapolation (FE) and individual features."""

from __future__ import annotations

import numpy as np
import pytest
from scoring_builders import cross_road, scenario, straight_road, straight_track, track

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
