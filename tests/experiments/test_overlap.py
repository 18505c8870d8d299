"""Overlapped gradient updates: a deferred ``train()`` runs while the workers step (between sending the actions and
collecting the results), the number and size of gradient steps is unchanged, and a flush runs what is pending."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import stable_baselines3 as sb3
from stable_baselines3.common.vec_env import DummyVecEnv

from seal.experiments.training.overlap import OverlapVecEnv, find_overlap_env, overlapped


class _Line(gym.Env):
    """A 1-d walk: observation = position, reward = -|position|; 20 steps an episode."""

    observation_space = gym.spaces.Box(-100.0, 100.0, (1,), np.float32)
    action_space = gym.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, log: list[str]) -> None:
        self.log, self.x, self.t = log, 0.0, 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict]:
        super().reset(seed=seed)
        self.x, self.t = 0.0, 0
        return np.array([self.x], np.float32), {}

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self.log.append("env")
        self.x += float(np.asarray(action).reshape(-1)[0])
        self.t += 1
        return np.array([self.x], np.float32), -abs(self.x), False, self.t >= 20, {}


class _RecordingVec(DummyVecEnv):
    """DummyVecEnv steps in step_wait; log when the actions are sent."""

    def __init__(self, log: list[str]) -> None:
        super().__init__([lambda: _Line(log)])
        self.log = log

    def step_async(self, actions: np.ndarray) -> None:
        self.log.append("sent")
        super().step_async(actions)


def test_jobs_run_after_the_actions_are_sent_and_before_the_results() -> None:
    log: list[str] = []
    venv = OverlapVecEnv(_RecordingVec(log))
    venv.reset()
    venv.defer(lambda: log.append("job"))
    venv.step(np.zeros((1, 1), np.float32))
    assert log == ["sent", "job", "env"]
    venv.defer(lambda: log.append("late"))
    venv.flush()
    assert log[-1] == "late" and venv.jobs == [] and venv.jobs_run == 2
    assert find_overlap_env(venv) is venv and find_overlap_env(_RecordingVec([])) is None


def _learn(overlap: bool) -> tuple[Any, list[str]]:
    log: list[str] = []
    base = _RecordingVec(log)
    env = OverlapVecEnv(base) if overlap else base
    model = overlapped(sb3.TD3)("MlpPolicy", env, learning_starts=40, batch_size=8, train_freq=1, gradient_steps=2,
                                policy_kwargs={"net_arch": [8]}, seed=0, device="cpu")
    calls: list[int] = []
    original = sb3.TD3.train

    def counting(self: Any, gradient_steps: int, batch_size: int = 100) -> None:
        calls.append(gradient_steps)
        log.append("train")
        original(self, gradient_steps, batch_size)

    sb3.TD3.train = counting  # type: ignore[method-assign]
    try:
        model.learn(100)
    finally:
        sb3.TD3.train = original  # type: ignore[method-assign]
    if overlap:
        env.flush()
    return model, log


def test_overlapped_td3_makes_the_same_updates_while_the_env_steps() -> None:
    plain, plain_log = _learn(overlap=False)
    over, over_log = _learn(overlap=True)
    # Same update-to-data ratio: 2 gradient steps per env step after learning_starts, in both loops.
    assert plain._n_updates == over._n_updates == 2 * (100 - 40)
    # Plain SB3: the learner trains after the env step; overlapped: between sending the actions and stepping.
    first = plain_log.index("train")
    assert plain_log[first - 1] == "env"
    first = over_log.index("train")
    assert over_log[first - 1] == "sent" and over_log[first + 1] == "env"
