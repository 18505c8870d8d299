"""The prior's network: a transformer over agent and lane tokens with a latent per agent, and a multimodal decoder.

Encoder: each agent's 1.1 s history (a flat MLP over its 11 steps) and each lane chunk become tokens of width
``d_model``; a pre-norm transformer encoder lets every token attend to every other. Its output at an agent's
token is that agent's latent (``[B, n_agents, d_model]``, the target at index 0) — the hook for latent steering
(adding a direction to a latent before decoding, as in papers ``000`` / ``002``).

Decoder: one query per mode, built from the mode's anchor (a control profile, see `PriorNet`) and offset by the
target's latent, cross-attends to all tokens; an MLP gives the mode's controls (acceleration and yaw rate at
``n_knots`` knots, a bounded correction of its anchor), integrated into positions by `seal.models.prior.kinematics`.
Mode logits: a K-way classifier on the target's latent plus a score of each attended query.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import torch
from torch import nn

from seal.core.config import check_keys
from seal.core.scenario import N_FUTURE
from seal.models.prior.features import AGENT_FEATURES, FeatureConfig
from seal.models.prior.kinematics import integrate_controls, knot_matrix


@dataclass(frozen=True)
class PriorConfig:
    """Architecture of the prior (recorded in every saved model).

    Attributes:
        features: what the prior sees (`FeatureConfig`).
        d_model: token and latent width.
        n_heads: attention heads.
        n_layers: transformer encoder layers.
        ff_mult: feed-forward width as a multiple of ``d_model``.
        dropout: dropout in the encoder.
        n_modes: candidate futures per target.
        n_knots: control knots over the horizon (evenly spaced, linear interpolation in between).
        n_future: predicted steps (0.1 s each).
        acc_limit_mps2: |longitudinal acceleration| bound of every candidate (m/s^2).
        yaw_rate_limit_rps: |yaw rate| bound of every candidate (rad/s).
        assignment: which mode a training target trains: ``"anchor"`` (the mode whose anchor, integrated from
            the target's start, is closest by ADE: a stable target for the mode classifier, as in MultiPath) or
            ``"predicted"`` (the mode whose prediction is closest: plain winner-takes-all).
    """

    features: FeatureConfig = field(default_factory=FeatureConfig)
    d_model: int = 64
    n_heads: int = 4
    n_layers: int = 3
    ff_mult: int = 2
    dropout: float = 0.0
    n_modes: int = 32
    n_knots: int = 16
    n_future: int = N_FUTURE
    acc_limit_mps2: float = 7.9
    yaw_rate_limit_rps: float = 0.98
    assignment: str = "anchor"

    def __post_init__(self) -> None:
        if self.assignment not in ("anchor", "predicted"):
            raise ValueError(
                f"prior config: field 'assignment' must be 'anchor' or 'predicted', got {self.assignment!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PriorConfig:
        d = dict(d)
        check_keys(cls, d, "prior config")
        feats = d.pop("features", {})
        if isinstance(feats, dict):
            check_keys(FeatureConfig, feats, "prior config: features")
            feats = FeatureConfig(**feats)
        return cls(features=feats, **d)


def _mlp(n_in: int, n_hidden: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, n_hidden), nn.ReLU(), nn.Linear(n_hidden, n_out))


def _out_layer(mlp: nn.Sequential) -> nn.Linear:
    """The output layer of an `_mlp` (typed: `nn.Sequential` indexing gives a plain `nn.Module`)."""
    layer = mlp[-1]
    if not isinstance(layer, nn.Linear):
        raise TypeError(f"expected an MLP ending in nn.Linear, got {type(layer).__name__}")
    return layer


def default_anchors(cfg: PriorConfig) -> torch.Tensor:
    """``[n_modes, 2, n_knots]`` anchor controls before any data: constant accelerations x constant yaw rates.

    Training replaces them with k-means centres of the training targets' controls (`seal.models.prior.anchors`).
    """
    acc = torch.tensor([0.0, -1.5, 1.0, -4.0]) * cfg.acc_limit_mps2 / 8.0
    yaw = torch.tensor([0.0, -0.05, 0.05, -0.15, 0.15, -0.3, 0.3, -0.5]) * cfg.yaw_rate_limit_rps
    grid = torch.stack(torch.meshgrid(acc, yaw, indexing="ij"), dim=-1).reshape(-1, 2)
    reps = math.ceil(cfg.n_modes / grid.shape[0])
    pairs = grid.repeat(reps, 1)[: cfg.n_modes]
    return pairs[:, :, None].expand(-1, -1, cfg.n_knots).clone()


class PriorNet(nn.Module):
    """See the module docstring. Inputs are the dict of `seal.models.prior.features.featurise`.

    Each mode has an anchor: a control profile (acceleration and yaw rate at the knots). The mode's query is
    built from its anchor, and its output is a correction in ``atanh`` space, so a fresh network predicts its
    anchors and the limits hold for any correction.
    """

    # Buffers (`register_buffer`), declared so type checkers see tensors: anchors [K, 2, knots], knot matrix.
    anchors: torch.Tensor
    knots: torch.Tensor

    def __init__(self, cfg: PriorConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.agent_in = _mlp(AGENT_FEATURES, 2 * d, d)
        self.chunk_in = _mlp(cfg.features.chunk_features, 2 * d, d)
        self.kind = nn.Parameter(torch.zeros(2, d))  # token kind: agent, lane
        layer = nn.TransformerEncoderLayer(
            d, cfg.n_heads, cfg.ff_mult * d, cfg.dropout, batch_first=True, norm_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, cfg.n_layers, enable_nested_tensor=False)
        self.encoder_norm = nn.LayerNorm(d)
        self.register_buffer("anchors", default_anchors(cfg))  # [K, 2, knots] (m/s^2, rad/s); saved with weights
        self.modes = nn.Parameter(0.1 * torch.randn(cfg.n_modes, d))
        self.anchor_in = _mlp(2 * cfg.n_knots, 2 * d, d)
        self.target_to_query = nn.Linear(d, d)
        self.query_norm = nn.LayerNorm(d)
        self.cross = nn.MultiheadAttention(d, cfg.n_heads, batch_first=True)
        self.head_norm = nn.LayerNorm(d)
        self.head = _mlp(d, 2 * d, 2 * cfg.n_knots)
        # Mode logits: a K-way classifier on the target's latent (anchors are fixed mode identities) plus a score
        # of each decoded query; own heads, so the regression gradients do not drown the classifier.
        self.classify = _mlp(d, 2 * d, cfg.n_modes)
        self.score = _mlp(d, d, 1)
        head_out = _out_layer(self.head)
        nn.init.zeros_(head_out.bias)
        with torch.no_grad():
            head_out.weight.mul_(0.1)  # start near the anchors
        self.register_buffer("knots", knot_matrix(cfg.n_knots, cfg.n_future), persistent=False)

    def _limits(self) -> torch.Tensor:
        return torch.tensor([self.cfg.acc_limit_mps2, self.cfg.yaw_rate_limit_rps]).view(1, 2, 1)

    def set_anchors(self, anchors: torch.Tensor) -> None:
        """Replace the anchors (``[n_modes, 2, n_knots]``: acceleration m/s^2, yaw rate rad/s); clipped to 95 %
        of the limits so ``atanh`` stays finite."""
        lim = self._limits()[0]
        if anchors.shape != self.anchors.shape:
            raise ValueError(f"anchors must have shape {tuple(self.anchors.shape)}, got {tuple(anchors.shape)}")
        self.anchors.copy_(torch.maximum(torch.minimum(anchors.float(), 0.95 * lim), -0.95 * lim))

    def encode(self, feats: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        """Scene tokens after the encoder.

        Returns:
            ``tokens`` ``[B, n_agents + n_chunks, d_model]`` (the first ``n_agents`` are the per-agent latents,
            the target first) and ``mask`` ``[B, n_agents + n_chunks]`` (True = present).
        """
        agents = self.agent_in(feats["agents"]) + self.kind[0]
        chunks = self.chunk_in(feats["chunks"]) + self.kind[1]
        tokens = torch.cat([agents, chunks], dim=1)
        mask = torch.cat([feats["agent_mask"], feats["chunk_mask"]], dim=1)
        tokens = self.encoder_norm(self.encoder(tokens, src_key_padding_mask=~mask))
        return tokens, mask

    def integrate(self, controls: torch.Tensor, start: torch.Tensor) -> torch.Tensor:
        """Positions ``[B, K, n_future, 2]`` (m, target frame) from knot controls ``[B, K, 2, n_knots]`` and the
        targets' ``start`` ``[B, 2]`` (speed m/s, direction of travel rad)."""
        per_step = controls @ self.knots.T  # [B, K, 2, T]
        k = controls.shape[1]
        return integrate_controls(
            per_step[:, :, 0], per_step[:, :, 1], start[:, :1].expand(-1, k), start[:, 1:2].expand(-1, k)
        )

    def anchor_trajectories(self, start: torch.Tensor) -> torch.Tensor:
        """``[B, n_modes, n_future, 2]`` the anchors integrated from each target's ``start`` ``[B, 2]``."""
        return self.integrate(self.anchors[None].expand(start.shape[0], -1, -1, -1), start)

    def decode_controls(self, tokens: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Knot controls ``[B, n_modes, 2, n_knots]`` (acceleration m/s^2, yaw rate rad/s) and mode logits
        ``[B, n_modes]`` from the encoder output."""
        n = self.cfg.n_knots
        lim = self._limits()
        anchor_pre = torch.atanh(self.anchors / lim)  # [K, 2, knots]
        mode_emb = self.modes + self.anchor_in(anchor_pre.flatten(1))  # [K, d]
        query = mode_emb[None] + self.target_to_query(tokens[:, :1])  # [B, K, d]
        attended, _ = self.cross(self.query_norm(query), tokens, tokens, key_padding_mask=~mask, need_weights=False)
        h = self.head_norm(query + attended)
        correction = self.head(h).unflatten(-1, (2, n))  # [B, K, 2, knots]
        controls = lim * torch.tanh(anchor_pre + correction)
        logits = self.classify(tokens[:, 0]) + self.score(h)[..., 0]
        return controls, logits

    @staticmethod
    def select_modes(controls: torch.Tensor, modes: torch.Tensor) -> torch.Tensor:
        """``controls`` ``[B, K, 2, n_knots]`` of the modes ``[B, M]`` -> ``[B, M, 2, n_knots]``."""
        return torch.gather(controls, 1, modes[:, :, None, None].expand(-1, -1, *controls.shape[2:]))

    def decode(
        self, tokens: torch.Tensor, mask: torch.Tensor, start: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Candidate positions ``[B, n_modes, n_future, 2]`` (m, target frame) and mode logits ``[B, n_modes]``.

        ``start`` ``[B, 2]`` is the target's speed (m/s) and direction of travel (rad, target frame).
        """
        controls, logits = self.decode_controls(tokens, mask)
        return self.integrate(controls, start), logits

    def forward(self, feats: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        tokens, mask = self.encode(feats)
        return self.decode(tokens, mask, feats["start"])
