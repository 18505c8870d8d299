"""Training of the prior: winner-takes-all regression over the modes plus cross-entropy on the mode logits.

Loss per target: the mode with the smallest ADE to the logged future is the winner; its positions are pulled to
the future with a Huber loss over the valid future steps (metres), and the mode logits are trained with
cross-entropy to pick the winner. Validation (targets of held-out scenarios) after every epoch measures
minADE@1 / @6; the best epoch by validation minADE@6 is kept and written, training stops early when it has not
improved for ``patience`` epochs, or when the next epoch would overrun the time budget. The training state is
saved next to the output after an epoch (at most every `STATE_EVERY_S`) so an interrupted run resumes with
``resume=True``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from seal.prior.anchors import fit_anchors
from seal.prior.features import featurise, road_points
from seal.prior.metrics import ROAD_CHECK_EVERY, displacement_errors, top_k_min
from seal.prior.network import PriorConfig, PriorNet, default_anchors
from seal.prior.prior import TrajectoryPrior
from seal.prior.samples import SampleSet, TargetFilter, build_samples
from seal.scenario import Scenario

STATE_EVERY_S = 30.0  # minimum seconds between two saves of the resumable training state


@dataclass(frozen=True)
class TrainConfig:
    """How the prior is trained (recorded in the saved model).

    Attributes:
        epochs: maximum epochs.
        batch_size: targets per optimiser step.
        lr: peak learning rate (AdamW; linear warm-up, then cosine decay to zero over the planned epochs).
        weight_decay: AdamW weight decay.
        warmup_steps: optimiser steps of linear warm-up.
        cls_weight: weight of the mode cross-entropy against the Huber regression (m).
        huber_beta_m: Huber transition (m).
        grad_clip: gradient-norm clip.
        val_fraction: share of the training scenarios held out for validation (by scenario).
        patience: epochs without a better validation minADE@6 before stopping.
        max_minutes: wall-clock budget; the planned epochs shrink to fit it after the first epoch and no epoch
            starts that would overrun it (None: no budget, fully deterministic for a seed).
        seed: seed of initialisation, validation hold-out and batch order.
        threads: torch CPU threads.
        road_weight: weight of the on-road loss: for ``road_modes`` random modes per target and step, the mean
            distance (m) by which their 0.5 s samples lie farther than ``road_margin_m`` from the nearest lane
            centreline point among ``road_chunks`` chunks around the target's 8 s constant-velocity path. It
            keeps the modes that the winner-takes-all regression does not train on the road. 0 switches it off.
        road_margin_m: distance from a lane centreline that costs nothing (m; about half a lane).
        road_modes: modes per target that the on-road loss sees in one step, to save time: the ``road_top_modes``
            most probable ones (those generators use most) and random others.
        road_top_modes: see ``road_modes``.
        road_batch: targets per step that the on-road loss sees (the first of the shuffled batch, to save time).
        road_chunks: lane chunks per target for the on-road loss.
        targets: which agents are training targets.
    """

    epochs: int = 10
    batch_size: int = 128
    lr: float = 2e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 200
    cls_weight: float = 0.5
    huber_beta_m: float = 0.5
    grad_clip: float = 5.0
    val_fraction: float = 0.05
    patience: int = 3
    max_minutes: float | None = 12.0
    seed: int = 0
    threads: int = 1
    road_weight: float = 3.0
    road_margin_m: float = 1.5
    road_modes: int = 8
    road_top_modes: int = 3
    road_batch: int = 48
    road_chunks: int = 96
    targets: TargetFilter = field(default_factory=TargetFilter)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        d = dict(d)
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"training config: unknown field(s) {sorted(unknown)}")
        targets = d.pop("targets", {})
        if isinstance(targets, dict):
            unknown = set(targets) - set(TargetFilter.__dataclass_fields__)
            if unknown:
                raise ValueError(f"training config: unknown field(s) targets.{sorted(unknown)}")
            targets = TargetFilter(**targets)
        return cls(targets=targets, **d)


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
    net: PriorNet, samples: SampleSet, rows: torch.Tensor, tc: TrainConfig, assigned: torch.Tensor | None,
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
    net: PriorNet, samples: SampleSet, tc: TrainConfig, assigned: torch.Tensor | None, max_targets: int = 2048
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


def split_validation(n_scenarios: int, fraction: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices of training and validation scenarios (at least one of each when ``n_scenarios >= 2``)."""
    if n_scenarios < 2:
        raise ValueError(f"need at least 2 training scenarios to hold out validation, got {n_scenarios}")
    perm = np.random.default_rng(seed).permutation(n_scenarios)
    n_val = min(n_scenarios - 1, max(1, round(fraction * n_scenarios)))
    return np.sort(perm[n_val:]), np.sort(perm[:n_val])


def _lr_factor(step: int, warmup: int, total: int) -> float:
    if step < warmup:
        return (step + 1) / warmup
    progress = min(1.0, (step - warmup) / max(1, total - warmup))
    return 0.5 * (1.0 + math.cos(math.pi * progress))


