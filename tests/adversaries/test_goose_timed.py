"""GOOSE's timed curves (``timing="curve"``): the NURBS is a trajectory whose parameter is time, so an edit changes
where and when the adversary is; the control-point target features; old agent files keep their semantics."""

from __future__ import annotations

import io
import json
import math
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf

from seal.adversaries.goose.agent import build_policy, load_goose_agent, save_goose_agent
from seal.adversaries.goose.curve import HOLD_SPEED_MPS, GooseCurve
from seal.adversaries.goose.goals import adversary_kinematics
from seal.adversaries.goose.nurbs import fit_timed_nurbs, greville_abscissae
from seal.adversaries.goose.obs import N_TARGET_FEATURES, observation_size, target_features
from seal.adversaries.goose.spec import GooseSpec
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, N_STEPS, VALID, VX, VY, Scenario, X, Y
from seal.envs.rollout import Rollout

SPEC = GooseSpec()


def _braking_scenario(decel: float = 2.0, v0: float = 20.0) -> Scenario:
    """The lane-change scenario with an adversary that brakes at ``decel`` m/s^2 from ``v0`` along a straight lane
    from the current step on (and never stops within the 8 s logged)."""
    road = sf.straight_road(3)
    t_cur = CURRENT_STEP * DT_S
    adv = sf.simulate_track(sf._lane_path(road, 1), 110.0, v0 + decel * t_cur,
                            accel_fn=lambda t: -decel)
    base = sf.lane_change_scenario()
    tracks = base.tracks.copy()
    tracks[base.adv_index] = adv
    return replace(base, tracks=tracks)


def _speed(track: np.ndarray) -> np.ndarray:
    return np.hypot(track[:, VX], track[:, VY])


def test_timed_fit_is_exact_for_a_quadratic_motion() -> None:
    """Positions of a constant deceleration are a quadratic in time, which a cubic B-spline holds exactly; the
    start derivative pins control point 1 at ``xi_1 = 1/6`` of the duration times the start velocity."""
    t = np.linspace(0.0, 8.0, 81)
    path = np.stack([20.0 * t - 1.0 * t**2, 0.5 * t], axis=-1)
    c = fit_timed_nurbs(path, np.array([20.0, 0.5]) * 8.0)
    np.testing.assert_allclose(greville_abscissae(), [0, 1 / 6, 0.5, 5 / 6, 1])
    np.testing.assert_allclose(c.ctrl[1], path[0] + np.array([20.0, 0.5]) * 8.0 / 6.0, atol=1e-9)
    np.testing.assert_allclose(c.points(np.linspace(0.0, 1.0, 81)), path, atol=1e-9)
    with pytest.raises(ValueError, match="path"):
        fit_timed_nurbs(np.zeros((1, 2)), np.zeros(2))


def test_zero_edit_replays_a_braking_log_with_its_speed() -> None:
    """The logged adversary brakes at 2 m/s^2: the timed fit replays its positions and speeds (the log-timed
    curve would too); the replay's speed is continuous into the episode."""
    s = _braking_scenario()
    log = s.track(s.adv_id).astype(np.float64)
    c = GooseCurve.from_scenario(s, "curve")
    assert c.timing == "curve" and c.fit_error_m < 0.1
    track = c.track()
    np.testing.assert_allclose(track[:, [X, Y]], log[:, [X, Y]], atol=0.1)
    np.testing.assert_allclose(_speed(track)[CURRENT_STEP:], _speed(log)[CURRENT_STEP:], atol=0.05)
    acc, yaw = adversary_kinematics(track, N_STEPS - 1)
    np.testing.assert_allclose(acc, -2.0, atol=0.1)
    assert np.abs(yaw).max() < 0.01


def test_moving_a_control_point_back_slows_the_adversary_and_keeps_the_clock() -> None:
    """On a timed curve with unit weights the clock is the identity, so future step ``k`` of ``K`` is the curve
    point at ``u = k / K``: pulling point 3 back 4 m (a[4] = -1) makes the adversary brake, then catch up to end
    where the log ends. With the logged profile instead, the same edit only shortens the path."""
    s = sf.lane_change_scenario()
    c = GooseCurve.from_scenario(s, "curve")
    a = np.zeros(12)
    a[4] = -1.0
    e = c.edited(a, SPEC)
    np.testing.assert_allclose(e.ctrl[3] - c.ctrl[3], [-SPEC.shift_m, 0.0])
    u = np.linspace(0.0, 1.0, 512)
    np.testing.assert_allclose(e.clock(u)[0], u, atol=1e-12)
    track = e.track()
    k = np.arange(1, c.n_future + 1)
    np.testing.assert_allclose(e.frame.to_local(track[CURRENT_STEP + 1 :, [X, Y]]), e.curve.points(k / c.n_future),
                               atol=1e-6)
    v_zero, v_edit = _speed(c.track())[CURRENT_STEP:], _speed(track)[CURRENT_STEP:]
    assert v_edit[0] == pytest.approx(v_zero[0], abs=1e-9)  # the current velocity is kept (point 1 is fixed)
    diff = v_edit - v_zero  # slower by up to ~0.86 m/s around 4.5 s, then catches up: faster at the end
    assert np.all(diff[15:55] < -0.1) and diff[45] == pytest.approx(-0.86, abs=0.05)
    assert np.all(diff[-10:] > 1.0)
    # Velocities agree with the positions (central differences along the track).
    pos_speed = np.hypot(*np.diff(track[CURRENT_STEP:, [X, Y]], axis=0).T) / DT_S
    np.testing.assert_allclose(pos_speed, 0.5 * (v_edit[:-1] + v_edit[1:]), atol=0.05)


