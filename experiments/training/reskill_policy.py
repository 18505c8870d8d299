"""The ReSkill ego's acting rule (thesis 6.4.1, after ReSkill), shared by training (`ReSkillEnv`, in the env
workers) and evaluation (`ReSkillPolicy`, the ego of every protocol).

Every ``H`` steps (the skill horizon) the high-level agent's action ``u in [-1, 1]^L`` picks a skill through the
benign prior, ``z = f_s^{-1}(noise_bound * u)`` (`seal.experiments.training.skill_prior`); every step the decoder
gives the skill's action ``a' = pi(obs, z)`` and the residual agent adds a bounded correction:

    a = clip(a' + g(t) * residual_bound * r(obs, z, a'), -1, 1),    r in [-1, 1]^2 (a tanh actor)

so ``|a - a'| <= g(t) * residual_bound`` in each dimension. ``g(t)`` is ReSkill's gate on the residual
(`residual_gate`): 0 while the high-level agent learns to use the skill space, then a linear ramp to 1. The
residual reads ``[obs, z, a']`` (`residual_input`; 100 + L + 2 values).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from seal.envs.observation import OBS_DIM
from seal.experiments.training.numpy_actor import NumpyMLP, deterministic_actor
from seal.experiments.training.skill_prior import EgoSkills, noise_of


def residual_gate(step: int, start: int, ramp: int) -> float:
    """Weight ``g`` in [0, 1] of the residual after ``step`` env steps: 0 before ``start``, then linear over
    ``ramp`` steps (``ramp`` 0: a switch at ``start``)."""
    if step < start:
        return 0.0
    return 1.0 if ramp <= 0 else float(min(1.0, (step - start) / ramp))


def residual_input(obs: np.ndarray, z: np.ndarray, base_action: np.ndarray) -> np.ndarray:
    """The residual agent's observation ``[obs_dim + L + 2]`` float32."""
    return np.concatenate([np.asarray(obs, dtype=np.float32).reshape(-1), z, base_action]).astype(np.float32)


def combine(base_action: np.ndarray, residual: np.ndarray, gate: float, residual_bound: float) -> np.ndarray:
    """The env action ``clip(a' + gate * residual_bound * clip(r, -1, 1), -1, 1)`` ``[2]`` float32."""
    delta = gate * residual_bound * np.clip(residual, -1.0, 1.0)
    return np.clip(base_action + delta, -1.0, 1.0).astype(np.float32)


class ReSkillPolicy:
    """The trained ReSkill ego as an SB3-style ``predict`` (one observation at a time, deterministic): the
    high-level SB3 model picks a skill every ``horizon`` steps, the residual actor corrects every step.

    Args:
        high: the high-level SB3 model (its ``predict`` gives the prior noise action ``[L]``).
        skills: the skill model (`EgoSkills`; cloned, so this policy has its own current skill).
        residual: the residual actor (`seal.experiments.training.numpy_actor.actor_mlp`), or None for none.
        gate: the residual's weight (`residual_gate` at the step the policy was taken).
        noise_bound: prior noise per unit of high-level action.
        residual_bound: largest residual per action dimension at gate 1.

    ``high_action(obs)`` is the high-level agent's deterministic action: a numpy copy of its TD3 actor
    (`seal.experiments.training.numpy_actor.deterministic_actor`, the weights of when the policy was made, as the
    residual's) or, for another model, its ``predict``.
    """

    def __init__(self, high: Any, skills: EgoSkills, residual: NumpyMLP | None, gate: float, noise_bound: float,
                 residual_bound: float) -> None:
        self.high, self.skills = high, skills.clone()
        self.residual, self.gate = residual, float(gate)
        self.noise_bound, self.residual_bound = float(noise_bound), float(residual_bound)
        self.steps = 0
        self.z = np.zeros(self.skills.latent_dim, dtype=np.float32)
        # ~10x cheaper a call than predict
        fast = deterministic_actor(high)
        self.high_action = fast if fast is not None else lambda obs: high.predict(obs, deterministic=True)[0]

    def reset(self) -> None:
        """A new episode: the next step picks a new skill."""
        self.steps = 0

    def act(self, observation: np.ndarray) -> np.ndarray:
        """Normalised ``[steering, acceleration]`` ``[2]`` float32 for one observation ``[obs_dim]`` (with the
        deadline slots appended for a time-aware ego)."""
        full = np.asarray(observation, dtype=np.float32).reshape(-1)
        # A time-aware ego's high-level agent also reads the deadline slots after the observation
        # (`seal.envs.deadline`); the skills and the residual read the observation only, as in training.
        obs = full[:OBS_DIM]
        if self.steps % self.skills.horizon == 0:
            u = self.high_action(full)
            self.z = self.skills.skill(noise_of(np.asarray(u).reshape(-1), self.noise_bound), obs)
        self.steps += 1
        base = self.skills.action(obs)
        if self.residual is None or self.gate <= 0.0:
            return np.asarray(base, dtype=np.float32).copy()
        r = self.residual(residual_input(obs, self.z, base))
        return combine(base, r, self.gate, self.residual_bound)

    def predict(self, observation: np.ndarray, state: Any = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict``; ``episode_start`` True starts a new skill schedule."""
        if episode_start is not None and bool(np.asarray(episode_start).reshape(-1)[0]):
            self.reset()
        return self.act(observation), state
