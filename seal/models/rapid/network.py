"""The RAPID network (paper 004, 3.2-3.4) at a CPU size: map encoder, agent encoder, denoiser.

* `MapEncoder` (3.3, eq. 6): map tokens -> MLP; ``N_LATENTS`` learned queries plus the Fourier encoding of a
  grid of spatial anchors attend to them once per scenario -> ``z_global [N_LATENTS, D]`` (cached by the caller).
* `AgentEncoder` (3.2): own state + local map read-out, and each optional input (previous acceleration, desired
  speed, destination, leader) projected linearly or replaced by its learned "missing" embedding; neighbours
  through a shared MLP and a masked max; then each agent queries ``z_global`` (cross-attention) -> ``ctx [n, D]``.
* `Denoiser` (3.4): noisy next-step acceleration ``x_k [n, 2]`` (agent frame, / ACC_SCALE), the diffusion step
  and ``ctx`` -> the clean acceleration ``x0 [n, 2]`` (x0-parametrisation: the physics guidance of eq. 7 acts
  on x0 directly).
"""

from __future__ import annotations

import math
from typing import cast

import numpy as np
import torch
from torch import nn

from seal.models.rapid.features import FREQS, NEIGHBOR_DIM, OWN_DIM, POS_DIM, AgentInputs

N_LATENTS = 16
"""Global map latents (4 x 4 anchor grid over the road's extent)."""


def _mlp(n_in: int, hidden: int, n_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(n_in, hidden), nn.SiLU(), nn.Linear(hidden, n_out))