def test_weights_shift_time_and_the_clock_is_inverted_exactly() -> None:
    """A heavier point 3 pulls position and time towards it: the adversary reaches the point's neighbourhood at
    the point's time and lingers there. Whatever the weights, each future step is at its time on the clock, and
    the reported speeds agree with the positions."""
    s = sf.lane_change_scenario()
    c = GooseCurve.from_scenario(s, "curve")
    rng = np.random.default_rng(3)
    for a in [np.r_[np.zeros(10), 1.0, 0.0], *rng.uniform(-1, 1, (4, 12))]:
        e = c.edited(a, SPEC)
        pts, _, speed = e._timed_motion()
        k = np.arange(1, c.n_future + 1) / c.n_future
        # The step's point lies on the curve at a parameter whose clock reads the step's time.
        grid = np.linspace(0.0, 1.0, 20001)
        t_grid = e.clock(grid)[0]
        u_k = np.interp(k, t_grid, grid)
        np.testing.assert_allclose(pts, e.curve.points(u_k), atol=2e-3)
        track = e.track()
        pos_speed = np.hypot(*np.diff(track[CURRENT_STEP:, [X, Y]], axis=0).T) / DT_S
        v = _speed(track)[CURRENT_STEP:]
        np.testing.assert_allclose(pos_speed, 0.5 * (v[:-1] + v[1:]), atol=0.1)
    # On uniform motion the control points sit at their Greville places in space and time, so x = v t whatever the
    # weights: a weight re-times only what deviates from uniform motion.
    heavy = c.edited(np.r_[np.zeros(10), 1.0, 0.0], SPEC)
    assert heavy.weights[3] == pytest.approx(SPEC.weight_factor)
    np.testing.assert_allclose(heavy.track(), c.track(), atol=1e-6)
    # Point 3 pulled 4 m back: the heavier it is, the closer the adversary comes to it around its time.
    back = np.zeros(12)
    back[4] = -1.0
    step = CURRENT_STEP + int(round(greville_abscissae()[3] * c.n_future))
    dist = []
    for w in (-1.0, 0.0, 1.0):
        e = c.edited(np.r_[back[:10], w, 0.0], SPEC)
        dist.append(float(np.hypot(*(e.frame.to_local(e.track()[step, [X, Y]]) - e.ctrl[3]))))
    assert dist[0] > dist[1] > dist[2]


def test_a_stopping_log_never_reverses_and_a_standing_one_holds_its_heading() -> None:
    """A log that brakes to a stop at 4 s and stands: the replay never turns back (a least-squares fit overshoots
    the stop and comes back; the fit falls back to the log-ordered control polygon). A log standing still all
    along stays put, with the current heading and no yaw."""
    s = sf.lane_change_scenario()
    log = s.track(s.adv_id).astype(np.float64).copy()
    v0, stop = 27.0, 4.0
    t = np.arange(N_STEPS - CURRENT_STEP) * DT_S
    dist = np.where(t < stop, v0 * t - 0.5 * v0 / stop * t**2, 0.5 * v0 * stop)
    speed = np.where(t < stop, v0 - v0 / stop * t, 0.0)
    log[CURRENT_STEP:, X] = log[CURRENT_STEP, X] + dist
    log[CURRENT_STEP:, VX] = speed
    tracks = s.tracks.copy()
    tracks[s.adv_index] = log
    c = GooseCurve.from_scenario(replace(s, tracks=tracks), "curve")
    assert not c.reverses()
    local = c.frame.to_local(c.track()[CURRENT_STEP:, [X, Y]])
    assert np.all(np.diff(local[:, 0]) > -1e-6)
    _, yaw = adversary_kinematics(c.track(), N_STEPS - 1)
    assert np.abs(yaw).max() < SPEC.desired_goal[2]
    log[CURRENT_STEP:, X] = log[CURRENT_STEP, X]
    log[CURRENT_STEP:, VX] = 0.0
    tracks[s.adv_index] = log
    still = GooseCurve.from_scenario(replace(s, tracks=tracks), "curve")
    track = still.track()
    np.testing.assert_allclose(track[CURRENT_STEP:, [X, Y]], log[CURRENT_STEP:, [X, Y]], atol=1e-9)
    np.testing.assert_allclose(track[CURRENT_STEP:, HEADING], log[CURRENT_STEP, HEADING], atol=1e-12)
    assert np.all(_speed(track)[CURRENT_STEP + 1 :] < HOLD_SPEED_MPS)
    assert np.all(track[CURRENT_STEP + 1 :, VALID] == 1.0)


