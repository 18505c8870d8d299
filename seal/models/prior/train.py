"""Training of the prior (`fit_prior`): data, anchors, optimisation, validation, early stopping, resumption.

The targets of a share of the scenarios (held out by scenario) are the validation set. The mode anchors are the
k-means centres of the training targets' controls (`seal.models.prior.anchors`); the losses are in
`seal.models.prior.losses`. After every epoch validation measures minADE@1 / @6 (and an on-road share); the best epoch
by validation minADE@6 is kept and written, training stops early when it has not improved for ``patience``
epochs, or when the next epoch would overrun the time budget. The training state is saved next to the output
after an epoch (at most every `STATE_EVERY_S`) so an interrupted run resumes with ``resume=True``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.scenario import Scenario
from seal.models.prior.anchors import fit_anchors
from seal.models.prior.losses import anchor_assignment, batch_loss, evaluate_samples, training_loss
from seal.models.prior.network import PriorConfig, PriorNet, default_anchors
from seal.models.prior.prior import TrajectoryPrior
from seal.models.prior.samples import SampleSet, build_samples
from seal.models.prior.train_config import PriorTrainConfig

logger = logging.getLogger(__name__)

STATE_EVERY_S = 30.0  # minimum seconds between two saves of the resumable training state


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


def resumable_state(out: str | Path, model_cfg: PriorConfig, tc: PriorTrainConfig) -> bool:
    """Whether ``out`` has the training state of an interrupted `fit_prior` with these very configs: resuming it
    gives the model an uninterrupted fit gives (the state is saved at epoch ends; each epoch's batch order has its
    own seed). False without a state, with another config's, or with one that does not read back."""
    spath = state_path(out)
    if not spath.exists():
        return False
    try:
        saved = torch.load(spath, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 - a damaged state is one to start over from, never to stop on
        return False
    return bool(saved.get("configs") == [model_cfg.to_dict(), tc.to_dict()])


@dataclass(frozen=True)
class _FitData:
    """The training / validation scenarios of a fit and their samples."""

    train_s: list[Scenario]
    val_s: list[Scenario]
    train_set: SampleSet
    val_set: SampleSet


def _prepare_data(
    scenarios: Sequence[Scenario], model_cfg: PriorConfig, tc: PriorTrainConfig, t_start: float
) -> _FitData:
    """Split off the validation scenarios and build both sample sets."""
    train_idx, val_idx = split_validation(len(scenarios), tc.val_fraction, tc.seed)
    train_s = [scenarios[i] for i in train_idx]
    val_s = [scenarios[i] for i in val_idx]
    road = tc.road_chunks if tc.road_weight > 0 else 0
    train_set = build_samples(train_s, model_cfg.features, tc.targets, road_chunks=road)
    val_set = build_samples(val_s, model_cfg.features, tc.targets, road_chunks=road)
    logger.info(
        f"prior: {len(train_s)} training scenarios ({len(train_set)} targets), {len(val_s)} validation scenarios "
        f"({len(val_set)} targets); features built in {time.perf_counter() - t_start:.1f} s"
    )
    return _FitData(train_s, val_s, train_set, val_set)


def _initial_model(
    model_cfg: PriorConfig, tc: PriorTrainConfig, train_set: SampleSet
) -> tuple[PriorNet, torch.optim.Optimizer]:
    """A fresh network (seeded by ``tc.seed``) with anchors fitted to the training targets, and its optimiser."""
    torch.manual_seed(tc.seed)
    net = PriorNet(model_cfg)
    limits = (model_cfg.acc_limit_mps2, model_cfg.yaw_rate_limit_rps)
    net.set_anchors(fit_anchors(
        train_set.future, train_set.future_valid, train_set.tables.start, model_cfg.n_modes, model_cfg.n_knots,
        limits, seed=tc.seed, fill=default_anchors(model_cfg),
    ))
    opt = torch.optim.AdamW(net.parameters(), lr=tc.lr, weight_decay=tc.weight_decay)
    return net, opt


def _restore_state(
    spath: Path, resume: bool, net: PriorNet, opt: torch.optim.Optimizer, st: dict[str, Any],
    configs: list[dict[str, Any]],
) -> dict[str, torch.Tensor] | None:
    """Load an interrupted run's state into ``net``, ``opt`` and ``st`` (when resuming and it exists); returns the
    best state so far."""
    if resume and spath.exists():
        saved = torch.load(spath, map_location="cpu", weights_only=True)
        if saved.get("configs") != configs:
            raise ValueError(
                f"training state {spath} was written with another model or training config; run with the same "
                "settings to resume, or delete it to start over"
            )
        net.load_state_dict(saved["model"])
        opt.load_state_dict(saved["optimizer"])
        st.update(saved["progress"])
        logger.info(f"prior: resuming after epoch {st['epoch']} from {spath}")
        best: dict[str, torch.Tensor] | None = saved["best_state"]
        return best
    if resume:
        logger.info(f"prior: no training state at {spath}; starting from scratch")
    return None


def _train_epoch(
    net: PriorNet, opt: torch.optim.Optimizer, train_set: SampleSet, tc: PriorTrainConfig,
    assigned: torch.Tensor | None, st: dict[str, Any], epoch: int, progress: bool,
) -> float:
    """One pass over the training samples (order and batch noise from the epoch's seed); advances ``st["step"]``
    and returns the mean batch loss."""
    from tqdm import tqdm

    steps_per_epoch = math.ceil(len(train_set) / tc.batch_size)
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
    return total_loss / max(1, n_batches)


def _log_epoch(epoch: int, train_loss: float, val: dict[str, float], epoch_s: float, improved: bool) -> None:
    logger.info(
        f"epoch {epoch}: train loss {train_loss:.3f}, val minADE@1 {val['min_ade_1']:.2f} m, "
        f"minADE@6 {val['min_ade_6']:.2f} m, minFDE@6 {val['min_fde_6']:.2f} m"
        + (f", on road {val['on_road']:.3f}" if "on_road" in val else "")
        + f" ({epoch_s:.0f} s)"
        + (" *" if improved else "")
    )


def _plan_and_stop(st: dict[str, Any], tc: PriorTrainConfig, epoch: int, elapsed: float, epoch_s: float) -> None:
    """After epoch ``epoch``: shrink the plan to the epochs that fit the time budget (after the first epoch) and set
    ``st["stop_reason"]`` on early stopping or when the next epoch would overrun the budget."""
    budget_s = None if tc.max_minutes is None else 60.0 * tc.max_minutes
    if budget_s is not None and epoch == 1 and st["planned_epochs"] > 1:
        fit = max(1, int((budget_s - elapsed) // epoch_s) + 1)  # epochs that fit, this one included
        if fit < st["planned_epochs"]:
            logger.info(f"prior: {fit} epochs fit the {tc.max_minutes:g} min budget; planning {fit} instead of "
                        f"{st['planned_epochs']}")
            st["planned_epochs"] = fit
    if st["bad_epochs"] >= tc.patience:
        st["stop_reason"] = f"early stop: no better validation minADE@6 for {tc.patience} epochs"
    elif budget_s is not None and st["epoch"] < st["planned_epochs"] and elapsed + epoch_s > budget_s:
        st["stop_reason"] = f"time budget of {tc.max_minutes:g} min reached"


class _PriorFit:
    """One run of `fit_prior`: its data, network, optimiser and progress ``st`` (saved for resumption)."""

    def __init__(
        self, scenarios: Sequence[Scenario], out: str | Path, model_cfg: PriorConfig, tc: PriorTrainConfig,
        data_info: dict[str, Any] | None, resume: bool,
    ) -> None:
        self.out, self.model_cfg, self.tc, self.data_info = out, model_cfg, tc, data_info
        self.t_start = time.perf_counter()
        self.cpu_start = time.process_time()
        self.data = _prepare_data(scenarios, model_cfg, tc, self.t_start)
        self.net, self.opt = _initial_model(model_cfg, tc, self.data.train_set)
        self.st: dict[str, Any] = {
            "epoch": 0, "step": 0, "planned_epochs": tc.epochs, "history": [], "best": None, "best_epoch": 0,
            "bad_epochs": 0, "seconds": 0.0, "stop_reason": None, "initial_train_loss": None,
        }
        self.configs = [model_cfg.to_dict(), tc.to_dict()]
        self.spath = state_path(out)
        self.best_state = _restore_state(self.spath, resume, self.net, self.opt, self.st, self.configs)
        train_set = self.data.train_set
        self.assigned = anchor_assignment(self.net, train_set) if model_cfg.assignment == "anchor" else None
        if self.st["initial_train_loss"] is None:
            self.st["initial_train_loss"] = round(training_loss(self.net, train_set, tc, self.assigned), 4)
        self.elapsed_before = float(self.st["seconds"])
        self.t_run = self.t_start  # the budget counts data preparation too
        self.last_state_save = self.t_run

    def summary(self) -> dict[str, Any]:
        """The training summary stored in the model file."""
        st, data = self.st, self.data
        return {
            "trained": True,
            "data": dict(self.data_info or {}),
            "train_scenario_ids": [s.scenario_id for s in data.train_s],
            "val_scenario_ids": [s.scenario_id for s in data.val_s],
            "n_train_targets": len(data.train_set),
            "n_val_targets": len(data.val_set),
            "train_config": self.tc.to_dict(),
            "initial_train_loss": st["initial_train_loss"],
            "epochs_run": st["epoch"],
            "best_epoch": st["best_epoch"],
            "best_val": st["best"],
            "history": st["history"],
            "stop_reason": st["stop_reason"],
            "seconds": round(self.elapsed_before + time.perf_counter() - self.t_run, 1),
            "cpu_seconds_this_run": round(time.process_time() - self.cpu_start, 1),
            "torch": str(torch.__version__),
        }

    def epoch(self, progress: bool) -> None:
        """Train, validate, record, plan / stop, and save the model (when better) and the resumable state."""
        st = self.st
        epoch = st["epoch"] + 1
        t_epoch = time.perf_counter()
        train_loss = _train_epoch(self.net, self.opt, self.data.train_set, self.tc, self.assigned, st, epoch,
                                  progress)
        val = evaluate_samples(self.net, self.data.val_set)
        epoch_s = time.perf_counter() - t_epoch
        st["epoch"] = epoch
        st["history"].append(
            {"epoch": epoch, "train_loss": round(train_loss, 4), "seconds": round(epoch_s, 1),
             **{f"val_{k}": round(v, 4) for k, v in val.items()}}
        )
        improved = st["best"] is None or val["min_ade_6"] < st["best"]["min_ade_6"]
        if improved:
            st["best"], st["best_epoch"], st["bad_epochs"] = val, epoch, 0
            self.best_state = {k: v.detach().clone() for k, v in self.net.state_dict().items()}
        else:
            st["bad_epochs"] += 1
        elapsed = self.elapsed_before + time.perf_counter() - self.t_run
        st["seconds"] = elapsed
        _log_epoch(epoch, train_loss, val, epoch_s, improved)
        _plan_and_stop(st, self.tc, epoch, elapsed, epoch_s)
        if improved:
            TrajectoryPrior(_net_with(self.model_cfg, self.best_state), training=self.summary()).save(self.out)
        # Resumable state at most every STATE_EVERY_S: with tiny epochs the writes would cost more than a rerun.
        if time.perf_counter() - self.last_state_save >= STATE_EVERY_S:
            _save_state(self.spath, self.net, self.opt, self.best_state, st, self.configs)
            self.last_state_save = time.perf_counter()

    def finish(self) -> TrajectoryPrior:
        """Write the best epoch's model, remove the resumable state and return the model."""
        st = self.st
        if st["stop_reason"] is None and st["planned_epochs"] < self.tc.epochs:
            # the budget cut the plan after the first epoch: say so (the model depends on the machine's speed)
            st["stop_reason"] = (f"time budget of {self.tc.max_minutes:g} min reached: {st['epoch']} of "
                                 f"{self.tc.epochs} epochs planned after the first")
        elif st["stop_reason"] is None:
            st["stop_reason"] = f"completed {st['epoch']} planned epochs"
        prior = TrajectoryPrior(_net_with(self.model_cfg, self.best_state), training=self.summary())
        prior.save(self.out)
        self.spath.unlink(missing_ok=True)
        logger.info(f"prior: {st['stop_reason']}; best epoch {st['best_epoch']} (val minADE@6 "
                    f"{st['best']['min_ade_6']:.2f} m); wrote {self.out} after {st['seconds']:.0f} s "
                    f"({time.process_time() - self.cpu_start:.0f} s CPU)")
        return prior


def fit_prior(
    scenarios: Sequence[Scenario],
    out: str | Path,
    model_cfg: PriorConfig | None = None,
    train_cfg: PriorTrainConfig | None = None,
    data_info: dict[str, Any] | None = None,
    resume: bool = False,
    progress: bool = True,
) -> TrajectoryPrior:
    """Train a prior on the targets of ``scenarios``, write the best epoch to ``out`` and return it. Per-epoch
    lines go to this module's logger (INFO); torch's thread count is the caller's (``train_cfg.threads`` is for the
    entry point to set).

    Args:
        scenarios: training scenarios; ``train_cfg.val_fraction`` of them are held out for validation.
        out: model file, written (atomically) after every epoch that improves validation minADE@6.
        model_cfg: architecture (default `PriorConfig()`).
        train_cfg: training settings (default `PriorTrainConfig()`).
        data_info: recorded in the model's training summary (dataset, split, ...).
        resume: continue from the training state an interrupted run left next to ``out``.
        progress: show a progress bar per epoch.
    """
    run = _PriorFit(scenarios, out, model_cfg or PriorConfig(), train_cfg or PriorTrainConfig(), data_info, resume)
    while run.st["epoch"] < run.st["planned_epochs"] and run.st["stop_reason"] is None:
        run.epoch(progress)
    return run.finish()


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

    from seal.core.atomic import atomic_write_bytes

    buf = io.BytesIO()
    torch.save(
        {"model": net.state_dict(), "optimizer": opt.state_dict(), "best_state": best_state, "progress": progress,
         "configs": configs},
        buf,
    )
    atomic_write_bytes(path, buf.getvalue())
