"""ScenarioEnv API: Gymnasium / SB3 env checkers, registration, SubprocVecEnv, reset options, info, Rollout."""

from __future__ import annotations

import pickle
import warnings

import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from seal.core.scenario import CURRENT_STEP, VALID, Scenario
from seal.envs import ENV_ID
from seal.envs.behaviors import ReplayBehavior
from seal.envs.observation import OBS_DIM
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv

INFO_KEYS = {"is_success", "crashed", "out_of_road", "route_completion", "crash_agent_id", "crashed_with_adversary"}


def test_gymnasium_env_checker(all_scenarios: list[Scenario]) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a checker warning is a failure, not a note in the log
        gym_check_env(ScenarioEnv(all_scenarios), skip_render_check=True)


def test_sb3_env_checker(all_scenarios: list[Scenario]) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sb3_check_env(ScenarioEnv(all_scenarios), warn=True)


def test_registered_with_gymnasium(lane_change: Scenario) -> None:
    env = gymnasium.make(ENV_ID, scenarios=[lane_change])
    obs, info = env.reset(seed=0)
    assert obs.shape == (OBS_DIM,) and obs.dtype == np.float32
    assert env.observation_space.contains(obs)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    assert set(info) >= INFO_KEYS
    env.close()


def _make_env(scenarios: list[Scenario]):
    def make() -> ScenarioEnv:
        return ScenarioEnv(scenarios)

    return make


def test_subproc_vec_env(highway: list[Scenario]) -> None:
    from stable_baselines3.common.vec_env import SubprocVecEnv

    vec = SubprocVecEnv([_make_env(highway), _make_env(highway)])
    try:
        vec.seed(0)
        obs = vec.reset()
        assert obs.shape == (2, OBS_DIM)
        for _ in range(5):
            obs, rewards, dones, infos = vec.step(np.zeros((2, 2), dtype=np.float32))
        assert obs.shape == (2, OBS_DIM) and rewards.shape == (2,)
        assert all(set(i) >= INFO_KEYS for i in infos)
    finally:
        vec.close()


def test_reset_picks_scenarios(all_scenarios: list[Scenario]) -> None:
    env = ScenarioEnv(all_scenarios)
    _, info = env.reset(options={"scenario_id": "curve"})
    assert info["scenario_id"] == "curve" and info["step"] == CURRENT_STEP
    with pytest.raises(KeyError, match="nope"):
        env.reset(options={"scenario_id": "nope"})
    picks = [env.reset(seed=7)[1]["scenario_id"] for _ in range(2)]
    assert picks[0] == picks[1]  # same seed, same scenario
    seen = {env.reset()[1]["scenario_id"] for _ in range(40)}
    assert len(seen) > 1  # without a seed the env's rng moves on


def test_rejects_unknown_config() -> None:
    with pytest.raises(ValueError, match="horizon"):
        ScenarioEnv([], config={"horizon": 3})


def test_reset_adversary_option_is_one_episode(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv])
    parked = stopped_adv.track(stopped_adv.adv_id).copy()
    parked[:, :5] = parked[CURRENT_STEP, :5]
    parked[:, 3:5] = 0.0
    env.reset(options={"adversary": ReplayBehavior(parked)})
    env.step(np.zeros(2))
    assert env._cur[stopped_adv.adv_index, 0] == pytest.approx(parked[CURRENT_STEP, 0])
    env.reset()
    env.step(np.zeros(2))
    assert env._cur[stopped_adv.adv_index, 0] == pytest.approx(stopped_adv.track(stopped_adv.adv_id)[11, 0])


def test_adversary_factory_called_each_reset(lane_change: Scenario) -> None:
    calls: list[str] = []

    def factory(scenario: Scenario, rng: np.random.Generator) -> ReplayBehavior:
        calls.append(scenario.scenario_id)
        return ReplayBehavior()

    env = ScenarioEnv([lane_change], adversary=factory)
    env.reset()
    env.reset()
    assert calls == ["lane_change", "lane_change"]


def test_rollout_on_last_step(lane_change: Scenario) -> None:
    env = ScenarioEnv([lane_change], config={"horizon_steps": 20})
    env.reset()
    steps = 0
    while True:
        obs, reward, terminated, truncated, info = env.step(np.array([0.0, 0.0]))
        steps += 1
        assert set(info) >= INFO_KEYS
        if terminated or truncated:
            break
        assert "rollout" not in info
    assert truncated and not terminated and steps == 20 and info["outcome"] == "timeout"
    ro: Rollout = info["rollout"]
    assert ro.tracks.shape == (lane_change.n_agents, CURRENT_STEP + 1 + 20, 8)
    assert ro.tracks.dtype == np.float32
    assert ro.last_step == CURRENT_STEP + 20 and ro.n_steps == 20
    np.testing.assert_array_equal(ro.tracks[:, : CURRENT_STEP + 1], lane_change.tracks[:, : CURRENT_STEP + 1])
    assert (ro.ego_track[CURRENT_STEP:, VALID] == 1).all()
    assert ro.ego_id == lane_change.ego_id and ro.adv_id == lane_change.adv_id
    back = pickle.loads(pickle.dumps(ro))
    np.testing.assert_array_equal(back.tracks, ro.tracks)
    assert env.rollout is ro
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(2))


def test_rollout_invalid_after_early_end(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv])
    env.reset()
    while True:
        *_, terminated, truncated, info = env.step(np.array([1.0, 1.0]))  # hard left: off the road soon
        if terminated or truncated:
            break
    ro = info["rollout"]
    assert ro.outcome == "out_of_road" and ro.out_of_road_step == ro.last_step
    assert (ro.tracks[:, ro.last_step + 1 :, VALID] == 0).all()


def test_render_rgb_array(lane_change: Scenario) -> None:
    env = ScenarioEnv([lane_change], render_mode="rgb_array")
    env.reset()
    env.step(np.zeros(2))
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    assert frame.std() > 5  # not blank


@pytest.mark.parametrize("bad", [np.array([np.nan, 0.0]), [0.0, np.inf], [0.1, 0.2, 0.3], [0.5], 0.3, None, "go"])
def test_step_refuses_non_finite_or_misshapen_actions(lane_change: Scenario, bad: object) -> None:
    env = ScenarioEnv([lane_change])
    env.reset(seed=0)
    with pytest.raises(ValueError, match="ScenarioEnv.step: action must"):
        env.step(bad)
    obs, *_ = env.step(np.zeros(2))  # the episode goes on after a refused action
    assert obs.shape == (OBS_DIM,)


def test_out_of_range_actions_are_clipped(lane_change: Scenario) -> None:
    """Finite actions beyond [-1, 1] act as the bound (Gymnasium's convention for Box actions)."""
    a, b = ScenarioEnv([lane_change]), ScenarioEnv([lane_change])
    a.reset(seed=0)
    b.reset(seed=0)
    for _ in range(5):
        a.step(np.array([5.0, -7.0]))
        b.step(np.array([1.0, -1.0]))
        assert (a._ego.x, a._ego.y, a._ego.heading, a._ego.speed) == (b._ego.x, b._ego.y, b._ego.heading, b._ego.speed)
