"""The ReSkill ego's view of the skill models: a state-conditioned benign prior to pick skills with and a
closed-loop decoder to turn the current skill into each step's action (thesis 6.4.1, ReSkill).

`EgoSkills` is the whole interface the ego uses, so another skill fit (issue 16: benign skills from clean driving,
a decoder that also sees the previous action) drops in behind it: `BenignSkills` implements it for a skills
folder written by ``seal fit skills`` (the VAE's decoder and the ``benign`` RealNVP prior) on the numpy snapshots
of `seal.models.skills.fast` (tens of microseconds a call, not torch's ~1 ms for one observation).

The high-level action is the noise fed to the prior: a vector ``u`` in ``[-1, 1]^L`` scaled by ``noise_bound``
(`noise_of`) and mapped through the bijection ``z = f_s^{-1}(u)``, so every action decodes to an in-distribution
skill and ``u = 0`` is the skill at the mode of the prior's base Gaussian.
"""

from __future__ import annotations

import os
from typing import Protocol

import numpy as np

from seal.models.skills.fast import FastDecoder, FastPriorSampler


class EgoSkills(Protocol):
    """What the ReSkill ego needs from a skill model."""

    latent_dim: int
    """Skill latent size L (the high-level action's size)."""
    horizon: int
    """Steps per skill H (10 = 1 s)."""
    obs_dim: int
    """Observation size the prior and decoder read (100)."""

    def skill(self, noise: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """Skill latent ``[L]`` float32 for prior noise ``[L]`` in the state ``obs [obs_dim]``; also makes it the
        skill `action` decodes."""
        ...

    def action(self, obs: np.ndarray) -> np.ndarray:
        """Decoded normalised action ``[steering, acceleration]`` ``[2]`` float32 in [-1, 1] of the current skill
        for the observation ``obs [obs_dim]`` (closed loop: called every step with that step's observation)."""
        ...

    def clone(self) -> EgoSkills:
        """A copy with its own current skill (weights shared): one per env or ego alive at the same time."""
        ...


class BenignSkills:
    """`EgoSkills` of a ``seal fit skills`` folder: the VAE decoder and the ``benign`` prior.

    Args:
        folder: the skills folder (``vae.pt``, ``prior_benign.pt``).
        prior: which prior class to draw skills from (``benign``; the ego never uses the adversarial one).
    """

    def __init__(self, folder: str | os.PathLike[str], prior: str = "benign") -> None:
        from seal.models.skills.io import load_skill_models

        models = load_skill_models(folder, priors=(prior,))
        self.latent_dim = int(models.vae.config.latent_dim)
        self.horizon = int(models.vae.config.horizon)
        self.obs_dim = int(models.vae.config.obs_dim)
        self._decoder = FastDecoder(models.vae)
        self._sampler = FastPriorSampler(models.priors[prior])

    @classmethod
    def from_models(cls, decoder: FastDecoder, sampler: FastPriorSampler, latent_dim: int, horizon: int,
                    obs_dim: int) -> BenignSkills:
        """From numpy snapshots already built (tests, or models held in memory)."""
        self = cls.__new__(cls)
        self.latent_dim, self.horizon, self.obs_dim = int(latent_dim), int(horizon), int(obs_dim)
        self._decoder, self._sampler = decoder, sampler
        return self

    def skill(self, noise: np.ndarray, obs: np.ndarray) -> np.ndarray:
        z = self._sampler.sample(np.asarray(noise, dtype=np.float32), np.asarray(obs, dtype=np.float32))
        self._decoder.set_skill(z)
        return z

    def action(self, obs: np.ndarray) -> np.ndarray:
        return self._decoder.decode(np.asarray(obs, dtype=np.float32))

    def clone(self) -> BenignSkills:
        import copy

        other = copy.copy(self)
        other._decoder = copy.copy(self._decoder)  # set_skill rebinds its bias array; the weights stay shared
        return other


def noise_of(action: np.ndarray, noise_bound: float) -> np.ndarray:
    """Prior noise ``[L]`` of a high-level action ``[L]`` in [-1, 1] (clipped first): ``noise_bound * action``."""
    return (noise_bound * np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0)).astype(np.float32)
