"""Sparse autoencoders on latents and SAE-refined control vectors (paper 002, section 3.3).

The SAE sees latents centred and divided by one scalar (their RMS standard deviation), so directions keep their
geometry: ``S = ReLU(W_enc (x - b_dec) + b_enc)``, ``x_hat = W_dec S + b_dec``; loss = mean squared
reconstruction error + ``l1`` x mean over rows of ``sum |S|``. The decoder's columns are kept at unit norm after
each step (otherwise the L1 term is dodged by shrinking ``S`` and growing ``W_dec``).

SAE control vector (paper eq. 1-3): ``V' = PCA_1(S_pos - S_neg)`` of randomly paired sparse codes, then
``V = W_dec V'`` back in latent space. The paper also adds ``b_dec``; a bias is not a direction (scaled by tau it
would shift every latent by a constant unrelated to the feature), so it is left out here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from seal.models.steering.linear import first_axis, paired_differences


@dataclass(frozen=True)
class SAEConfig:
    """Training of one sparse autoencoder.

    Attributes:
        width: sparse intermediate dimension.
        l1: weight of the L1 sparsity term.
        epochs: passes over the latents.
        batch_size: rows per step.
        lr: Adam learning rate.
        seed: initialisation and shuffling seed.
    """

    width: int = 128
    l1: float = 3e-2
    epochs: int = 200
    batch_size: int = 512
    lr: float = 1e-3
    seed: int = 0


class SparseAutoencoder(nn.Module):
    """``d -> width -> d`` with ReLU codes (module docstring). ``centre [d]`` and ``scale`` map latents to its
    input space."""

    # Buffers (`register_buffer`), declared so type checkers see tensors.
    centre: torch.Tensor
    scale: torch.Tensor

    def __init__(self, d: int, width: int) -> None:
        super().__init__()
        self.enc = nn.Linear(d, width)
        self.dec = nn.Linear(width, d)
        self.register_buffer("centre", torch.zeros(d, dtype=torch.float64))
        self.register_buffer("scale", torch.ones((), dtype=torch.float64))
        with torch.no_grad():
            self.dec.weight.copy_(self.enc.weight.T)
            self.normalize_decoder()

    def normalize_decoder(self) -> None:
        with torch.no_grad():
            self.dec.weight.div_(self.dec.weight.norm(dim=0, keepdim=True).clamp(min=1e-8))

    def inputs(self, latents: np.ndarray) -> torch.Tensor:
        return ((torch.as_tensor(latents, dtype=torch.float64) - self.centre) / self.scale).float()

    def code(self, x: torch.Tensor) -> torch.Tensor:
        """Sparse codes ``[N, width]`` of inputs ``[N, d]`` (already centred and scaled)."""
        return torch.relu(self.enc(x - self.dec.bias))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        s = self.code(x)
        return self.dec(s), s


@dataclass(frozen=True)
class SAEStats:
    """Fit diagnostics: explained variance of the reconstruction, mean active codes per row (L0), share of codes
    never active, on held-out latents."""

    width: int
    explained_variance: float
    l0: float
    dead_share: float
    final_loss: float


def fit_sae(latents: np.ndarray, cfg: SAEConfig, held_out: np.ndarray | None = None
            ) -> tuple[SparseAutoencoder, SAEStats]:
    """Train an SAE on ``latents [N, d]``; stats on ``held_out`` rows (default: the training rows)."""
    torch.manual_seed(cfg.seed)
    z = np.asarray(latents, np.float64)
    sae = SparseAutoencoder(z.shape[1], cfg.width)
    sae.centre.copy_(torch.as_tensor(z.mean(0)))
    sae.scale.fill_(float(np.sqrt(z.var(0).mean())) or 1.0)
    x = sae.inputs(z)
    opt = torch.optim.Adam(sae.parameters(), lr=cfg.lr)
    gen = torch.Generator().manual_seed(cfg.seed)
    loss = torch.zeros(())
    for _ in range(cfg.epochs):
        for rows in torch.randperm(len(x), generator=gen).split(cfg.batch_size):
            xb = x[rows]
            x_hat, s = sae(xb)
            loss = ((x_hat - xb) ** 2).mean() + cfg.l1 * s.abs().sum(1).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sae.normalize_decoder()
    with torch.no_grad():
        xe = sae.inputs(np.asarray(held_out if held_out is not None else z, np.float64))
        x_hat, s = sae(xe)
        ev = 1.0 - float(((x_hat - xe) ** 2).sum() / ((xe - xe.mean(0)) ** 2).sum())
        stats = SAEStats(cfg.width, ev, float((s > 0).float().sum(1).mean()), float((s.max(0).values <= 0).float()
                         .mean()), float(loss))
    return sae.eval(), stats


def sae_control_vector(sae: SparseAutoencoder, pos: np.ndarray, neg: np.ndarray, seed: int = 0
                       ) -> tuple[np.ndarray, float]:
    """SAE-refined control vector: unit direction ``[d]`` in latent space and the class gap along it (the mean
    projection of the latent pair differences; module docstring)."""
    rng = np.random.default_rng(seed)
    pos, neg = np.asarray(pos, np.float64), np.asarray(neg, np.float64)
    with torch.no_grad():
        s_pos = sae.code(sae.inputs(pos)).double().numpy()
        s_neg = sae.code(sae.inputs(neg)).double().numpy()
    n = min(max(len(pos), len(neg)), 4096)
    i, j = rng.integers(len(pos), size=n), rng.integers(len(neg), size=n)
    code_diffs = s_pos[i] - s_neg[j]
    axis = first_axis(code_diffs, rng, code_diffs.mean(0))
    v = sae.dec.weight.detach().double().numpy() @ axis
    v = v / max(float(np.linalg.norm(v)), 1e-12)
    latent_diffs = pos[i] - neg[j]
    if latent_diffs.mean(0) @ v < 0:  # keep "towards the positive class" after the decoder's mixing
        v = -v
    return v, float(latent_diffs.mean(0) @ v)


__all__ = ["SAEConfig", "SAEStats", "SparseAutoencoder", "fit_sae", "paired_differences", "sae_control_vector"]
