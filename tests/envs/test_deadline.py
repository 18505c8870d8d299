"""The time-aware ego's deadline slots: hand-computed values, the wrapper's termination, and evaluation episodes
that give a trained time-aware ego the same slots."""

from __future__ import annotations

import numpy as np
import pytest

from seal.core.outcome import Outcome
from seal.core.scenario import CURRENT_STEP, DT_S, Scenario
from seal.envs.deadline import (
    DEADLINE_OBS_DIM,
    DeadlineObservation,
    deadline_features,
    deadline_observation_space,
    needs_deadline,
)
from seal.envs.kinematics import MAX_SPEED_MPS, recover_actions
from seal.envs.observation import OBS_DIM, observation_space
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.episodes import run_episode

BRAKE = np.array([0.0, -1.0])


def test_features_by_hand(lane_change: Scenario) -> None:
    env = ScenarioEnv([lane_change])
    env.reset()
    route, horizon = env._route, env.config["horizon_steps"]
    span = route.length - route.start_s
    first = env.deadline_features()
    assert first[0] == 1.0
    assert first[1] == pytest.approx(0.95 * span / (horizon * DT_S) / MAX_SPEED_MPS, rel=1e-6)
    # 30 steps in, halfway along: 60 steps left for the distance to the 95 % point.
    half = deadline_features(route, route.start_s + 0.5 * span, CURRENT_STEP + 30, horizon, 0.95)
    assert half[0] == pytest.approx(60 / horizon)
    assert half[1] == pytest.approx(0.45 * span / (60 * DT_S) / MAX_SPEED_MPS, rel=1e-6)
    # past the success point: nothing required; out of time short of it: the slot saturates.
    assert deadline_features(route, route.length, CURRENT_STEP + 10, horizon, 0.95)[1] == 0.0
    assert list(deadline_features(route, route.start_s, CURRENT_STEP + horizon, horizon, 0.95)) == [0.0, 1.0]


def test_wrapper_appends_slots_and_ends_the_time_limit_as_terminal(stopped_adv: Scenario) -> None:
    env = DeadlineObservation(ScenarioEnv([stopped_adv]))
    assert env.observation_space.shape == (DEADLINE_OBS_DIM,)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (OBS_DIM + 2,) and env.observation_space.contains(obs)
    np.testing.assert_array_equal(obs[OBS_DIM:], env.unwrapped.deadline_features())
    seen = []
    while True:  # the ego brakes to a stop and waits: the time runs out
        obs, _, terminated, truncated, info = env.step(BRAKE)
        seen.append(obs[OBS_DIM:].copy())
        if terminated or truncated:
            break
    assert terminated and not truncated and info["outcome"] == Outcome.TIMEOUT
    assert list(seen[-1]) == [0.0, 1.0]
    assert all(a[0] > b[0] for a, b in zip(seen, seen[1:], strict=False))  # time left falls every step
    still = seen[len(seen) // 2:]  # stopped long since (6 m/s^2 brakes it within a few seconds)
    assert all(b[1] >= a[1] for a, b in zip(still, still[1:], strict=False))  # standing still, the need only grows


class _RecordingEgo:
    """Replays the logged ego's actions and records the observations it is given."""

    def __init__(self, scenario: Scenario, deadline_obs: bool) -> None:
        self.name, self.deadline_obs = "recording", deadline_obs
        self.actions = recover_actions(scenario.track(scenario.ego_id), CURRENT_STEP)
        self.seen: list[np.ndarray] = []

    def reset(self, scenario: Scenario) -> None:
        self.seen.clear()

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        self.seen.append(np.asarray(observation).copy())
        return self.actions[step]


def test_episode_loop_gives_a_time_aware_ego_the_slots(lane_change: Scenario) -> None:
    env = ScenarioEnv([lane_change])
    plain, aware = _RecordingEgo(lane_change, False), _RecordingEgo(lane_change, True)
    first = run_episode(env, lane_change, plain)
    second = run_episode(env, lane_change, aware)
    assert first.outcome == second.outcome == Outcome.SUCCESS and first.last_step == second.last_step
    assert {o.shape for o in plain.seen} == {(OBS_DIM,)} and {o.shape for o in aware.seen} == {(OBS_DIM + 2,)}
    np.testing.assert_array_equal(np.stack(aware.seen)[:, :OBS_DIM], np.stack(plain.seen))
    route = env._route
    start = deadline_features(route, route.start_s, CURRENT_STEP, 90, 0.95)
    np.testing.assert_array_equal(aware.seen[0][OBS_DIM:], start)
    assert aware.seen[-1][OBS_DIM] == pytest.approx(1.0 - (len(aware.seen) - 1) / 90)


def test_needs_deadline_reads_the_observation_size() -> None:
    assert needs_deadline(deadline_observation_space())
    assert not needs_deadline(observation_space())
    assert not needs_deadline(None)


def test_sb3_style_ego_is_time_aware_when_its_model_was() -> None:
    from seal.experiments.training.egos import PolicyEgo

    class Model:
        def __init__(self, space) -> None:  # type: ignore[no-untyped-def]
            self.observation_space = space

        def predict(self, obs, deterministic=True):  # type: ignore[no-untyped-def]
            return np.zeros(2), None

    assert PolicyEgo(Model(deadline_observation_space()), "aware").deadline_obs
    assert not PolicyEgo(Model(observation_space()), "plain").deadline_obs