def state_path(out: str | Path) -> Path:
    """Where `fit_prior` keeps its per-epoch training state (removed when training finishes)."""
    out = Path(out)
    return out.with_name(out.name + ".train-state")


def fit_prior(
    scenarios: Sequence[Scenario],
    out: str | Path,
    model_cfg: PriorConfig | None = None,
    train_cfg: TrainConfig | None = None,
    data_info: dict[str, Any] | None = None,
    resume: bool = False,
    progress: bool = True,
    log: Callable[[str], None] = print,
) -> TrajectoryPrior:
    """Train a prior on the targets of ``scenarios``, write the best epoch to ``out`` and return it.

    Args:
        scenarios: training scenarios; ``train_cfg.val_fraction`` of them are held out for validation.
        out: model file, written (atomically) after every epoch that improves validation minADE@6.
        model_cfg: architecture (default `PriorConfig()`).
        train_cfg: training settings (default `TrainConfig()`).
        data_info: recorded in the model's training summary (dataset, split, ...).
        resume: continue from the training state an interrupted run left next to ``out``.
        progress: show a progress bar per epoch.
        log: where per-epoch lines go.
    """
    from tqdm import tqdm

    model_cfg = model_cfg or PriorConfig()
    tc = train_cfg or TrainConfig()
    torch.set_num_threads(tc.threads)
    t_start = time.perf_counter()
    cpu_start = time.process_time()
    train_idx, val_idx = split_validation(len(scenarios), tc.val_fraction, tc.seed)
    train_s = [scenarios[i] for i in train_idx]
    val_s = [scenarios[i] for i in val_idx]
    road = tc.road_chunks if tc.road_weight > 0 else 0
    train_set = build_samples(train_s, model_cfg.features, tc.targets, road_chunks=road)
    val_set = build_samples(val_s, model_cfg.features, tc.targets, road_chunks=road)
    log(
        f"prior: {len(train_s)} training scenarios ({len(train_set)} targets), {len(val_s)} validation scenarios "
        f"({len(val_set)} targets); features built in {time.perf_counter() - t_start:.1f} s"
    )

    torch.manual_seed(tc.seed)
    net = PriorNet(model_cfg)
    limits = (model_cfg.acc_limit_mps2, model_cfg.yaw_rate_limit_rps)
    net.set_anchors(fit_anchors(
        train_set.future, train_set.future_valid, train_set.tables.start, model_cfg.n_modes, model_cfg.n_knots,
        limits, seed=tc.seed, fill=default_anchors(model_cfg),
    ))
    opt = torch.optim.AdamW(net.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    steps_per_epoch = math.ceil(len(train_set) / tc.batch_size)
    st: dict[str, Any] = {
        "epoch": 0, "step": 0, "planned_epochs": tc.epochs, "history": [], "best": None, "best_epoch": 0,
        "bad_epochs": 0, "seconds": 0.0, "stop_reason": None, "initial_train_loss": None,
    }
    best_state: dict[str, torch.Tensor] | None = None
    spath = state_path(out)
    if resume and spath.exists():
        saved = torch.load(spath, map_location="cpu", weights_only=True)
        if saved.get("configs") != [model_cfg.to_dict(), tc.to_dict()]:
            raise ValueError(
                f"training state {spath} was written with another model or training config; run with the same "
                "settings to resume, or delete it to start over"
            )
        net.load_state_dict(saved["model"])
        opt.load_state_dict(saved["optimizer"])
        best_state = saved["best_state"]
        st.update(saved["progress"])
        log(f"prior: resuming after epoch {st['epoch']} from {spath}")
    elif resume:
        log(f"prior: no training state at {spath}; starting from scratch")
    assigned = anchor_assignment(net, train_set) if model_cfg.assignment == "anchor" else None
    if st["initial_train_loss"] is None:
        st["initial_train_loss"] = round(training_loss(net, train_set, tc, assigned), 4)
    budget_s = None if tc.max_minutes is None else 60.0 * tc.max_minutes
    elapsed_before = float(st["seconds"])
    t_run = t_start  # the budget counts data preparation too
    last_state_save = t_run

    def summary() -> dict[str, Any]:
        return {
            "trained": True,
            "data": dict(data_info or {}),
            "train_scenario_ids": [s.scenario_id for s in train_s],
            "val_scenario_ids": [s.scenario_id for s in val_s],
            "n_train_targets": len(train_set),
            "n_val_targets": len(val_set),
            "train_config": tc.to_dict(),
            "initial_train_loss": st["initial_train_loss"],
            "epochs_run": st["epoch"],
            "best_epoch": st["best_epoch"],
            "best_val": st["best"],
            "history": st["history"],
            "stop_reason": st["stop_reason"],
            "seconds": round(elapsed_before + time.perf_counter() - t_run, 1),
            "cpu_seconds_this_run": round(time.process_time() - cpu_start, 1),
            "torch": str(torch.__version__),
        }

    while st["epoch"] < st["planned_epochs"] and st["stop_reason"] is None:
        epoch = st["epoch"] + 1
        t_epoch = time.perf_counter()
        net.train()
        gen = torch.Generator().manual_seed(tc.seed * 1000 + epoch)
        order = torch.randperm(len(train_set), generator=gen)
        total_loss, n_batches = 0.0, 0
        total_steps = st["planned_epochs"] * steps_per_epoch
        bar = tqdm(
            range(steps_per_epoch), desc=f"epoch {epoch}/{st['planned_epochs']}", unit="batch", disable=not progress,
            leave=False,
        )
        for b in bar:
            rows = order[b * tc.batch_size : (b + 1) * tc.batch_size]
            for group in opt.param_groups:
                group["lr"] = tc.lr * _lr_factor(st["step"], tc.warmup_steps, total_steps)
            loss = batch_loss(net, train_set, rows, tc, assigned, gen)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), tc.grad_clip)
            opt.step()
            st["step"] += 1
            total_loss += loss.item()
            n_batches += 1
            if b % 20 == 0:
                bar.set_postfix(loss=f"{total_loss / n_batches:.3f}")
        bar.close()
        val = evaluate_samples(net, val_set)
        epoch_s = time.perf_counter() - t_epoch
        st["epoch"] = epoch
        st["history"].append(
            {"epoch": epoch, "train_loss": round(total_loss / max(1, n_batches), 4), "seconds": round(epoch_s, 1),
             **{f"val_{k}": round(v, 4) for k, v in val.items()}}
        )
        improved = st["best"] is None or val["min_ade_6"] < st["best"]["min_ade_6"]
        if improved:
            st["best"], st["best_epoch"], st["bad_epochs"] = val, epoch, 0
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        else:
            st["bad_epochs"] += 1
        elapsed = elapsed_before + time.perf_counter() - t_run
        st["seconds"] = elapsed
        log(
            f"epoch {epoch}: train loss {total_loss / max(1, n_batches):.3f}, val minADE@1 {val['min_ade_1']:.2f} m, "
            f"minADE@6 {val['min_ade_6']:.2f} m, minFDE@6 {val['min_fde_6']:.2f} m"
            + (f", on road {val['on_road']:.3f}" if "on_road" in val else "")
            + f" ({epoch_s:.0f} s)"
            + (" *" if improved else "")
        )
        if budget_s is not None and epoch == 1 and st["planned_epochs"] > 1:
            fit = max(1, int((budget_s - elapsed) // epoch_s) + 1)  # epochs that fit, this one included
            if fit < st["planned_epochs"]:
                log(f"prior: {fit} epochs fit the {tc.max_minutes:g} min budget; planning {fit} instead of "
                    f"{st['planned_epochs']}")
                st["planned_epochs"] = fit
        if st["bad_epochs"] >= tc.patience:
            st["stop_reason"] = f"early stop: no better validation minADE@6 for {tc.patience} epochs"
        elif budget_s is not None and st["epoch"] < st["planned_epochs"] and elapsed + epoch_s > budget_s:
            st["stop_reason"] = f"time budget of {tc.max_minutes:g} min reached"
        if improved:
            TrajectoryPrior(_net_with(model_cfg, best_state), training=summary()).save(out)
        # Resumable state at most every STATE_EVERY_S: with tiny epochs the writes would cost more than a rerun.
        if time.perf_counter() - last_state_save >= STATE_EVERY_S:
            _save_state(spath, net, opt, best_state, st, [model_cfg.to_dict(), tc.to_dict()])
            last_state_save = time.perf_counter()
    if st["stop_reason"] is None:
        st["stop_reason"] = f"completed {st['epoch']} planned epochs"
    prior = TrajectoryPrior(_net_with(model_cfg, best_state), training=summary())
    prior.save(out)
    spath.unlink(missing_ok=True)
    log(f"prior: {st['stop_reason']}; best epoch {st['best_epoch']} (val minADE@6 "
        f"{st['best']['min_ade_6']:.2f} m); wrote {out} after {st['seconds']:.0f} s "
        f"({time.process_time() - cpu_start:.0f} s CPU)")
    return prior


def _net_with(cfg: PriorConfig, state: dict[str, torch.Tensor] | None) -> PriorNet:
    net = PriorNet(cfg)
    if state is not None:
        net.load_state_dict(state)
    return net


def _save_state(
    path: Path, net: PriorNet, opt: torch.optim.Optimizer, best_state: dict[str, torch.Tensor] | None,
    progress: dict[str, Any], configs: list[dict[str, Any]],
) -> None:
    import io

    from seal.atomic import atomic_write_bytes

    buf = io.BytesIO()
    torch.save(
        {"model": net.state_dict(), "optimizer": opt.state_dict(), "best_state": best_state, "progress": progress,
         "configs": configs},
        buf,
    )
    atomic_write_bytes(path, buf.getvalue())
