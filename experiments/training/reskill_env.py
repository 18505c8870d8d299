"""`ReSkillEnv`: the closed-loop env as the ReSkill ego's high-level agent sees it (one step = one skill).

A step takes the high-level action ``u [L]`` (prior noise per `noise_bound`), picks the skill
``z = f_s^{-1}(noise_bound * u)`` in the current state and plays it for the skill horizon H (or until the episode
ends): each env step decodes ``a'`` from that step's observation, adds the residual agent's correction (its numpy
actor, copied in by `set_residual` with the current gate, plus Gaussian exploration noise) and steps the wrapped
`ClosedLoopEnv` (`seal.experiments.training.reskill_policy.combine`). The reward is the sum of the H env rewards.

The residual's transitions ``(x, r, reward, x', done)`` of the env steps played (``x`` = `residual_input`) come back
in ``info["residual"]`` as arrays; each transition is completed by the next env step (after a skill's last step:
in the next `step`, once the next skill, part of ``x'``, is known). ``info["env_steps"]`` is the number of env
steps the skill played (the trainer counts env steps, not decisions). Only steps with an open gate produce
residual transitions: with gate 0 the residual does not act, and its transitions would teach its critic that
actions do not matter.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np

from seal.experiments.training.numpy_actor import NumpyMLP
from seal.experiments.training.reskill_policy import combine, residual_input
from seal.experiments.training.skill_prior import EgoSkills, noise_of

RESIDUAL_KEYS = ("obs", "action", "reward", "next_obs", "done", "truncated")


def residual_space(obs_dim: int, latent_dim: int) -> gym.spaces.Box:
    """Observation space of the residual agent: ``[obs, z, a']``."""
    return gym.spaces.Box(-np.inf, np.inf, (obs_dim + latent_dim + 2,), np.float32)


class ReSkillEnv(gym.Wrapper):
    """One skill per step (module docstring).

    Args:
        env: the closed-loop env (its ``get_state`` / ``set_state`` / curriculum methods stay reachable).
        skills: the skill model (`EgoSkills`), cloned for this env.
        noise_bound: prior noise per unit of high-level action.
        residual_bound: largest residual per action dimension at gate 1.
        residual_noise_std: exploration noise on the residual action.
        seed: seed of the residual exploration noise.
    """

    def __init__(self, env: gym.Env, skills: EgoSkills, noise_bound: float, residual_bound: float,
                 residual_noise_std: float, seed: int) -> None:
        super().__init__(env)
        self.skills = skills.clone()
        self.noise_bound, self.residual_bound = float(noise_bound), float(residual_bound)
        self.residual_noise_std = float(residual_noise_std)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (self.skills.latent_dim,), np.float32)
        self.rng = np.random.default_rng(seed)
        self.residual_actor: NumpyMLP | None = None
        self.gate = 0.0
        self._obs: np.ndarray | None = None
        self._pending: tuple[np.ndarray, np.ndarray, float] | None = None

    # ---------------------------------------------------------------------------- trainer-facing methods
    def set_residual(self, actor: NumpyMLP | None, gate: float) -> None:
        """The residual actor's weights (`seal.experiments.training.numpy_actor.actor_mlp`) and gate."""
        self.residual_actor, self.gate = actor, float(gate)

    def get_state(self) -> dict[str, np.ndarray]:
        """The closed-loop env's state plus ``reskill_rng`` (JSON of the residual noise rng)."""
        state = dict(self.env.get_wrapper_attr("get_state")())
        state["reskill_rng"] = np.array(json.dumps(self.rng.bit_generator.state))
        return state

    def set_state(self, state: Mapping[str, np.ndarray], source: str = "reskill state") -> None:
        self.env.get_wrapper_attr("set_state")({k: v for k, v in state.items() if k != "reskill_rng"}, source)
        if "reskill_rng" in state:
            self.rng.bit_generator.state = json.loads(str(np.asarray(state["reskill_rng"])))

    # ------------------------------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        self._obs, self._pending = np.asarray(obs, dtype=np.float32), None
        return obs, info

    def _residual(self, x: np.ndarray) -> np.ndarray:
        assert self.residual_actor is not None
        r = self.residual_actor(x)
        if self.residual_noise_std > 0:
            r = r + self.rng.normal(0.0, self.residual_noise_std, r.shape).astype(np.float32)
        return np.clip(r, -1.0, 1.0).astype(np.float32)

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        if self._obs is None:
            raise RuntimeError("ReSkillEnv.step before reset")
        z = self.skills.skill(noise_of(np.asarray(action).reshape(-1), self.noise_bound), self._obs)
        active = self.residual_actor is not None and self.gate > 0.0
        rows: list[tuple[Any, ...]] = []
        total, steps = 0.0, 0
        terminated = truncated = False
        info: dict[str, Any] = {}
        obs = self._obs
        while steps < self.skills.horizon and not (terminated or truncated):
            base = self.skills.action(obs)
            x = residual_input(obs, z, base) if active else None
            if self._pending is not None and x is not None:
                rows.append((*self._pending, x, False, False))  # the previous step's x' is this step's x
            self._pending = None
            r = self._residual(x) if x is not None else None
            env_action = combine(base, r, self.gate, self.residual_bound) if r is not None else base
            next_obs, reward, terminated, truncated, info = self.env.step(env_action)
            obs = np.asarray(next_obs, dtype=np.float32)
            total += float(reward)
            steps += 1
            if x is not None and r is not None:
                if terminated or truncated:
                    x_next = residual_input(obs, z, self.skills.action(obs))
                    rows.append((x, r, float(reward), x_next, bool(terminated), bool(truncated and not terminated)))
                else:  # completed by the next step (after a skill's last step: the next skill's first)
                    self._pending = (x, r, float(reward))
        self._obs = obs
        info = dict(info)
        info["env_steps"] = steps
        if rows:
            info["residual"] = _stack(rows)
        return obs, total, terminated, truncated, info


def _stack(filled: list[tuple[Any, ...]]) -> dict[str, np.ndarray]:
    """Transitions ``(x, r, reward, x', done, truncated)`` as arrays (``RESIDUAL_KEYS``)."""
    return {
        "obs": np.stack([f[0] for f in filled]).astype(np.float32),
        "action": np.stack([f[1] for f in filled]).astype(np.float32),
        "reward": np.array([f[2] for f in filled], dtype=np.float32),
        "next_obs": np.stack([f[3] for f in filled]).astype(np.float32),
        "done": np.array([f[4] for f in filled], dtype=np.float32),
        "truncated": np.array([f[5] for f in filled], dtype=bool),
    }
