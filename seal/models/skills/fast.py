"""Numpy inference for one observation at a time (the skill policy's per-step path).

For a single observation torch's per-operation overhead (~5-10 us) dominates: decoding one action costs ~100 us
and sampling a skill ~800 us in torch, against ~10 us and ~60 us here. The arrays are copied from the torch
modules (float32, same operations), so results agree with `SkillVAE.decode` / `ConditionalRealNVP.sample` to
float rounding; a change of the torch weights needs a new snapshot.
"""

from __future__ import annotations

import numpy as np
from torch import nn

from seal.models.skills.realnvp import ConditionalRealNVP
from seal.models.skills.vae import SkillVAE

Layers = list[tuple[np.ndarray, np.ndarray]]


def _layers(seq: nn.Sequential) -> Layers:
    """(weight ``[out, in]``, bias ``[out]``) of every Linear of a ReLU MLP built by `seal.models.skills.vae.mlp`."""
    return [
        (m.weight.detach().cpu().numpy().astype(np.float32).copy(), m.bias.detach().cpu().numpy().astype(np.float32))
        for m in seq if isinstance(m, nn.Linear)
    ]


def _run(x: np.ndarray, layers: Layers) -> np.ndarray:
    """ReLU MLP forward (no output activation); bias and ReLU in place (same float32 operations, fewer
    temporaries: a step's cost here is call overhead)."""
    last = len(layers) - 1
    for k, (w, b) in enumerate(layers):
        x = w @ x
        x += b
        if k < last:
            np.maximum(x, 0.0, out=x)
    return x


class FastDecoder:
    """`SkillVAE.decode` for one observation: the input standardisation and the ignored slots are folded into the
    first layer, and the latent's contribution to it is computed once per skill (`set_skill`)."""

    def __init__(self, vae: SkillVAE) -> None:
        layers = _layers(vae.decoder)
        d = vae.config.obs_dim
        w1, b1 = layers[0]
        mean = vae.obs_mean.cpu().numpy().astype(np.float32)
        std = vae.obs_std.cpu().numpy().astype(np.float32)
        keep = vae.decoder_keep.cpu().numpy().astype(np.float32)
        self._w_obs = (w1[:, :d] * keep / std).astype(np.float32)
        self._b_obs = (b1 - self._w_obs @ mean).astype(np.float32)
        self._w_z = w1[:, d:].copy()
        self._rest = layers[1:]
        self._b = self._b_obs.copy()

    def set_skill(self, z: np.ndarray) -> None:
        """Latent ``[latent_dim]`` used by the following `decode` calls."""
        self._b = self._b_obs + self._w_z @ np.asarray(z, dtype=np.float32)

    def decode(self, obs: np.ndarray) -> np.ndarray:
        """Action ``[action_dim]`` float32 in [-1, 1] for one observation ``[obs_dim]`` (float32)."""
        h = self._w_obs @ obs
        h += self._b
        np.maximum(h, 0.0, out=h)
        out = _run(h, self._rest)
        return np.tanh(out, out=out)


class FastPriorSampler:
    """`ConditionalRealNVP.sample` for one state."""

    def __init__(self, prior: ConditionalRealNVP) -> None:
        self._embed = _layers(prior.embed_mlp)
        self._cond_mean = prior.cond_mean.cpu().numpy().astype(np.float32)
        self._cond_std = prior.cond_std.cpu().numpy().astype(np.float32)
        self._z_mean = prior.z_mean.cpu().numpy().astype(np.float32)
        self._z_std = prior.z_std.cpu().numpy().astype(np.float32)
        self._couplings = [
            (c.keep.cpu().numpy(), c.change.cpu().numpy(), _layers(c.net), np.float32(c.clamp))
            for c in prior.coupling_layers
        ]

    def sample(self, noise: np.ndarray, cond: np.ndarray) -> np.ndarray:
        """Latent ``[latent_dim]`` float32 for noise ``[latent_dim]`` and state ``[cond_dim]``."""
        e = _run((np.asarray(cond, dtype=np.float32) - self._cond_mean) / self._cond_std, self._embed)
        np.maximum(e, 0.0, out=e)
        x = np.asarray(noise, dtype=np.float32).copy()
        for keep, change, layers, clamp in reversed(self._couplings):
            out = _run(np.concatenate([x[keep], e]), layers)
            n = change.size
            a = clamp * np.tanh(out[:n] / clamp)
            x[change] = (x[change] - out[n:]) * np.exp(-a)
        return x * self._z_std + self._z_mean
