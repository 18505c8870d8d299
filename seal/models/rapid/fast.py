"""The per-step inference path of the RAPID network (`RapidBackground`): the operations of `AgentEncoder.forward`
(with cached read-out keys / values) and of `Denoiser.forward_from`, regrouped so that an env step makes few,
larger torch calls.

Why: at 120 agents one thread spends most of the network's time in many small torch calls per agent batch (four
optional-input projections each followed by a ``where``, separate bias adds, out-of-place activations). Here:

* the own-state MLP's second layer and the four optional inputs (previous acceleration, desired speed,
  destination, leader) are one matrix product: ``[silu(own W1 + b1), x_opt * mask, mask] @ [W2; W_opt; b_opt -
  missing]`` + ``b2 + sum(missing)`` equals ``own(x) + sum_p where(mask_p, W_p x_p + b_p, missing_p)`` for masks in
  {0, 1} (the missing embedding enters through the mask column);
* linear layers are ``addmm`` and activations in place (inference only: nothing is kept for a backward pass);
* the denoiser's diffusion-step term ``step_embedding(k) W_k`` is computed once per step ``k`` and cached.

Both classes read the weights of the modules they were built from at construction; build them again after
changing the weights (`RapidBackground` builds them once, for a network in eval mode).
"""

from __future__ import annotations

import math
from typing import cast

import torch
from torch import nn

from seal.models.rapid.network import AgentEncoder, Denoiser, step_embedding

OPTIONAL = (("prev", "prev_acc", "prev_mask"), ("speed", "speed_cmd", "speed_mask"), ("dest", "dest", "dest_mask"),
            ("leader", "leader", "leader_mask"))
"""The optional inputs: (module key, `AgentInputs` field, mask field)."""


def _linear(m: nn.Module) -> tuple[torch.Tensor, torch.Tensor]:
    """``(W^T, b)`` of an `nn.Linear`, contiguous, detached."""
    lin = cast(nn.Linear, m)
    return lin.weight.detach().T.contiguous(), lin.bias.detach().clone()


