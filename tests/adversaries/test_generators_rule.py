"""Rule-based generator: Bezier geometry, the timing that meets the logged ego, and the crash it causes."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf

from seal.adversaries.base import make_generator
from seal.adversaries.history import RolloutHistory
from seal.adversaries.rule import bezier_curvature, bezier_points
from seal.core.scenario import CURRENT_STEP, DT_S, VX, VY, X, Y
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.episodes import run_episode
from seal.experiments.training.egos import ReplayEgo


def test_bezier_geometry() -> None:
    u = np.linspace(0, 1, 201)
    line = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    np.testing.assert_allclose(bezier_points(line, u)[:, 0], 3 * u, atol=1e-12)
    np.testing.assert_allclose(bezier_curvature(line, u), 0.0, atol=1e-12)
    # The standard quarter-circle approximation (k = 0.5523): curvature within 2.2 % of 1 / R, and at the ends
    # exactly 2 (1 - k) / (3 k^2 R) (the end-point formula (n - 1) / n |d1 x d2| / |d1|^3 with d = control steps).
    r, k = 20.0, 0.5523
    arc = np.array([[r, 0.0], [r, k * r], [k * r, r], [0.0, r]])
    pts = bezier_points(arc[None], u)[0]
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), r, rtol=3e-4)
    kappa = bezier_curvature(arc, u)
    np.testing.assert_allclose(kappa, 1 / r, rtol=0.022)
    np.testing.assert_allclose(kappa[[0, -1]], 2 * (1 - k) / (3 * k**2 * r), rtol=1e-9)


def test_rule_meets_the_logged_ego_and_causes_a_crash() -> None:
    scenario = sf.highway_scenario(1)
    gen = make_generator("rule")
    generation = gen.generate(scenario, RolloutHistory().queue(scenario), np.random.default_rng(0))
    target = generation.predicted_step
    assert generation.extra["feasible"] and abs(generation.extra["accel_mps2"]) <= 4.0
    track = generation.behavior._given
    ego = scenario.track(scenario.ego_id)
    adv = scenario.track(scenario.adv_id)
    # History is the log; at the target step the adversary is exactly at the ego's logged position.
    np.testing.assert_array_equal(track[: CURRENT_STEP + 1], adv[: CURRENT_STEP + 1])
    np.testing.assert_allclose(track[target, [X, Y]], ego[target, [X, Y]], atol=1e-6)
    # Constant acceleration along the curve: the speed changes by a * dt per step (central differences).
    speed = np.hypot(track[:, VX], track[:, VY])
    accel = np.diff(speed[CURRENT_STEP + 2 : target - 1]) / DT_S
    np.testing.assert_allclose(accel, generation.extra["accel_mps2"], atol=0.05)
    rollout = run_episode(ScenarioEnv(scenario), scenario, ReplayEgo(), generation.behavior)
    assert rollout.crashed and rollout.ego_crashes[0][1] == scenario.adv_id
    assert rollout.first_crash_step <= target


def test_rule_prefers_the_gentlest_feasible_target() -> None:
    """Adversary 30 m behind the ego in its lane, both at 20 m/s: meeting the ego at tau needs a = 60 / tau^2, so
    the latest target (tau = 8 s, a = 0.9375 m/s^2) is the gentlest; the rear-end contact (5 m long cars) starts
    when 30 - a t^2 / 2 = 5, at t = 7.30 s."""
    road = sf.straight_road(2)
    lane = road.lanes[0].centerline
    ego = sf.simulate_track(lane, 80.0, 20.0)
    adv = sf.simulate_track(lane, 50.0, 20.0)
    scenario = sf.make_scenario(road, [ego, adv], "rear_end")
    generation = make_generator("rule").generate(scenario, (), np.random.default_rng(0))
    assert generation.predicted_step == CURRENT_STEP + 80
    assert generation.extra["accel_mps2"] == pytest.approx(60.0 / 64.0, rel=1e-3)
    assert generation.extra["peak_lat_accel_mps2"] == pytest.approx(0.0, abs=1e-6)
    # With no feasible target the least infeasible one is still the gentlest.
    strict = make_generator("rule", max_accel_mps2=0.5).generate(scenario, (), np.random.default_rng(0))
    assert strict.predicted_step == CURRENT_STEP + 80 and not strict.extra["feasible"]
    rollout = run_episode(ScenarioEnv(scenario), scenario, ReplayEgo(), generation.behavior)
    assert rollout.ego_crashes[0][1] == scenario.adv_id
    assert abs(rollout.first_crash_step - (CURRENT_STEP + 73)) <= 1
