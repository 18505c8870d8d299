"""`GooseEnv`: each step is a full roll-out of the heuristic ego against the adversary replaying the edited curve."""

from __future__ import annotations

import numpy as np
import pytest

from seal.adversaries.goose.env import GooseEnv, simulate
from seal.adversaries.goose.goals import achieved_goal, goal_reward
from seal.adversaries.goose.spec import GooseSpec
from seal.core.scenario import CURRENT_STEP, N_STEPS, Scenario, X, Y
from seal.envs.behaviors import ReplayBehavior

EASY_GOAL = (50.0, 100.0, 100.0)
"""Reached by any roll-out (gaps are capped at 50 m)."""


@pytest.fixture(scope="module")
def scenarios(lane_change: Scenario, highway: list[Scenario]) -> list[Scenario]:
    return [lane_change, highway[0]]


def test_reset_observes_the_logged_adversary_and_steps_replay_the_curve(scenarios: list[Scenario]) -> None:
    env = GooseEnv(scenarios, GooseSpec(max_updates=2))
    obs, info = env.reset(seed=0, options={"scenario_id": "lane_change"})
    assert env.observation_space.contains(obs)
    start = env.start("lane_change")
    np.testing.assert_allclose(obs["achieved_goal"], achieved_goal(start.rollout))
    assert start.rollout.adversary == "ReplayBehavior"
    np.testing.assert_allclose(obs["desired_goal"], GooseSpec().desired_goal)
    assert info["scenario_id"] == "lane_change" and not info["solved_at_start"]

    a = np.zeros(12)
    a[3] = -1.0  # control point 2 towards the ego's side
    obs, reward, terminated, truncated, info = env.step(a)
    curve = env.curve
    spec = env.goose_spec
    assert curve is not None
    assert curve.ctrl[2, 1] == pytest.approx(curve.fitted.ctrl[2, 1] - spec.shift_m * spec.point_scale[1])
    # The roll-out's adversary is exactly where the re-timed curve puts it.
    r = env.last_rollout
    track = curve.track()
    last = min(r.last_step, N_STEPS - 1)
    np.testing.assert_allclose(r.adv_track[CURRENT_STEP : last + 1, [X, Y]], track[CURRENT_STEP : last + 1, [X, Y]],
                               atol=1e-3)
    np.testing.assert_allclose(obs["achieved_goal"], achieved_goal(r))
    assert reward == pytest.approx(float(goal_reward(obs["achieved_goal"], obs["desired_goal"])))
    assert info["updates"] == 1 and obs["observation"][-1] == pytest.approx(0.5)
    if not terminated:
        _, _, terminated, truncated, info = env.step(np.zeros(12))
        assert terminated or truncated  # K = 2 updates at most
        assert info["updates"] == 2


def test_same_curve_same_rollout(scenarios: list[Scenario]) -> None:
    """The ego is deterministic, so one curve always gives the same roll-out (and the cache is sound)."""
    env = GooseEnv(scenarios)
    env.reset(options={"scenario_id": "highway-0"})
    obs1, *_ = env.step(np.full(12, 0.3))
    env.reset(options={"scenario_id": "highway-0"})
    obs2, *_ = env.step(np.full(12, 0.3))
    np.testing.assert_array_equal(obs1["observation"], obs2["observation"])
    direct = simulate(env.sim, env.driver, "highway-0", ReplayBehavior())
    np.testing.assert_array_equal(direct.tracks, env.start("highway-0").rollout.tracks)


def test_reaching_the_goal_terminates_and_solved_scenarios_are_skipped(scenarios: list[Scenario]) -> None:
    easy = GooseSpec(desired_goal=EASY_GOAL)
    env = GooseEnv(scenarios, easy, skip_solved=False)
    obs, info = env.reset(options={"scenario_id": "lane_change"})
    assert info["solved_at_start"] and info["is_success"]
    _, reward, terminated, truncated, info = env.step(np.zeros(12))
    assert terminated and not truncated and info["is_success"] and reward == 0.0
    with pytest.raises(RuntimeError, match="no unsolved scenario"):
        GooseEnv(scenarios, easy, skip_solved=True).reset(seed=0)


def test_compute_reward_is_vectorised_for_her(scenarios: list[Scenario]) -> None:
    env = GooseEnv(scenarios)
    achieved = np.array([[2.0, 9.0, 0.7], [0.0, 1.0, 0.1]], dtype=np.float32)
    desired = np.tile(np.array(GooseSpec().desired_goal, dtype=np.float32), (2, 1))
    np.testing.assert_allclose(env.compute_reward(achieved, desired, [{}, {}]), [-0.325, 0.0], atol=1e-6)
    sparse = GooseEnv(scenarios, GooseSpec(reward="sparse"))
    np.testing.assert_array_equal(sparse.compute_reward(achieved, desired, [{}, {}]), [-1.0, 0.0])


def test_passes_the_sb3_env_checker(scenarios: list[Scenario]) -> None:
    from stable_baselines3.common.env_checker import check_env

    check_env(GooseEnv(scenarios[:1], GooseSpec(max_updates=1)), warn=False, skip_render_check=True)
