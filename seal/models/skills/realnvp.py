"""State-conditioned RealNVP prior over skill latents (ReSkill's skill prior; SEAL trains one on benign and one on
adversarial windows).

A bijection ``f_s`` between a skill latent ``z`` and Gaussian noise ``u ~ N(0, I)``, conditioned on a state ``s``
(the window's first observation):

    u = f_s(z) = C_K( ... C_1((z - z_mean) / z_std) ...),   log p(z | s) = log N(u; 0, I) + log |det df_s/dz|

Each affine coupling ``C_k`` keeps one half of the dimensions (alternating halves) and maps the other half
``x_b -> x_b * exp(a) + b`` with ``(a, b) = net_k(x_keep, e(s))``; ``a = c tanh(raw / c)`` bounds the log-scale
by ``scale_clamp``. ``e(s)`` is a state embedding (an MLP of the standardised observation) shared by the
couplings. The fixed standardisation (fitted on the training latents) is part of the bijection and of the
log-determinant, so `log_prob` is the exact density of ``z`` itself. Sampling inverts the couplings:
``z = f_s^{-1}(u)``; noise vectors map one-to-one onto latents, so every noise draw is an in-distribution skill.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, cast

import numpy as np
import torch
from torch import nn

from seal.core.config import check_keys
from seal.models.skills.vae import mlp, out_layer

_MIN_STD = 1e-3
_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class RealNVPConfig:
    """Architecture of a conditional RealNVP prior.

    Attributes:
        latent_dim: skill latent size (the VAE's).
        cond_dim: state size (the observation, 100).
        n_couplings: affine coupling layers (4).
        hidden: hidden size of the coupling networks and the state embedding.
        cond_embed: state embedding size.
        scale_clamp: bound of each coupling's log-scale.
    """

    latent_dim: int = 8
    cond_dim: int = 100
    n_couplings: int = 4
    hidden: int = 128
    cond_embed: int = 64
    scale_clamp: float = 3.0

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "RealNVP config") -> RealNVPConfig:
        check_keys(cls, d, where)
        return cls(**d)


class AffineCoupling(nn.Module):
    """One conditional affine coupling: dims ``keep`` pass through and condition the map of dims ``change``."""

    keep: torch.Tensor  # buffers: [len(keep)], [len(change)] dim indices
    change: torch.Tensor
    net: nn.Sequential

    def __init__(self, keep: list[int], change: list[int], cond_embed: int, hidden: int, scale_clamp: float) -> None:
        super().__init__()
        self.register_buffer("keep", torch.tensor(keep, dtype=torch.long))
        self.register_buffer("change", torch.tensor(change, dtype=torch.long))
        self.clamp = float(scale_clamp)
        self.net = mlp([len(keep) + cond_embed, hidden, hidden], 2 * len(change))
        # Identity at initialisation: training starts from the (standardised) Gaussian.
        nn.init.zeros_(out_layer(self.net).weight)
        nn.init.zeros_(out_layer(self.net).bias)

    def _scale_shift(self, x_keep: torch.Tensor, cond: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        raw, shift = self.net(torch.cat([x_keep, cond], dim=-1)).chunk(2, dim=-1)
        return self.clamp * torch.tanh(raw / self.clamp), shift

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Data -> noise direction: ``y [B, L]`` and log-determinant ``[B]``."""
        a, b = self._scale_shift(x[:, self.keep], cond)
        y = x.clone()
        y[:, self.change] = x[:, self.change] * torch.exp(a) + b
        return y, a.sum(-1)

    def inverse(self, y: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """Noise -> data direction (exact inverse of `forward`)."""
        a, b = self._scale_shift(y[:, self.keep], cond)
        x = y.clone()
        x[:, self.change] = (y[:, self.change] - b) * torch.exp(-a)
        return x


class ConditionalRealNVP(nn.Module):
    """State-conditioned RealNVP prior (see the module docstring).

    Shapes: latents ``[B, latent_dim]``, states ``[B, cond_dim]``, noise ``[B, latent_dim]``.
    """

    # Buffers (`register_buffer`): the state and latent standardisation.
    cond_mean: torch.Tensor
    cond_std: torch.Tensor
    z_mean: torch.Tensor
    z_std: torch.Tensor
    embed: nn.Sequential

    def __init__(self, config: RealNVPConfig | None = None) -> None:
        super().__init__()
        self.config = cfg = config or RealNVPConfig()
        if cfg.latent_dim < 2:
            raise ValueError(f"RealNVP needs latent_dim >= 2 to couple, got {cfg.latent_dim}")
        self.register_buffer("cond_mean", torch.zeros(cfg.cond_dim))
        self.register_buffer("cond_std", torch.ones(cfg.cond_dim))
        self.register_buffer("z_mean", torch.zeros(cfg.latent_dim))
        self.register_buffer("z_std", torch.ones(cfg.latent_dim))
        self.embed = nn.Sequential(mlp([cfg.cond_dim, cfg.hidden], cfg.cond_embed), nn.ReLU())
        half = cfg.latent_dim // 2
        first, second = list(range(half)), list(range(half, cfg.latent_dim))
        self.couplings = nn.ModuleList(
            AffineCoupling(*((first, second) if k % 2 == 0 else (second, first)), cfg.cond_embed, cfg.hidden,
                           cfg.scale_clamp)
            for k in range(cfg.n_couplings)
        )

    @property
    def coupling_layers(self) -> list[AffineCoupling]:
        """The couplings in data -> noise order (a typed view of the ``couplings`` module list, which holds only
        `AffineCoupling` by construction)."""
        return cast(list[AffineCoupling], list(self.couplings))

    @property
    def embed_mlp(self) -> nn.Sequential:
        """The state embedding's MLP (``embed`` is this MLP followed by a ReLU)."""
        return cast(nn.Sequential, self.embed[0])

    def fit_norm(self, z: np.ndarray, cond: np.ndarray) -> None:
        """Set the latent and state standardisation from training latents ``[N, L]`` and states ``[N, D]``."""
        z = np.asarray(z, dtype=np.float64)
        cond = np.asarray(cond, dtype=np.float64)
        self.z_mean.copy_(torch.as_tensor(z.mean(0), dtype=torch.float32))
        self.z_std.copy_(torch.as_tensor(np.maximum(z.std(0), _MIN_STD), dtype=torch.float32))
        self.cond_mean.copy_(torch.as_tensor(cond.mean(0), dtype=torch.float32))
        self.cond_std.copy_(torch.as_tensor(np.maximum(cond.std(0), _MIN_STD), dtype=torch.float32))

    def embed_state(self, cond: torch.Tensor) -> torch.Tensor:
        """State embedding ``[B, cond_embed]`` (compute once to sample several latents for the same states)."""
        return self.embed((cond - self.cond_mean) / self.cond_std)

    def to_noise(self, z: torch.Tensor, cond: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``u = f_s(z)`` ``[B, L]`` and ``log |det df_s/dz|`` ``[B]``."""
        e = self.embed_state(cond)
        x = (z - self.z_mean) / self.z_std
        logdet = -torch.log(self.z_std).sum().expand(z.shape[0])
        for c in self.couplings:
            x, ld = c(x, e)
            logdet = logdet + ld
        return x, logdet

    def log_prob(self, z: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """Exact ``log p(z | s)`` ``[B]`` (nats)."""
        u, logdet = self.to_noise(z, cond)
        return -0.5 * (u.pow(2).sum(-1) + self.config.latent_dim * _LOG_2PI) + logdet

    def sample(self, noise: torch.Tensor, cond: torch.Tensor | None = None, embedded: torch.Tensor | None = None
               ) -> torch.Tensor:
        """Latents ``z = f_s^{-1}(noise)`` ``[B, L]`` for states ``cond [B, D]`` (or their `embed_state`)."""
        if embedded is None:
            if cond is None:
                raise ValueError("ConditionalRealNVP.sample needs the states (cond) or their embedding (embedded)")
            embedded = self.embed_state(cond)
        x = noise
        for c in reversed(self.coupling_layers):
            x = c.inverse(x, embedded)
        return x * self.z_std + self.z_mean