class FastAgentEncoder:
    """`AgentEncoder.forward(inp, z, kv)` of ``enc`` (module docstring); call as ``fast(inp, kv)``."""

    @torch.no_grad()
    def __init__(self, enc: AgentEncoder) -> None:
        self.own1 = _linear(enc.own[0])
        w2, b2 = _linear(enc.own[2])
        ws, bias_minus_missing = [w2], []
        for key, _, _ in OPTIONAL:
            w, b = _linear(enc.optional[key])
            ws.append(w)
            bias_minus_missing.append(b - enc.missing[key].detach())
        self.mid_w = torch.cat(ws + [torch.stack(bias_minus_missing)]).contiguous()
        self.mid_b = b2 + sum(enc.missing[k].detach() for k, _, _ in OPTIONAL)
        self.mask_cols = torch.tensor([i for i, (key, _, _) in enumerate(OPTIONAL)
                                       for _ in range(cast(nn.Linear, enc.optional[key]).in_features)])
        self.nb1, self.nb2 = _linear(enc.neighbor[0]), _linear(enc.neighbor[2])
        self.nb_missing = enc.missing["neighbors"].detach().clone()
        self.norm = enc.norm
        e, heads = enc.attn.embed_dim, enc.attn.num_heads
        self.heads, self.head_dim = heads, e // heads
        self.q = (enc.attn.in_proj_weight.detach()[:e].T.contiguous() / math.sqrt(self.head_dim),
                  enc.attn.in_proj_bias.detach()[:e] / math.sqrt(self.head_dim))
        self.att_out = _linear(enc.attn.out_proj)
        self.out1, self.out2 = _linear(enc.out[0]), _linear(enc.out[2])

    @torch.no_grad()
    def __call__(self, inp: dict[str, torch.Tensor], kv: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        """``inp``: `AgentInputs` fields as tensors (masks 0 / 1); ``kv``: `AgentEncoder.latent_kv` -> ``[n, D]``."""
        masks = torch.stack([(inp[m] > 0.5).to(inp["own"].dtype) for _, _, m in OPTIONAL], dim=1)
        opt = torch.cat([inp[f] for _, f, _ in OPTIONAL], dim=1) * masks[:, self.mask_cols]
        return self.tables(inp["own"], opt, masks, inp["neighbors"], inp["neighbor_mask"], kv)

    @torch.no_grad()
    def tables(self, own: torch.Tensor, opt: torch.Tensor, masks: torch.Tensor, neighbors: torch.Tensor,
               neighbor_mask: torch.Tensor, kv: tuple[torch.Tensor, torch.Tensor]) -> torch.Tensor:
        """The encoder on `seal.models.rapid.features.InputTables`' tables: ``opt [n, 8]`` the optional inputs in
        `OPTIONAL`'s order, zero where absent, ``masks [n, 4]`` 0 / 1 (the per-step path: no per-field tensors)."""
        n = own.shape[0]
        h_own = torch.nn.functional.silu(torch.addmm(self.own1[1], own, self.own1[0]), inplace=True)
        h = torch.addmm(self.mid_b, torch.cat([h_own, opt, masks], dim=1), self.mid_w)
        k_nb = neighbors.shape[1]
        nb = torch.nn.functional.silu(torch.addmm(self.nb1[1], neighbors.reshape(n * k_nb, -1),
                                                  self.nb1[0]), inplace=True)
        nb = torch.addmm(self.nb2[1], nb, self.nb2[0]).reshape(n, k_nb, -1)
        nmask = neighbor_mask > 0.5
        pooled = nb.masked_fill_(~nmask[..., None], -1e4).amax(dim=1)
        h += torch.where(nmask.any(dim=1, keepdim=True), pooled, self.nb_missing)
        h = self.norm(h)
        q = torch.addmm(self.q[1], h, self.q[0]).reshape(n, self.heads, self.head_dim)
        k, v = kv[0].reshape(-1, self.heads, self.head_dim), kv[1].reshape(-1, self.heads, self.head_dim)
        att = torch.softmax(torch.einsum("nhd,lhd->nhl", q, k), dim=-1)
        read = torch.einsum("nhl,lhd->nhd", att, v).reshape(n, -1)
        h = torch.addmm(h, read, self.att_out[0]).add_(self.att_out[1])
        hidden = torch.nn.functional.silu(torch.addmm(self.out1[1], h, self.out1[0]), inplace=True)
        return torch.addmm(h, hidden, self.out2[0]).add_(self.out2[1])


class FastDenoiser:
    """`Denoiser.context_part` / `forward_from` of ``den`` (module docstring) for `seal.models.rapid.sampler.
    ddim_sample`."""

    @torch.no_grad()
    def __init__(self, den: Denoiser) -> None:
        first = cast(nn.Linear, den.net[0])
        w = first.weight.detach()
        self.ctx_w, self.bias = w[:, 18:].T.contiguous(), first.bias.detach().clone()
        self.x_w, self.step_w = w[:, :2].T.contiguous(), w[:, 2:18].T.contiguous()
        self.l2, self.l3 = _linear(den.net[2]), _linear(den.net[4])
        self._step_terms: dict[int, torch.Tensor] = {}

    @torch.no_grad()
    def context_part(self, ctx: torch.Tensor) -> torch.Tensor:
        """``[n, 2D]``: `Denoiser.context_part`."""
        return torch.addmm(self.bias, ctx, self.ctx_w)

    @torch.no_grad()
    def forward_from(self, x: torch.Tensor, k: int, ctx_part: torch.Tensor) -> torch.Tensor:
        """`Denoiser.forward_from`: the clean estimate ``[n, 2]`` for noisy ``x [n, 2]`` at diffusion step ``k``."""
        step = self._step_terms.get(k)
        if step is None:
            step = self._step_terms[k] = step_embedding(torch.tensor([k])) @ self.step_w
        h = torch.addmm(ctx_part, x, self.x_w).add_(step)
        h = torch.nn.functional.silu(h, inplace=True)
        h = torch.nn.functional.silu(torch.addmm(self.l2[1], h, self.l2[0]), inplace=True)
        return torch.addmm(self.l3[1], h, self.l3[0])
