"""GOOSE's adversary curve: the fit in the adversary's frame, the 12-d edit, and the re-timed replay track."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from seal.adversaries.goose.curve import N_CURVE_FEATURES, Frame, GooseCurve, _smoothstep
from seal.adversaries.goose.spec import GooseSpec
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, N_STEPS, VALID, VX, VY, Scenario, X, Y

SPEC = GooseSpec()


def test_frame_round_trip_and_axes() -> None:
    f = Frame(10.0, -5.0, math.pi / 2)
    np.testing.assert_allclose(f.to_local(np.array([10.0, -5.0])), [0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(f.to_local(np.array([10.0, -2.0])), [3.0, 0.0], atol=1e-12)  # 3 m ahead
    np.testing.assert_allclose(f.to_local(np.array([8.0, -5.0])), [0.0, 2.0], atol=1e-12)  # 2 m to the left
    pts = np.random.default_rng(0).normal(size=(7, 2)) * 30
    np.testing.assert_allclose(f.to_world(f.to_local(pts)), pts, atol=1e-9)


@pytest.mark.parametrize("timing", ["log", "curve"])
def test_fit_is_in_the_adversary_frame_and_the_zero_edit_replays_the_log(lane_change: Scenario, timing: str) -> None:
    c = GooseCurve.from_scenario(lane_change, timing)
    log = lane_change.track(lane_change.adv_id).astype(np.float64)
    assert c.n_future == N_STEPS - 1 - CURRENT_STEP
    np.testing.assert_allclose(c.fitted.ctrl[0], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(c.frame.to_world(c.fitted.ctrl[-1]), log[-1, [X, Y]], atol=1e-6)
    assert c.fit_error_m < 0.01  # a straight lane
    track = c.track()
    assert track.shape == (N_STEPS, 8)
    np.testing.assert_array_equal(track[: CURRENT_STEP + 1], log[: CURRENT_STEP + 1])
    np.testing.assert_allclose(track[:, [X, Y]], log[:, [X, Y]], atol=0.05)
    np.testing.assert_allclose(np.hypot(track[:, VX], track[:, VY]), np.hypot(log[:, VX], log[:, VY]), atol=0.02)
    np.testing.assert_allclose(track[:, HEADING], log[:, HEADING], atol=1e-3)
    assert c.length_ratio() == pytest.approx(1.0, abs=1e-3)


@pytest.mark.parametrize("timing", ["log", "curve"])
def test_edit_moves_points_1_to_4_within_bounds(lane_change: Scenario, timing: str) -> None:
    c = GooseCurve.from_scenario(lane_change, timing)
    a = np.zeros(12)
    a[6] = 1.0  # x of control point 4
    a[3] = -0.5  # y of control point 2
    a[9] = 1.0  # weight of control point 2
    e = c.edited(a, SPEC)
    np.testing.assert_allclose(e.ctrl[0], c.ctrl[0])
    np.testing.assert_allclose(e.ctrl[4] - c.ctrl[4], [SPEC.shift_m, 0.0])
    np.testing.assert_allclose(e.ctrl[2] - c.ctrl[2], [0.0, -0.5 * SPEC.shift_m * SPEC.point_scale[1]])
    np.testing.assert_allclose(e.weights, [1, 1, SPEC.weight_factor, 1, 1])
    np.testing.assert_allclose(c.ctrl, c.fitted.ctrl)  # the original is untouched (frozen edit)
    many = c
    for _ in range(20):
        many = many.edited(np.ones(12), SPEC)
    limit = np.array(np.broadcast_to(SPEC.max_offset_m * np.array(SPEC.point_scale)[:, None], (4, 2)))
    limit[0, 1] = 0.0  # point 1 slides along the start heading only: the curve keeps leaving along it
    if timing == "curve":
        limit[0, 0] = 0.0  # ... and on a timed curve it is the current velocity: it does not move at all
    np.testing.assert_allclose(many.ctrl[1:] - c.fitted.ctrl[1:], limit)
    fixed = [0, 1] if timing == "curve" else [1]
    np.testing.assert_allclose(np.delete(many.features(SPEC)[8:16], fixed), 1.0)  # offsets normalised to limits
    assert np.all(many.features(SPEC)[8:16][fixed] == 0.0)
    np.testing.assert_allclose(many.weights[1:], SPEC.weight_max)
    np.testing.assert_allclose(many.ctrl[0], c.fitted.ctrl[0])
    np.testing.assert_allclose(many.reset_edit().ctrl, c.fitted.ctrl)
    with pytest.raises(ValueError, match="12"):
        c.edited(np.zeros(5), SPEC)


def test_retiming_keeps_the_logged_profile_scaled_to_the_new_length(lane_change: Scenario) -> None:
    """Log: constant 27 m/s along a straight lane. Stretching the (straight) curve by shift_m: with x = k / K the
    share of the log covered at future step k of K, the distance along the curve is L0 x (1 + (r - 1) g(x)) with g
    the smoothstep; the speed stays continuous."""
    c = GooseCurve.from_scenario(lane_change, "log")
    a = np.zeros(12)
    a[6] = 1.0
    e = c.edited(a, SPEC)
    r = e.curve.length() / c.log_length_m
    assert r == pytest.approx((c.log_length_m + SPEC.shift_m) / c.log_length_m, abs=1e-3)
    track = e.track()
    x = c.s_log[1:] / c.log_length_m
    np.testing.assert_allclose(x, np.arange(1, c.n_future + 1) / c.n_future, atol=1e-6)  # constant speed
    g, _ = _smoothstep(x)
    expected_s = c.log_length_m * x * (1.0 + (r - 1.0) * g)
    local = c.frame.to_local(track[CURRENT_STEP + 1 :, [X, Y]])
    np.testing.assert_allclose(local[:, 0], expected_s, atol=0.02)  # along the straight curve
    np.testing.assert_allclose(local[:, 1], 0.0, atol=0.02)
    np.testing.assert_allclose(local[-1], e.ctrl[-1], atol=1e-6)  # ends at the moved end point
    speed = np.hypot(track[:, VX], track[:, VY])
    assert abs(speed[CURRENT_STEP + 1] - speed[CURRENT_STEP]) < 0.01  # no jump into the episode
    # Velocities agree with the positions (central differences along the track).
    pos_speed = np.hypot(*np.diff(track[CURRENT_STEP:, [X, Y]], axis=0).T) / DT_S
    mid_speed = 0.5 * (speed[CURRENT_STEP:-1] + speed[CURRENT_STEP + 1 :])
    np.testing.assert_allclose(pos_speed, mid_speed, atol=0.05)
    # With s0 = v0 t the speed is v0 (1 + (r - 1)(9 tau^2 - 8 tau^3)), tau = t / T: the largest |acc| is
    # 6 v0 (r - 1) / T, at the end (0.375 m/s^2 here).
    acc = np.abs(np.diff(speed[CURRENT_STEP:]) / DT_S)
    assert acc.max() == pytest.approx(6 * 27.0 * (r - 1.0) / (c.n_future * DT_S), rel=0.05)


def test_stops_are_kept_and_a_shrunken_curve_never_reverses(lane_change: Scenario) -> None:
    """A log that drives 216 m in 4 s and then stands. On a curve half as long the warp is monotone: it drives
    to the end of the curve and stands where the log stands. On a curve at 20 % the warp would go back: the
    adversary is held (speed 0) instead, and never passes the end of the curve."""
    c = GooseCurve.from_scenario(lane_change, "log")
    k = np.arange(c.n_future + 1)
    v_log = np.where(k <= 40, c.log_length_m / 4.0, 0.0)
    s_log = np.minimum(k, 40) * DT_S * c.log_length_m / 4.0
    for scale in (0.5, 0.2):
        shrunk = replace(c, s_log=s_log, v_log=v_log, ctrl=c.fitted.ctrl * scale)
        assert shrunk.length_ratio() == pytest.approx(scale, abs=1e-3)
        track = shrunk.track()
        local = shrunk.frame.to_local(track[CURRENT_STEP:, [X, Y]])
        speed = np.hypot(track[CURRENT_STEP:, VX], track[CURRENT_STEP:, VY])
        assert np.all(np.diff(local[:, 0]) >= -1e-9)
        assert local[:, 0].max() <= scale * c.log_length_m + 1e-6
        standing = np.flatnonzero(np.diff(local[:, 0]) < 1e-9) + 1
        assert np.all(speed[standing] == 0.0)
        if scale == 0.5:
            np.testing.assert_array_equal(standing, np.arange(41, c.n_future + 1))  # exactly where the log stands
            assert local[40, 0] == pytest.approx(scale * c.log_length_m, abs=0.05)


def test_short_log_is_replayed_only_while_logged(curve: Scenario) -> None:
    c = GooseCurve.from_scenario(curve)
    track = c.track()
    valid_log = curve.track(curve.adv_id)[:, VALID] > 0.5
    np.testing.assert_array_equal(track[:, VALID] > 0.5, valid_log)
    feats = c.features(SPEC)
    assert feats.shape == (N_CURVE_FEATURES,) and feats.dtype == np.float32
    np.testing.assert_allclose(feats[8:20], 0.0)  # no offsets, log weights 0 before any edit


def test_an_adversary_with_no_logged_future_stays_absent(lane_change: Scenario) -> None:
    tracks = lane_change.tracks.copy()
    tracks[lane_change.adv_index, CURRENT_STEP + 1 :] = 0.0
    gone = replace(lane_change, tracks=tracks)
    c = GooseCurve.from_scenario(gone)
    assert c.n_future == 0 and c.log_length_m == 0.0
    for curve in (c, c.edited(np.ones(12), SPEC)):
        track = curve.track()
        assert not np.any(track[CURRENT_STEP + 1 :, VALID])
        np.testing.assert_array_equal(track[: CURRENT_STEP + 1], tracks[lane_change.adv_index, : CURRENT_STEP + 1])
        assert np.all(np.isfinite(curve.features(SPEC)))


@pytest.mark.parametrize("timing", ["log", "curve"])
def test_curve_leaves_the_current_pose_along_the_logged_heading(highway: list[Scenario], timing: str) -> None:
    """The replay's first step turns no faster than the goal's yaw-rate bound allows, for the fitted curve and for
    any edit: point 1 stays on the heading ray (a sideways push of it is ignored)."""
    rng = np.random.default_rng(0)
    for scenario in highway:
        c = GooseCurve.from_scenario(scenario, timing)
        assert c.fitted.ctrl[1, 1] == 0.0 and c.fitted.ctrl[1, 0] > 0
        h0 = scenario.track(scenario.adv_id)[CURRENT_STEP, HEADING]
        for a in [np.zeros(12), *rng.uniform(-1, 1, (5, 12))]:
            e = c.edited(a, SPEC)
            assert e.ctrl[1, 1] == 0.0
            side = a.copy()
            side[1] = -a[1]
            np.testing.assert_array_equal(c.edited(side, SPEC).track(), e.track())
            step = math.remainder(e.track()[CURRENT_STEP + 1, HEADING] - h0, 2 * math.pi)
            assert abs(step) / DT_S < SPEC.desired_goal[2]