def test_target_features_point_from_each_control_point_to_the_ego_at_its_time() -> None:
    """Ego at (100 + k, 7) m in the world at step k; adversary frame at the origin heading +y (so local = (y, -x)).
    Control point i stands for future step round(xi_i K); the feature is (ego local - point) / 50 and a present
    flag; a step after the roll-out ended takes the last executed step."""
    s = sf.lane_change_scenario()
    c = GooseCurve.from_scenario(s, "curve")
    frame = replace(c.frame, x0=0.0, y0=0.0, h0=math.pi / 2)
    c = replace(c, frame=frame)
    tracks = np.zeros((2, N_STEPS, 8), dtype=np.float32)
    k = np.arange(N_STEPS)
    tracks[0, :, X], tracks[0, :, Y], tracks[0, :, VALID] = 100.0 + k, 7.0, 1.0
    last = CURRENT_STEP + 60
    r = Rollout("x", tracks, np.array([0, 1]), ego_id=0, adv_id=1, last_step=last, outcome="success")
    f = target_features(r, c).reshape(4, 3)
    assert f.shape == (4, 3) and N_TARGET_FEATURES == 12
    steps = CURRENT_STEP + np.rint(greville_abscissae()[1:] * c.n_future).astype(int)
    for i, step in enumerate(np.minimum(steps, last)):
        ego_local = np.array([7.0, -(100.0 + step)])
        np.testing.assert_allclose(f[i, :2], (ego_local - c.ctrl[i + 1]) / 50.0, atol=1e-5)
        assert f[i, 2] == 1.0
    assert steps[-1] > last  # point 4 stands for a step after the roll-out ended
    assert observation_size(SPEC) - observation_size(GooseSpec(obs_targets=False)) == N_TARGET_FEATURES


def test_agent_files_without_the_new_spec_keys_keep_the_old_semantics(tmp_path: Path) -> None:
    """A file written before `timing` / `obs_targets` existed (its spec lacks them) loads as logged-profile timing
    without target features, so its network's input size still matches; a new file round-trips its spec."""
    old_spec = GooseSpec(timing="log", obs_targets=False)
    path = tmp_path / "old.zip"
    save_goose_agent(path, build_policy("sac", old_spec, [16], 8), "sac", old_spec, [16], 8)
    with zipfile.ZipFile(path) as zf:
        meta, weights = json.loads(zf.read("goose.json")), zf.read("policy.pt")
    del meta["spec"]["timing"], meta["spec"]["obs_targets"]
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("goose.json", json.dumps(meta))
        zf.writestr("policy.pt", weights)
    path.write_bytes(buf.getvalue())
    agent = load_goose_agent(path)
    assert agent.spec.timing == "log" and agent.spec.obs_targets is False
    new = tmp_path / "new.zip"
    save_goose_agent(new, build_policy("sac", SPEC, [16], 8), "sac", SPEC, [16], 8)
    assert load_goose_agent(new).spec == SPEC and SPEC.timing == "curve" and SPEC.obs_targets
    with pytest.raises(ValueError, match="timing"):
        GooseSpec(timing="arc")


@pytest.mark.parametrize("timing", ["curve", "log"])
def test_env_and_generator_replay_the_curve_of_their_spec_timing(timing: str) -> None:
    """The env fits its scenarios with the spec's timing, and the generator with its agent's: the first update's
    track is the curve of that timing edited by the agent's action (a braking log, where the timings differ)."""
    import torch

    from seal.adversaries.goose.agent import GooseAgent
    from seal.adversaries.goose.env import GooseEnv, simulate
    from seal.adversaries.goose.generator import GooseGenerator
    from seal.envs.behaviors import ReplayBehavior
    from seal.envs.heuristic import HeuristicDriver
    from seal.envs.scenario_env import ScenarioEnv

    s = _braking_scenario(decel=1.0)
    spec = GooseSpec(timing=timing)
    env = GooseEnv([s], spec)
    assert env.start(s.scenario_id).curve.timing == timing
    torch.manual_seed(0)
    agent = GooseAgent(build_policy("sac", spec, [16], 8), spec, "sac")
    history = [simulate(ScenarioEnv([s]), HeuristicDriver(), s.scenario_id, ReplayBehavior())]
    g = GooseGenerator(agent).generate(s, history, np.random.default_rng(0))
    expected = GooseCurve.from_scenario(s, timing).edited(np.asarray(g.extra["action"]), spec).track()
    np.testing.assert_allclose(g.behavior._given, expected, atol=1e-3)  # the action is logged rounded to 1e-4
    other = GooseCurve.from_scenario(s, "log" if timing == "curve" else "curve")
    assert np.abs(other.edited(np.asarray(g.extra["action"]), spec).track() - expected).max() > 0.1
