"""`SkillPolicy`: the hierarchical skill policy of ReSkill / SEAL (thesis 6.3.2).

Every ``horizon`` steps (10 = 1 s) it draws Gaussian noise from its own seeded rng, maps it through the
state-conditioned prior given the current observation to a skill latent ``z``, and on every step decodes the
action closed-loop from the current observation and ``z``. Inference runs on numpy snapshots of the models
(`seal.models.skills.fast`): one step costs tens of microseconds, not the ~1 ms torch needs for single inputs.
"""

from __future__ import annotations

import copy
import os
from typing import Any

import numpy as np

from seal.models.skills.fast import FastDecoder, FastPriorSampler
from seal.models.skills.realnvp import ConditionalRealNVP
from seal.models.skills.vae import SkillVAE


class SkillPolicy:
    """Sample a skill every ``horizon`` steps, decode actions every step (see the module docstring).

    Args:
        vae: the skill VAE (its decoder is used).
        prior: the state-conditioned prior to sample skills from (adversarial for the SEAL adversary).
        horizon: steps per skill (default: the VAE's window length).
        seed: seed of the noise rng (`reset` can reseed).
        noise_scale: standard deviation of the noise fed to the prior (1 = the prior itself; < 1 favours its
            most likely skills).
    """

    def __init__(
        self, vae: SkillVAE, prior: ConditionalRealNVP, horizon: int | None = None, seed: int | None = 0,
        noise_scale: float = 1.0,
    ) -> None:
        if prior.config.latent_dim != vae.config.latent_dim or prior.config.cond_dim != vae.config.obs_dim:
            raise ValueError(
                f"SkillPolicy: prior (latent {prior.config.latent_dim}, state {prior.config.cond_dim}) does not fit "
                f"the VAE (latent {vae.config.latent_dim}, observation {vae.config.obs_dim})"
            )
        self.horizon = int(horizon or vae.config.horizon)
        if self.horizon < 1:
            raise ValueError(f"SkillPolicy: horizon must be >= 1, got {self.horizon}")
        self.latent_dim = vae.config.latent_dim
        self.obs_dim = vae.config.obs_dim
        self.noise_scale = float(noise_scale)
        self._decoder = FastDecoder(vae)
        self._sampler = FastPriorSampler(prior)
        self.z: np.ndarray | None = None
        """The current skill latent ``[latent_dim]`` (None before the first step)."""
        self.steps = 0
        """Steps taken since the last `reset`."""
        self.reset(seed)

    @classmethod
    def load(cls, folder: str | os.PathLike[str], prior: str = "adversarial", **kwargs: Any) -> SkillPolicy:
        """Policy from a skills folder written by ``seal fit skills`` (``prior``: ``adversarial`` or ``benign``)."""
        from seal.models.skills.io import load_skill_models

        models = load_skill_models(folder, priors=(prior,))
        return cls(models.vae, models.priors[prior], **kwargs)

    def clone(self) -> SkillPolicy:
        """A policy with its own episode state (noise rng, current skill) sharing this one's model weights: one per
        behaviour, so behaviours alive at the same time (several envs in one process) do not share a skill."""
        other = copy.copy(self)
        other._decoder = copy.copy(self._decoder)  # set_skill rebinds its skill bias, the weights stay shared
        other.rng = copy.deepcopy(self.rng)
        other.reset()
        return other

    def reset(self, seed: int | None = None) -> None:
        """Start a new episode: the next step samples a new skill; ``seed`` reseeds the noise rng if given."""
        if seed is not None or not hasattr(self, "rng"):
            self.rng = np.random.default_rng(seed)
        self.steps = 0
        self.z = None

    def act(self, observation: np.ndarray) -> np.ndarray:
        """Normalised action ``[steering, acceleration]`` ``[2]`` float32 for one observation ``[obs_dim]``."""
        # No copy for the env's float32 rows; the compiled decoder needs a contiguous vector.
        obs = np.ascontiguousarray(observation, dtype=np.float32).reshape(-1)
        if obs.shape[0] != self.obs_dim:
            raise ValueError(f"SkillPolicy.act: observation must have {self.obs_dim} entries, got {obs.shape[0]}")
        if self.steps % self.horizon == 0:
            noise = self.rng.standard_normal(self.latent_dim) * self.noise_scale
            self.z = self._sampler.sample(noise, obs)
            self._decoder.set_skill(self.z)
        self.steps += 1
        return self._decoder.decode(obs)

    def predict(
        self, observation: np.ndarray, state: Any = None, episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict`` for one observation; ``episode_start`` True restarts the skill schedule."""
        if episode_start is not None and bool(np.asarray(episode_start).reshape(-1)[0]):
            self.reset()
        return self.act(observation), state
