"""Losses of the trajectory prior and the validation metrics computed during training.

* Regression: each target's winning mode (the mode whose anchor is closest to the logged future, or with
  ``assignment == "predicted"`` the closest prediction) is pulled to the logged future with a Huber loss over the
  valid future steps (m).
* Classification: cross-entropy of the mode logits against the winning mode.
* On road: modes the regression does not train (the most probable and random others) are pushed back within a
  margin of the lane centrelines (`road_loss`).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from seal.models.prior.features import featurise, road_points
from seal.models.prior.metrics import ROAD_CHECK_EVERY, displacement_errors, top_k_min
from seal.models.prior.network import PriorNet
from seal.models.prior.samples import SampleSet
from seal.models.prior.train_config import PriorTrainConfig


def prior_loss(
    chosen_xy: torch.Tensor, logits: torch.Tensor, best: torch.Tensor, future_xy: torch.Tensor,
    future_valid: torch.Tensor, cls_weight: float, huber_beta_m: float,
) -> torch.Tensor:
    """Huber regression of each target's winning mode + cross-entropy of the mode logits (module docstring).

    Args:
        chosen_xy: ``[B, T, 2]`` the winning mode's positions (m). logits: ``[B, K]``. best: ``[B]`` winning modes.
        future_xy: ``[B, T, 2]`` logged future (m). future_valid: ``[B, T]`` bool.
    """
    huber = F.smooth_l1_loss(chosen_xy, future_xy, reduction="none", beta=huber_beta_m).sum(-1)  # [B, T]
    m = future_valid.to(huber.dtype)
    reg = ((huber * m).sum(-1) / m.sum(-1).clamp(min=1.0)).mean()
    return reg + cls_weight * F.cross_entropy(logits, best)


@torch.no_grad()
def anchor_assignment(net: PriorNet, samples: SampleSet, batch_size: int = 1024) -> torch.Tensor:
    """``[S]`` for every target, the mode whose anchor (integrated from the target's start) has the smallest ADE.

    Anchors are fixed during training, so this is computed once instead of every step.
    """
    out = []
    for rows in torch.arange(len(samples)).split(batch_size):
        anchors = net.anchor_trajectories(samples.tables.start[rows])
        ade, _ = displacement_errors(anchors, samples.future[rows], samples.future_valid[rows])
        out.append(ade.argmin(dim=1))
    return torch.cat(out)


def road_loss(xy: torch.Tensor, points: torch.Tensor, mask: torch.Tensor, margin_m: float) -> torch.Tensor:
    """Mean distance (m) beyond ``margin_m`` from positions ``[B, M, T, 2]`` to the nearest of ``points``
    ``[B, R, 2]`` (``mask`` ``[B, R]`` marks real points)."""
    b, m, t, _ = xy.shape
    flat = xy.reshape(b, m * t, 2)
    with torch.no_grad():  # find the nearest point without autograd over the [B, M*T, R] distance matrix
        nearest = torch.cdist(flat, points).masked_fill(~mask[:, None, :], float("inf")).argmin(dim=-1)
    near = torch.gather(points, 1, nearest[..., None].expand(-1, -1, 2))  # [B, M*T, 2]
    return torch.relu(torch.linalg.norm(flat - near, dim=-1) - margin_m).mean()


def batch_loss(
    net: PriorNet, samples: SampleSet, rows: torch.Tensor, tc: PriorTrainConfig, assigned: torch.Tensor | None,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """Training loss of the targets ``rows``; ``assigned`` are the anchor assignments of all targets (None for
    ``assignment == "predicted"``: the mode with the smallest ADE wins). ``generator`` draws the modes the
    on-road loss sees."""
    feats = featurise(samples.tables, rows, net.cfg.features)
    tokens, mask = net.encode(feats)
    fut, valid = samples.future[rows], samples.future_valid[rows]
    use_road = tc.road_weight > 0 and samples.tables.road_idx is not None
    n_sub = min(len(rows), tc.road_batch) if use_road else 0  # targets the on-road loss sees
    controls, logits = net.decode_controls(tokens, mask)
    start = feats["start"]
    if assigned is not None:
        best = assigned[rows]
        # Only the modes the losses see are integrated: integration is the costliest part of decoding.
        chosen = net.integrate(net.select_modes(controls, best[:, None]), start)[:, 0]
    else:
        xy = net.integrate(controls, start)
        with torch.no_grad():
            best = displacement_errors(xy, fut, valid)[0].argmin(dim=1)
        chosen = xy[torch.arange(len(rows)), best]
    loss = prior_loss(chosen, logits, best, fut, valid, tc.cls_weight, tc.huber_beta_m)
    if n_sub:
        n_top = min(tc.road_top_modes, tc.road_modes, net.cfg.n_modes)
        top = torch.topk(logits[:n_sub].detach(), n_top, dim=1).indices
        rand = torch.randint(0, net.cfg.n_modes, (n_sub, max(0, tc.road_modes - n_top)), generator=generator)
        extra = torch.cat([top, rand], dim=1)
        others = net.integrate(net.select_modes(controls[:n_sub], extra), start[:n_sub])
        points, pmask = road_points(samples.tables, rows[:n_sub])
        samples_xy = others[:, :, ROAD_CHECK_EVERY - 1 :: ROAD_CHECK_EVERY]
        loss = loss + tc.road_weight * road_loss(samples_xy, points, pmask, tc.road_margin_m)
    return loss


@torch.no_grad()
def training_loss(
    net: PriorNet, samples: SampleSet, tc: PriorTrainConfig, assigned: torch.Tensor | None, max_targets: int = 2048
) -> float:
    """Mean training loss of ``net`` (eval mode) over the first ``max_targets`` targets of ``samples``."""
    was_training = net.training
    net.eval()
    rows = torch.arange(min(len(samples), max_targets))
    gen = torch.Generator().manual_seed(0)
    total = sum(batch_loss(net, samples, chunk, tc, assigned, gen).item() * len(chunk) for chunk in rows.split(512))
    net.train(was_training)
    return total / len(rows)


@torch.no_grad()
def evaluate_samples(net: PriorNet, samples: SampleSet, batch_size: int = 512) -> dict[str, float]:
    """Mean minADE@1 / @6 / @K and minFDE@6 (m) of ``net`` on ``samples`` (their valid future steps), and, when
    the samples carry road chunks, ``on_road``: the share of candidates whose 0.5 s samples all lie within 4 m
    (about a lane width) of a lane-centreline point (a training monitor; `seal eval prior` measures it exactly)."""
    net.eval()
    sums = {"min_ade_1": 0.0, "min_ade_6": 0.0, "min_ade_all": 0.0, "min_fde_6": 0.0}
    on_road = 0.0
    n = len(samples)
    for start in range(0, n, batch_size):
        rows = torch.arange(start, min(n, start + batch_size))
        xy, logits = net(featurise(samples.tables, rows, net.cfg.features))
        ade, fde = displacement_errors(xy, samples.future[rows], samples.future_valid[rows])
        sums["min_ade_1"] += float(top_k_min(ade, logits, 1).sum())
        sums["min_ade_6"] += float(top_k_min(ade, logits, 6).sum())
        sums["min_ade_all"] += float(ade.min(dim=1).values.sum())
        sums["min_fde_6"] += float(top_k_min(fde, logits, 6).sum())
        if samples.tables.road_idx is not None:
            points, mask = road_points(samples.tables, rows)
            pts = xy[:, :, ROAD_CHECK_EVERY - 1 :: ROAD_CHECK_EVERY]
            b, k, t, _ = pts.shape
            d = torch.cdist(pts.reshape(b, k * t, 2), points).masked_fill(~mask[:, None, :], float("inf"))
            on_road += float((d.min(dim=-1).values.view(b, k, t) <= 4.0).all(dim=-1).float().mean(dim=1).sum())
    out = {k: v / n for k, v in sums.items()}
    if samples.tables.road_idx is not None:
        out["on_road"] = on_road / n
    return out
