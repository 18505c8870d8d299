"""Ranking losses of pi_score's training within groups of candidates (one scenario and previous roll-out each):
``pred`` and ``target`` are ``[G * n, 2]`` predicted / simulated ``[f_coll, f_diff]`` of ``G`` groups of ``n``
consecutive candidates, ranked by their sum (`seal.models.objective.train`)."""

from __future__ import annotations

import torch


def listnet_loss(pred: torch.Tensor, target: torch.Tensor, n_cand: int, temperature: float) -> torch.Tensor:
    """ListNet cross-entropy between the candidate distributions ``softmax(sum / temperature)`` of the simulated
    and the predicted ``f_coll + f_diff``, per group of ``n_cand`` consecutive pairs (``pred, target [G * n, 2]``),
    averaged over groups; minus the target's entropy, so a perfect ranking scores about 0."""
    p = pred.sum(dim=-1).reshape(-1, n_cand) / temperature
    t = torch.softmax(target.sum(dim=-1).reshape(-1, n_cand) / temperature, dim=-1)
    return (t * (torch.log(t.clamp(min=1e-12)) - torch.log_softmax(p, dim=-1))).sum(dim=-1).mean()


def pairwise_loss(pred: torch.Tensor, target: torch.Tensor, n_cand: int, temperature: float,
                  min_gap: float = 0.05) -> torch.Tensor:
    """RankNet-style pairwise logistic loss on the predicted ``f_coll + f_diff`` within each group of ``n_cand``
    consecutive pairs (``pred, target [G * n, 2]``): for every ordered pair of candidates (a, b) of a group whose
    simulated sums differ by more than ``min_gap``, ``softplus(-(s_a - s_b) / temperature)`` with a the better one,
    weighted by the size of the simulated gap ``|y_a - y_b|`` (a swap of very different candidates costs more, as it
    costs more Spearman); the weighted mean over all such pairs of all groups (0 when there are none).

    The per-scenario Spearman only sees the order of the candidates of one scenario, and this loss only sees
    differences within a group, so a shift of a whole scenario's scores (what MSE spends most of its effort on:
    62 % of the f_diff variance is between scenarios) neither helps nor hurts it.
    """
    s = pred.sum(dim=-1).reshape(-1, n_cand)
    y = target.sum(dim=-1).reshape(-1, n_cand)
    gap = y[:, :, None] - y[:, None, :]  # [G, n, n]: y_a - y_b
    weight = torch.where(gap > min_gap, gap, torch.zeros_like(gap))
    total = weight.sum()
    if float(total) <= 0.0:
        return pred.sum() * 0.0
    margin = (s[:, :, None] - s[:, None, :]) / temperature
    return (weight * torch.nn.functional.softplus(-margin)).sum() / total


def group_ranks(y: torch.Tensor) -> torch.Tensor:
    """Average ranks ``0..n-1`` along the last axis of ``y [G, n]`` (tied values share their mean rank), as
    `seal.models.objective.metrics.average_ranks`."""
    less = (y[..., None, :] < y[..., :, None]).sum(dim=-1).to(y.dtype)
    equal = (y[..., None, :] == y[..., :, None]).sum(dim=-1).to(y.dtype)
    return less + 0.5 * (equal - 1.0)


def pearson_rank_loss(pred: torch.Tensor, target: torch.Tensor, n_cand: int, temperature: float = 1.0
                      ) -> torch.Tensor:
    """``1 -`` the mean over groups of the Pearson correlation between the predicted ``f_coll + f_diff`` and the
    ranks of the simulated one, per group of ``n_cand`` consecutive pairs (``pred, target [G * n, 2]``).

    A smooth stand-in for the per-scenario Spearman (which is the Pearson correlation of both sides' ranks): only
    the prediction's ranks are relaxed to its values. Unlike a pairwise loss it weighs every candidate's rank as
    Spearman does, and like it ignores a shift or scale of a whole scenario's scores. A group whose simulated sums
    are all equal (or whose predictions are) adds 1 (no correlation). ``temperature`` is unused (the loss is
    scale-free); it is accepted for the common signature of the ranking losses."""
    del temperature
    s = pred.sum(dim=-1).reshape(-1, n_cand)
    r = group_ranks(target.sum(dim=-1).reshape(-1, n_cand))
    s = s - s.mean(dim=-1, keepdim=True)
    r = r - r.mean(dim=-1, keepdim=True)
    ss, rr = (s * s).sum(dim=-1), (r * r).sum(dim=-1)
    # A (near-)constant group is left out of the gradient: sqrt and 1 / norm are not differentiable at 0, and a
    # NaN there would poison every weight (e.g. a scenario whose candidates all stay far from the ego).
    ok = (ss > 1e-8) & (rr > 0)
    den = torch.sqrt(torch.where(ok, ss * rr, torch.ones_like(ss)))
    corr = torch.where(ok, (s * r).sum(dim=-1) / den, torch.zeros_like(ss))
    return 1.0 - corr.mean()
