"""The skill VAE (ReSkill): an LSTM encoder of a (observation, action) window to a latent skill ``z``, and a
closed-loop decoder ``pi(a | obs, z)`` that produces each step's action from that step's observation and ``z``.

Inputs are standardised inside the model with statistics fitted on the training windows (`SkillVAE.fit_norm`,
stored as buffers, so a loaded model needs no side files). Loss (`SkillVAE.loss`): mean squared action error in
units of each action dimension's training std (steering varies far less than acceleration; raw MSE would
ignore it), summed over the 2 dimensions and averaged over steps, plus ``beta`` times the KL divergence of the
posterior ``N(mu, exp(logvar))`` from ``N(0, I)`` (summed over latent dimensions).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from seal.core.config import check_keys
from seal.envs import observation as ob

_MIN_STD = 1e-3
OWN_ACTION_SLOTS = ((ob.STEERING, 0), (ob.LAST_ACTION.start, 0), (ob.LAST_ACTION.start + 1, 1))
"""(observation slot, action index) pairs that hold the agent's own previous action: the applied steering and the
last action (steering, acceleration) of `seal.envs.observation`."""


@dataclass(frozen=True)
class VAEConfig:
    """Architecture of the skill VAE.

    Attributes:
        obs_dim: observation size (100, `seal.envs.observation.OBS_DIM`).
        action_dim: action size (2: steering, acceleration).
        horizon: window length (steps).
        latent_dim: skill latent size (8).
        encoder_hidden: LSTM hidden size.
        decoder_hidden: hidden layer sizes of the decoder MLP. Its cost is most of the SEAL adversary's per-step
            cost (issue 23): ``(128, 128)`` with prior ``hidden: 64`` takes the skill-adversary env step from 1.44 to
            1.31 replayed steps (`seal bench env --adversary seal`), but on the decisive pool it made SEAL less
            realistic (mean WD 0.186 vs 0.152 at this default; heuristic ego, 150 Normal eval scenarios, K = 5,
            heuristic objective) with fewer ego crashes (46.7 % vs 54.7 %), so the default stays.
        beta: KL weight.
        decoder_ignore: observation slots the decoder does not see. Default none: the decoder sees the previous
            action (slots 32-34 of `seal.envs.observation`: the applied steering and the last action), so consecutive
            actions, and the first action of a new skill, continue from the last one (smooth skills, issue 16).
            ``[32, 33, 34]`` hides it (the decoder cannot lean on copying the previous action; skill boundaries
            then jump).
        closed_loop_training: decode each training window step by step, the decoder seeing its own decoded action
            of the step before in the previous-action slots (`OWN_ACTION_SLOTS`) from the window's second step on,
            as it runs in the env (the first step sees the logged previous action, as a new skill sees the last
            applied one). False (default): every step sees the logged previous action (teacher forcing), which a
            decoder can copy, so the skill latent matters little: from a zero previous action on 500 logged states,
            the std over z ~ N(0, I) of the decoded acceleration is 0.07 m/s^2 on the first step and 0.30 averaged
            over the 10-step skill, against 0.47 / 0.90 with closed-loop training. Measured on the session-60 pool
            (README, "Skills in closed loop"): the adversarial prior's skills start braking behind a braking car
            in one of two such fits (`seal.models.skills.braking_probe`; still too late), the benign prior's in
            neither; against the heuristic ego SEAL gets more realistic (mean WD 0.143 -> 0.135) with slower
            contacts (4.40 -> 4.17 m/s), against a TD3 ego less realistic (0.072 -> 0.109) with faster ones (6.52 ->
            6.97), so the default stays.
    """

    obs_dim: int = 100
    action_dim: int = 2
    horizon: int = 10
    latent_dim: int = 8
    encoder_hidden: int = 128
    decoder_hidden: tuple[int, ...] = (256, 256)
    beta: float = 0.01
    decoder_ignore: tuple[int, ...] = ()
    closed_loop_training: bool = False

    def __post_init__(self) -> None:
        bad = [i for i in self.decoder_ignore if not 0 <= int(i) < self.obs_dim]
        if bad:
            raise ValueError(f"VAE config: decoder_ignore slots {bad} are outside 0..{self.obs_dim - 1}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["decoder_hidden"] = list(self.decoder_hidden)
        d["decoder_ignore"] = list(self.decoder_ignore)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "VAE config") -> VAEConfig:
        check_keys(cls, d, where)
        d = dict(d)
        for key in ("decoder_hidden", "decoder_ignore"):
            if key in d:
                d[key] = tuple(int(h) for h in d[key])
        return cls(**d)


def mlp(sizes: list[int], out_dim: int) -> nn.Sequential:
    """ReLU MLP ``sizes[0] -> sizes[1] -> ... -> out_dim`` (no output activation)."""
    layers: list[nn.Module] = []
    for a, b in zip(sizes[:-1], sizes[1:], strict=True):
        layers += [nn.Linear(a, b), nn.ReLU()]
    layers.append(nn.Linear(sizes[-1], out_dim))
    return nn.Sequential(*layers)


def out_layer(net: nn.Sequential) -> nn.Linear:
    """The output layer of an `mlp` (typed: `nn.Sequential` indexing gives a plain `nn.Module`)."""
    layer = net[-1]
    if not isinstance(layer, nn.Linear):
        raise TypeError(f"expected an MLP ending in nn.Linear, got {type(layer).__name__}")
    return layer


class SkillVAE(nn.Module):
    """Skill VAE (see the module docstring).

    Shapes: observations ``[B, T, obs_dim]``, actions ``[B, T, action_dim]`` (normalised, in [-1, 1]), latents
    ``[B, latent_dim]``.
    """

    # Buffers (`register_buffer`), declared so type checkers see tensors rather than `Module.__getattr__`'s union.
    obs_mean: torch.Tensor
    obs_std: torch.Tensor
    act_std: torch.Tensor
    decoder_keep: torch.Tensor

    def __init__(self, config: VAEConfig | None = None) -> None:
        super().__init__()
        self.config = cfg = config or VAEConfig()
        self.register_buffer("obs_mean", torch.zeros(cfg.obs_dim))
        self.register_buffer("obs_std", torch.ones(cfg.obs_dim))
        self.register_buffer("act_std", torch.ones(cfg.action_dim))
        keep = torch.ones(cfg.obs_dim)
        keep[list(cfg.decoder_ignore)] = 0.0
        self.register_buffer("decoder_keep", keep)
        self.encoder = nn.LSTM(cfg.obs_dim + cfg.action_dim, cfg.encoder_hidden, batch_first=True)
        self.to_posterior = nn.Linear(cfg.encoder_hidden, 2 * cfg.latent_dim)
        self.decoder = mlp([cfg.obs_dim + cfg.latent_dim, *cfg.decoder_hidden], cfg.action_dim)

    def fit_norm(self, obs: np.ndarray, actions: np.ndarray) -> None:
        """Set the standardisation from training rows ``obs [N, obs_dim]`` and ``actions [N, action_dim]``."""
        obs = np.asarray(obs, dtype=np.float64)
        actions = np.asarray(actions, dtype=np.float64)
        self.obs_mean.copy_(torch.as_tensor(obs.mean(0), dtype=torch.float32))
        self.obs_std.copy_(torch.as_tensor(np.maximum(obs.std(0), _MIN_STD), dtype=torch.float32))
        self.act_std.copy_(torch.as_tensor(np.maximum(actions.std(0), _MIN_STD), dtype=torch.float32))

    def normalise_obs(self, obs: torch.Tensor) -> torch.Tensor:
        return (obs - self.obs_mean) / self.obs_std

    def encode(self, obs: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Posterior mean and log-variance ``[B, latent_dim]`` of windows ``obs [B, T, D]``, ``actions [B, T, 2]``."""
        x = torch.cat([self.normalise_obs(obs), actions / self.act_std], dim=-1)
        _, (h, _) = self.encoder(x)
        mu, logvar = self.to_posterior(h[-1]).chunk(2, dim=-1)
        return mu, logvar.clamp(-12.0, 6.0)

    def decode(self, obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Actions ``[..., action_dim]`` in [-1, 1] for observations ``[..., obs_dim]`` and latents ``[..., latent]``
        (``z`` broadcast over the leading dimensions of ``obs`` it lacks, e.g. ``[B, L]`` for ``[B, T, D]``)."""
        while z.dim() < obs.dim():
            z = z.unsqueeze(-2)
        z = z.expand(*obs.shape[:-1], z.shape[-1])
        return torch.tanh(self.decoder(torch.cat([self.normalise_obs(obs) * self.decoder_keep, z], dim=-1)))

    def forward(
        self, obs: torch.Tensor, actions: torch.Tensor, sample: bool = True
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Reconstructed actions ``[B, T, 2]`` (from a posterior sample, or its mean when ``sample`` is False),
        posterior mean and log-variance."""
        mu, logvar = self.encode(obs, actions)
        z = mu + torch.randn_like(mu) * torch.exp(0.5 * logvar) if sample else mu
        decoded = self.decode_closed_loop(obs, z) if self.config.closed_loop_training else self.decode(obs, z)
        return decoded, mu, logvar

    def decode_closed_loop(self, obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        """Actions ``[B, T, action_dim]`` of windows ``obs [B, T, D]`` decoded step by step, each step after the first
        seeing the decoded action of the step before in `OWN_ACTION_SLOTS` (gradients flow through it)."""
        slots, dims = [slot for slot, _ in OWN_ACTION_SLOTS], [dim for _, dim in OWN_ACTION_SLOTS]
        steps = [self.decode(obs[:, 0], z)]
        for t in range(1, obs.shape[1]):
            o = obs[:, t].clone()
            o[:, slots] = steps[-1][:, dims]
            steps.append(self.decode(o, z))
        return torch.stack(steps, dim=1)

    def recon_error(self, recon: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        """Per-window standardised squared error ``[B]``: sum over action dims, mean over steps."""
        return (((recon - actions) / self.act_std) ** 2).sum(-1).mean(-1)

    @staticmethod
    def kl(mu: torch.Tensor, logvar: torch.Tensor) -> torch.Tensor:
        """KL(N(mu, exp(logvar)) || N(0, I)) per window ``[B]`` (nats)."""
        return 0.5 * (mu.pow(2) + logvar.exp() - 1.0 - logvar).sum(-1)

    def loss(self, obs: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, dict[str, float]]:
        """Training loss (recon + beta KL, means over the batch) and its parts."""
        recon, mu, logvar = self(obs, actions)
        rec = self.recon_error(recon, actions).mean()
        kl = self.kl(mu, logvar).mean()
        return rec + self.config.beta * kl, {"recon": rec.item(), "kl": kl.item()}
