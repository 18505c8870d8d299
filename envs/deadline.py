"""The episode's deadline as an ego can see it: a time-aware observation for egos that learn (``deadline_obs``).

An episode is a success only if the ego covers ``success_completion`` (95 %) of its route within ``horizon_steps``
(9 s); a timeout is a failure in every table. The 100-slot observation (`seal.envs.observation`) says neither how
much time is left nor how far the success point is, and SB3's off-policy learners bootstrap through truncation
(``handle_timeout_termination``). To such a learner the deadline does not exist: waiting costs it only the
discount, while driving past an adversary risks crash and out-of-road penalties, so stopping and waiting is a
sound policy of the MDP it learns, and a poor one of the task it is scored on (the "timid" seeds of the decisive
comparison time out on 9-20 % of Normal scenarios). Pardo et al., "Time Limits in Reinforcement Learning" (ICML
2018): when the time limit is part of the task, put the remaining time in the observation and treat the limit
as a terminal state.

`DeadlineObservation` does both for a training env: it appends `DEADLINE_SLOTS` slots to the observation and turns
truncation into termination. An ego trained with it (observation of ``OBS_DIM + DEADLINE_SLOTS`` slots) gets the
same slots in evaluation (`with_deadline`, called by `seal.experiments.evaluation.episodes.run_episode`).

====== ============================================================================== ======= ========= ======
index  meaning                                                                        units   scale     bounds
====== ============================================================================== ======= ========= ======
100    time left: (start step + ``horizon_steps`` - step) / ``horizon_steps``           steps   1         [0, 1]
101    required speed: route distance left to the success point / time left            m/s     / 40      [0, 1]
       (1 when no time is left and the point is not reached; 0 once it is passed)
====== ============================================================================== ======= ========= ======
"""

from __future__ import annotations

from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from seal.core.scenario import CURRENT_STEP, DT_S
from seal.envs.kinematics import MAX_SPEED_MPS
from seal.envs.observation import OBS_DIM, OBS_HIGH, OBS_LOW
from seal.envs.route import Route

DEADLINE_SLOTS = 2
"""Slots appended to the observation (module docstring)."""
DEADLINE_OBS_DIM = OBS_DIM + DEADLINE_SLOTS


def deadline_features(route: Route, s_m: float, step: int, horizon_steps: int, success_completion: float
                      ) -> np.ndarray:
    """The `DEADLINE_SLOTS` slots ``[2]`` float32 of an ego at arc length ``s_m`` (m) on ``route`` at scenario step
    ``step`` (10 Hz; the episode starts at `CURRENT_STEP`)."""
    steps_left = max(CURRENT_STEP + int(horizon_steps) - int(step), 0)
    time_left = steps_left / max(int(horizon_steps), 1)
    target_s = route.start_s + float(success_completion) * (route.length - route.start_s)
    distance_m = max(target_s - float(s_m), 0.0)
    if distance_m <= 0.0:
        required = 0.0
    elif steps_left == 0:
        required = 1.0
    else:
        required = min(distance_m / (steps_left * DT_S) / MAX_SPEED_MPS, 1.0)
    return np.array([time_left, required], dtype=np.float32)


def deadline_observation_space() -> spaces.Box:
    """``Box((OBS_DIM + DEADLINE_SLOTS,), float32)``: the observation's bounds, then [0, 1] per deadline slot."""
    low = np.concatenate([OBS_LOW, np.zeros(DEADLINE_SLOTS, dtype=np.float32)])
    high = np.concatenate([OBS_HIGH, np.ones(DEADLINE_SLOTS, dtype=np.float32)])
    return spaces.Box(low, high, dtype=np.float32)


def with_deadline(obs: np.ndarray, env: gym.Env) -> np.ndarray:
    """``obs [OBS_DIM]`` with the deadline slots of ``env``'s current state appended (``env`` a `ScenarioEnv` or a
    wrapper of one)."""
    return _appended(obs, env.get_wrapper_attr("deadline_features")())


def _appended(obs: np.ndarray, features: np.ndarray) -> np.ndarray:
    return np.concatenate([np.asarray(obs, dtype=np.float32).reshape(-1), features])


def needs_deadline(observation_space: Any) -> bool:
    """Whether a policy with ``observation_space`` was trained on the deadline observation (its size says so)."""
    shape = getattr(observation_space, "shape", None)
    return shape is not None and tuple(shape) == (DEADLINE_OBS_DIM,)


class DeadlineObservation(gym.Wrapper):
    """A time-aware training env (module docstring): the deadline slots appended to every observation, and the end of
    the time limit reported as ``terminated`` (a terminal state, not bootstrapped) instead of ``truncated``.
    ``info["outcome"]`` still says ``timeout``."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.observation_space = deadline_observation_space()
        self._features = env.get_wrapper_attr("deadline_features")  # found once, not through the wrappers each step

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        return _appended(obs, self._features()), info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        return _appended(obs, self._features()), reward, bool(terminated or truncated), False, info
