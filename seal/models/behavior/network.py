"""The behaviour network (thesis 7.3.1, 7.3.3, 7.3.4): encoder, reconstruction decoder, projection head + LoRA.

* Encoder ``z_i = Enc(X_i, X)``: each agent token (`seal.models.behavior.features`, the target first) goes through an
  MLP to width ``d_model``; a pre-norm transformer encoder (the prior's building block,
  `seal.models.prior.network`) lets the tokens attend to each other; the target's output token is mapped to the
  latent ``z [B, latent_dim]`` (thesis d1 = 256).
* Decoder ``Dec(z)`` (MTR's multimodal head, decoding from ``z`` alone so that ``z`` must carry the behaviour):
  ``n_modes`` learned mode queries added to ``z``, an MLP each gives the full trajectory ``[S, 2]`` (target frame,
  in units of ``pos_scale_m``) and a mode logit.
* Projection ``v = normalize(FC_proj(z) + B A z)`` (eq. 7.6): ``FC_proj`` is a linear layer to ``proj_dim``
  (thesis d2 = 16); the LoRA adapter ``A [latent_dim -> rank]``, ``B [rank -> proj_dim]`` with ``B`` initialised to
  zero, so a fresh adapter leaves ``v`` unchanged (thesis r = 16, full rank for d2 = 16).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from seal.core.config import check_keys
from seal.models.behavior.features import BehaviorFeatureConfig


@dataclass(frozen=True)
class BehaviorConfig:
    """Architecture of the behaviour network (recorded in every saved model).

    Attributes:
        features: what the encoder sees.
        d_model: token width of the transformer.
        n_heads: attention heads.
        n_layers: transformer encoder layers.
        ff_mult: feed-forward width as a multiple of ``d_model``.
        dropout: dropout in the encoder.
        latent_dim: width of the behaviour latent z (thesis d1 = 256).
        proj_dim: width of the contrastive embedding v (thesis d2 = 16).
        lora_rank: rank r of the LoRA adapter (thesis r = 16).
        n_modes: reconstruction modes of the decoder.
    """

    features: BehaviorFeatureConfig = field(default_factory=BehaviorFeatureConfig)
    d_model: int = 64
    n_heads: int = 4
    n_layers: int = 2
    ff_mult: int = 2
    dropout: float = 0.0
    latent_dim: int = 256
    proj_dim: int = 16
    lora_rank: int = 16
    n_modes: int = 6

    def __post_init__(self) -> None:
        for key in ("d_model", "n_heads", "n_layers", "ff_mult", "latent_dim", "proj_dim", "lora_rank", "n_modes"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"behaviour config: field {key!r} must be >= 1, got {getattr(self, key)}")
        if self.d_model % self.n_heads:
            raise ValueError(f"behaviour config: d_model ({self.d_model}) must be a multiple of n_heads "
                             f"({self.n_heads})")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "behaviour config") -> BehaviorConfig:
        d = dict(d)
        check_keys(cls, d, where)
        feats = d.pop("features", {})
        if isinstance(feats, dict):
            check_keys(BehaviorFeatureConfig, feats, f"{where}: features")
            feats = BehaviorFeatureConfig(**feats)
        return cls(features=feats, **d)


class BehaviorNet(nn.Module):
    """See the module docstring. Inputs: ``agents [B, N, token_features]``, ``mask [B, N]`` (True = present)."""

    def __init__(self, cfg: BehaviorConfig) -> None:
        super().__init__()
        self.cfg = cfg
        d, d1, n_in = cfg.d_model, cfg.latent_dim, cfg.features.token_features
        self.token_in = nn.Sequential(nn.Linear(n_in, 2 * d), nn.ReLU(), nn.Linear(2 * d, d))
        layer = nn.TransformerEncoderLayer(d, cfg.n_heads, cfg.ff_mult * d, cfg.dropout, batch_first=True,
                                           norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, cfg.n_layers, enable_nested_tensor=False)
        self.encoder_norm = nn.LayerNorm(d)
        self.to_latent = nn.Linear(d, d1)
        self.modes = nn.Parameter(0.1 * torch.randn(cfg.n_modes, d1))
        self.decoder = nn.Sequential(nn.LayerNorm(d1), nn.Linear(d1, d1), nn.ReLU(),
                                     nn.Linear(d1, 2 * cfg.features.n_rows))
        self.mode_logit = nn.Sequential(nn.LayerNorm(d1), nn.Linear(d1, d), nn.ReLU(), nn.Linear(d, 1))
        self.proj = nn.Linear(d1, cfg.proj_dim)
        self.lora_a = nn.Linear(d1, cfg.lora_rank, bias=False)
        self.lora_b = nn.Linear(cfg.lora_rank, cfg.proj_dim, bias=False)
        nn.init.zeros_(self.lora_b.weight)  # eq. 7.6: B = 0, so v starts as the pre-trained projection

    def encode(self, agents: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Behaviour latents ``z [B, latent_dim]`` of the targets (token 0 of each row)."""
        tokens = self.encoder(self.token_in(agents), src_key_padding_mask=~mask)
        return self.to_latent(self.encoder_norm(tokens[:, 0]))

    def decode(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Reconstructed trajectories ``[B, n_modes, S, 2]`` (units of ``pos_scale_m``, target frame) and mode
        logits ``[B, n_modes]`` from ``z``."""
        h = z[:, None] + self.modes[None]
        traj = self.decoder(h).unflatten(-1, (self.cfg.features.n_rows, 2))
        return traj, self.mode_logit(h)[..., 0]

    def project(self, z: torch.Tensor, lora: bool = True) -> torch.Tensor:
        """Contrastive embedding ``v [B, proj_dim]`` (unit norm) of eq. 7.6; ``lora=False`` leaves the adapter out."""
        out = self.proj(z)
        if lora:
            out = out + self.lora_b(self.lora_a(z))
        return F.normalize(out, dim=-1)

    def lora_parameters(self) -> list[torch.Tensor]:
        """A and B: the only parameters fine-tuning trains."""
        return [self.lora_a.weight, self.lora_b.weight]

    def base_parameters(self) -> list[torch.Tensor]:
        """Everything but the adapter (what pre-training trains)."""
        lora = {id(p) for p in self.lora_parameters()}
        return [p for p in self.parameters() if id(p) not in lora]

    def forward(self, agents: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(traj, logits, v)`` of the targets."""
        z = self.encode(agents, mask)
        traj, logits = self.decode(z)
        return traj, logits, self.project(z)