class MapEncoder(nn.Module):
    """Map tokens ``[M, POS_DIM + 3]`` -> global latents ``[N_LATENTS, D]`` (eq. 6)."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.tokens = _mlp(POS_DIM + 3, dim, dim)
        self.queries = nn.Parameter(torch.randn(N_LATENTS, dim) * 0.1)
        self.anchor_pe = nn.Linear(POS_DIM, dim)
        self.attn = nn.MultiheadAttention(dim, 4, batch_first=True)

    def forward(self, tokens: torch.Tensor, anchors_pe: torch.Tensor, pad: torch.Tensor | None = None
                ) -> torch.Tensor:
        """``tokens [B, M, F]``, ``anchors_pe [B, N_LATENTS, POS_DIM]``, ``pad [B, M]`` (True: padding token)
        -> ``[B, N_LATENTS, D]``."""
        kv = self.tokens(tokens)
        q = self.queries[None] + self.anchor_pe(anchors_pe)
        out, _ = self.attn(q, kv, kv, key_padding_mask=pad, need_weights=False)
        return out + q


def anchor_encoding(tokens: np.ndarray) -> np.ndarray:
    """Fourier encoding ``[N_LATENTS, POS_DIM]`` of a 4 x 4 grid over the extent of the tokens' positions
    (recovered from the lowest-frequency sin / cos pair, which is unambiguous within 1 km)."""
    n = len(FREQS)
    sin0, cos0 = tokens[:, [0, n]], tokens[:, [2 * n, 3 * n]]
    xy = np.arctan2(sin0, cos0) / FREQS[0]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    gx, gy = np.meshgrid(np.linspace(lo[0], hi[0], 4), np.linspace(lo[1], hi[1], 4))
    grid = np.column_stack([gx.ravel(), gy.ravel()])
    ang = grid[:, :, None] * FREQS[None, None, :]
    return np.concatenate([np.sin(ang).reshape(len(grid), -1), np.cos(ang).reshape(len(grid), -1)], 1).astype(
        np.float32)


class AgentEncoder(nn.Module):
    """`AgentInputs` and the global latents of each agent's scenario -> context ``[n, D]``."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.own = _mlp(OWN_DIM, dim, dim)
        self.optional = nn.ModuleDict({
            "prev": nn.Linear(2, dim), "speed": nn.Linear(1, dim), "dest": nn.Linear(3, dim),
            "leader": nn.Linear(2, dim), "neighbors": nn.Identity(),
        })
        self.missing = nn.ParameterDict({k: nn.Parameter(torch.zeros(dim)) for k in self.optional})
        self.neighbor = _mlp(NEIGHBOR_DIM, dim, dim)
        self.norm = nn.LayerNorm(dim)
        self.attn = nn.MultiheadAttention(dim, 4, batch_first=True)
        self.out = _mlp(dim, 2 * dim, dim)

    def _opt(self, name: str, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return torch.where(mask[:, None] > 0.5, self.optional[name](x), self.missing[name])

    def latent_kv(self, z_global: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Keys and values ``[N_LATENTS, D]`` of one scenario's global latents ``z_global [1 or N_LATENTS, ...]``
        in the read-out attention: they depend on the map only, so a caller caches them with the latents
        instead of projecting the same 16 latents again for every agent on every step."""
        z = z_global.reshape(-1, self.attn.embed_dim)
        w, b = self.attn.in_proj_weight, self.attn.in_proj_bias
        e = self.attn.embed_dim
        return z @ w[e: 2 * e].T + b[e: 2 * e], z @ w[2 * e:].T + b[2 * e:]

    def _read(self, h: torch.Tensor, kv: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        """The read-out attention of ``h [n, D]`` against cached ``kv`` (`latent_kv`): the operations of
        ``self.attn`` with one query per agent and the same keys for all."""
        e, heads = self.attn.embed_dim, self.attn.num_heads
        d = e // heads
        w, b = self.attn.in_proj_weight, self.attn.in_proj_bias
        q = (h @ w[:e].T + b[:e]).reshape(-1, heads, d)
        k, v = kv[0].reshape(-1, heads, d), kv[1].reshape(-1, heads, d)
        att = torch.softmax(torch.einsum("nhd,lhd->nhl", q, k) / math.sqrt(d), dim=-1)
        read = torch.einsum("nhl,lhd->nhd", att, v).reshape(-1, e)
        return self.attn.out_proj(read)

    def forward(self, inp: dict[str, torch.Tensor], z_global: torch.Tensor,
                kv: tuple[torch.Tensor, torch.Tensor] | None = None) -> torch.Tensor:
        """``inp``: `AgentInputs` fields as tensors; ``z_global [n, N_LATENTS, D]`` (each agent's scenario's);
        ``kv``: `latent_kv` of a single scenario's latents (then ``z_global`` is not read: the per-step path)."""
        h = self.own(inp["own"])
        h = h + self._opt("prev", inp["prev_acc"], inp["prev_mask"])
        h = h + self._opt("speed", inp["speed_cmd"], inp["speed_mask"])
        h = h + self._opt("dest", inp["dest"], inp["dest_mask"])
        h = h + self._opt("leader", inp["leader"], inp["leader_mask"])
        nb = self.neighbor(inp["neighbors"])
        nmask = inp["neighbor_mask"][..., None] > 0.5
        pooled = torch.where(nmask, nb, torch.full_like(nb, -1e4)).amax(dim=1)
        any_nb = nmask.any(dim=1)
        h = h + torch.where(any_nb, pooled, self.missing["neighbors"])
        h = self.norm(h)
        if kv is not None:
            h = h + self._read(h, kv)
        else:
            read, _ = self.attn(h[:, None], z_global, z_global, need_weights=False)
            h = h + read[:, 0]
        return h + self.out(h)


def step_embedding(k: torch.Tensor, dim: int = 16) -> torch.Tensor:
    """Sinusoidal embedding ``[n, dim]`` of diffusion steps ``k [n]``."""
    half = dim // 2
    freq = torch.exp(-math.log(1000.0) * torch.arange(half, dtype=torch.float32) / half)
    ang = k.float()[:, None] * freq[None]
    return torch.cat([torch.sin(ang), torch.cos(ang)], dim=1)


class Denoiser(nn.Module):
    """``(x_k [n, 2], k [n], ctx [n, D]) -> x0 [n, 2]``."""

    def __init__(self, dim: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(2 + 16 + dim, 2 * dim), nn.SiLU(), nn.Linear(2 * dim, 2 * dim), nn.SiLU(),
            nn.Linear(2 * dim, 2),
        )

    def forward(self, x: torch.Tensor, k: torch.Tensor, ctx: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([x, step_embedding(k), ctx], dim=1))

    def context_part(self, ctx: torch.Tensor) -> torch.Tensor:
        """``[n, 2D]``: the first layer's context term and bias, the same at every DDIM step of an env step."""
        first = cast(nn.Linear, self.net[0])
        return ctx @ first.weight[:, 18:].T + first.bias

    def forward_from(self, x: torch.Tensor, k: int, ctx_part: torch.Tensor) -> torch.Tensor:
        """`forward` for one diffusion step ``k`` shared by all rows, given `context_part`: the step embedding
        is one row and the context is not multiplied again (the per-agent cost of the sampler)."""
        first = cast(nn.Linear, self.net[0])
        emb = step_embedding(torch.tensor([k]))
        h = ctx_part + x @ first.weight[:, :2].T + emb @ first.weight[:, 2:18].T
        net = self.net
        return net[4](net[3](net[2](net[1](h))))


class RapidNet(nn.Module):
    """The three parts together; ``dim`` is the width D."""

    def __init__(self, dim: int = 64) -> None:
        super().__init__()
        self.dim = dim
        self.map = MapEncoder(dim)
        self.agent = AgentEncoder(dim)
        self.denoiser = Denoiser(dim)


def inputs_to_torch(inp: AgentInputs) -> dict[str, torch.Tensor]:
    """`AgentInputs` as a dict of float32 tensors (no copy)."""
    return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) for k, v in vars(inp).items()}
