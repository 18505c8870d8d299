"""Training loops of the skill VAE and of the state-conditioned priors.

Both use AdamW on shuffled mini-batches, evaluate on held-out windows before training and after every epoch, keep
the best epoch (lowest validation loss; epoch 0 = the starting weights, which matters when fine-tuning), stop
early after ``patience`` epochs without improvement or when the next epoch would overrun ``max_minutes``, and
write one CSV row per epoch (atomically rewritten, so it can be watched).

The VAE trains on windows gathered from the demonstration rows (`seal.models.skills.demos.gather_windows`); the priors
train on the VAE's posterior means of benign or adversarial windows, conditioned on each window's first
observation (thesis 6.3.2: the priors are fitted after, and separately from, the shared VAE).
"""

from __future__ import annotations

import csv
import io
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.atomic import atomic_write_bytes
from seal.core.config import check_keys
from seal.models.skills.demos import gather_windows
from seal.models.skills.realnvp import ConditionalRealNVP
from seal.models.skills.vae import SkillVAE

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class SkillTrainConfig:
    """Optimisation settings of one model.

    Attributes:
        batch_size: windows per step.
        lr: AdamW learning rate.
        weight_decay: AdamW weight decay.
        max_epochs: epochs at most.
        epoch_windows: training windows drawn (without replacement) per epoch; None = all of them.
        patience: epochs without a better validation loss before stopping.
        max_minutes: wall-clock budget (None: none); no epoch starts that would overrun it.
        grad_clip: gradient-norm clip.
        seed: initialisation and shuffling seed.
    """

    batch_size: int = 256
    lr: float = 1e-3
    weight_decay: float = 1e-5
    max_epochs: int = 30
    epoch_windows: int | None = None
    patience: int = 4
    max_minutes: float | None = None
    grad_clip: float = 5.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("batch_size", "max_epochs", "patience"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"training config: {name} must be >= 1, got {getattr(self, name)}")
        if self.lr <= 0:
            raise ValueError(f"training config: lr must be > 0, got {self.lr}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "training config") -> SkillTrainConfig:
        check_keys(cls, d, where)
        return cls(**d)


@dataclass
class FitResult:
    """Outcome of a training run: per-epoch rows, best epoch and its validation loss, why it stopped, seconds."""

    history: list[dict[str, float]]
    best_epoch: int
    best_val: float
    stop_reason: str
    seconds: float


def _write_csv(path: Path | None, rows: list[dict[str, float | str]]) -> None:
    if path is None or not rows:
        return
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(path, buf.getvalue().encode())


def _train_epoch(
    model: torch.nn.Module, opt: torch.optim.Optimizer, order: np.ndarray, n_batches: int,
    batch_loss: Callable[[np.ndarray], tuple[torch.Tensor, dict[str, float]]], cfg: SkillTrainConfig, bar_desc: str,
    progress: bool,
) -> dict[str, float]:
    """One pass over the training indices ``order`` in ``n_batches`` batches; returns the summed losses (``"loss"``
    and each part of ``batch_loss``)."""
    from tqdm import tqdm

    model.train()
    sums: dict[str, float] = {}
    bar = tqdm(range(n_batches), desc=bar_desc, unit="batch", disable=not progress, leave=False)
    for b in bar:
        idx = order[b * cfg.batch_size : (b + 1) * cfg.batch_size]
        if idx.size == 0:
            continue
        loss, parts = batch_loss(idx)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        sums["loss"] = sums.get("loss", 0.0) + loss.item()
        for k, v in parts.items():
            sums[k] = sums.get(k, 0.0) + v
        if b % 20 == 0:
            bar.set_postfix(loss=f"{sums['loss'] / (b + 1):.4f}")
    bar.close()
    return sums


def _validated(model: torch.nn.Module, validate: Callable[[], dict[str, float]]) -> dict[str, float]:
    """``validate()`` with ``model`` in eval mode and without gradients."""
    model.eval()
    with torch.no_grad():
        return validate()


STATE_FORMAT = "seal-skill-fit-state"


def _save_state(path: Path, key: str, epoch: int, model: torch.nn.Module, opt: torch.optim.Optimizer,
                rng: np.random.Generator, history: list[dict[str, float]], progress: dict[str, Any],
                elapsed_s: float) -> None:
    """Everything `fit_loop` needs to go on after ``epoch`` exactly as if it had not stopped (atomic write);
    ``progress``: best validation loss, best epoch, epochs without improvement, best weights, and why the loop
    stopped after this epoch (None: it goes on)."""
    state = {"format": STATE_FORMAT, "key": key, "epoch": epoch, "model": model.state_dict(),
             "optimizer": opt.state_dict(), "numpy_rng": rng.bit_generator.state, "torch_rng": torch.get_rng_state(),
             "history": history, "progress": progress, "elapsed_s": elapsed_s}
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())


def _load_state(path: Path | None, key: str) -> dict[str, Any] | None:
    """The state `_save_state` left at ``path`` for the same ``key`` (data and settings), else None."""
    if path is None or not path.is_file():
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # a foreign or damaged file: train from the start (it is overwritten)
        logger.warning(f"{path} does not load ({type(exc).__name__}): training from the first epoch")
        return None
    if not isinstance(state, dict) or state.get("format") != STATE_FORMAT or state.get("key") != key:
        logger.info(f"{path} is the state of other data or settings: training from the first epoch")
        return None
    return state


def _start(model: torch.nn.Module, opt: torch.optim.Optimizer, rng: np.random.Generator,
           validate: Callable[[], dict[str, float]], saved: dict[str, Any] | None, desc: str
           ) -> tuple[list[dict[str, float]], dict[str, Any], float]:
    """Where `fit_loop` starts: from ``saved`` (its state after an epoch: weights, optimiser and generators are
    restored in place) or afresh (epoch 0's validation of the starting weights). Returns the history, the progress
    (`_save_state`) and the seconds already used."""
    if saved is None:
        t0 = time.perf_counter()
        val0 = _validated(model, validate)
        logger.info(f"{desc} epoch 0: val loss {val0['loss']:.4f} (starting weights)")
        progress = {"best_val": val0["loss"], "best_epoch": 0, "bad": 0, "stop": None,
                    "best_state": {k: v.detach().clone() for k, v in model.state_dict().items()}}
        return ([{"epoch": 0, **{f"val_{k}": round(v, 6) for k, v in val0.items()}}], progress,
                time.perf_counter() - t0)
    model.load_state_dict(saved["model"])
    opt.load_state_dict(saved["optimizer"])
    rng.bit_generator.state = saved["numpy_rng"]
    torch.set_rng_state(saved["torch_rng"])
    logger.info(f"{desc}: going on after epoch {saved['epoch']} (saved state)")
    return list(saved["history"]), dict(saved["progress"]), float(saved["elapsed_s"])


def fit_loop(
    model: torch.nn.Module,
    n_train: int,
    batch_loss: Callable[[np.ndarray], tuple[torch.Tensor, dict[str, float]]],
    validate: Callable[[], dict[str, float]],
    cfg: SkillTrainConfig,
    csv_path: str | Path | None = None,
    desc: str = "train",
    progress: bool = True,
    state_path: str | Path | None = None,
    state_key: str = "",
) -> FitResult:
    """Generic loop: ``batch_loss(indices)`` over shuffled training indices ``0..n_train-1``, ``validate()``
    returning a dict with ``"loss"`` (lower is better) after each epoch; the best weights are restored at the end.
    One INFO line per epoch goes to this module's logger.

    With ``state_path`` the loop's whole state (weights, optimiser, both random generators, history, best epoch,
    time used) is written there after every epoch, and a loop started with a state of the same ``state_key`` (a
    fingerprint of the data and settings) goes on after that epoch: an interrupted fit ends with the weights an
    uninterrupted one reaches. The caller removes the file once it has saved the model."""
    if n_train < 1:
        raise ValueError(f"{desc}: no training windows")
    torch.manual_seed(cfg.seed)
    rng = np.random.default_rng(cfg.seed)
    opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=cfg.lr,
                            weight_decay=cfg.weight_decay)
    per_epoch = n_train if cfg.epoch_windows is None else min(n_train, int(cfg.epoch_windows))
    n_batches = max(1, math.ceil(per_epoch / cfg.batch_size))
    budget = None if cfg.max_minutes is None else 60.0 * cfg.max_minutes
    csv_file = None if csv_path is None else Path(csv_path)
    state_file = None if state_path is None else Path(state_path)
    history, done, elapsed_s = _start(model, opt, rng, validate, _load_state(state_file, state_key), desc)
    t0 = time.perf_counter() - elapsed_s
    best_val, best_epoch, bad, best_state = done["best_val"], done["best_epoch"], done["bad"], done["best_state"]
    stop = done["stop"] or f"completed {cfg.max_epochs} epochs"
    # a loop that had stopped has nothing left to train
    first = cfg.max_epochs + 1 if done["stop"] is not None else int(history[-1]["epoch"]) + 1
    for epoch in range(first, cfg.max_epochs + 1):
        t_epoch = time.perf_counter()
        order = rng.permutation(n_train)[:per_epoch]
        sums = _train_epoch(model, opt, order, n_batches, batch_loss, cfg, f"{desc} {epoch}/{cfg.max_epochs}",
                            progress)
        val = _validated(model, validate)
        epoch_s = time.perf_counter() - t_epoch
        row = {"epoch": epoch, **{f"train_{k}": round(v / n_batches, 6) for k, v in sums.items()},
               **{f"val_{k}": round(v, 6) for k, v in val.items()}, "seconds": round(epoch_s, 2)}
        history.append(row)
        blank: dict[str, float | str] = dict.fromkeys(row, "")  # epoch 0 has no train columns
        rows: list[dict[str, float | str]] = [{**blank, **r} for r in history]
        _write_csv(csv_file, rows)
        improved = val["loss"] < best_val
        if improved:
            best_val, best_epoch, bad = val["loss"], epoch, 0
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
        else:
            bad += 1
        logger.info(f"{desc} epoch {epoch}: train loss {row['train_loss']:.4f}, val loss {val['loss']:.4f} "
                    f"({epoch_s:.1f} s)" + (" *" if improved else ""))
        elapsed = time.perf_counter() - t0
        ended = None
        if bad >= cfg.patience:
            ended = f"early stop: no better validation loss for {cfg.patience} epochs"
        elif budget is not None and epoch < cfg.max_epochs and elapsed + epoch_s > budget:
            ended = f"time budget of {cfg.max_minutes:g} min reached"
        if state_file is not None:
            _save_state(state_file, state_key, epoch, model, opt, rng, history,
                        {"best_val": best_val, "best_epoch": best_epoch, "bad": bad, "best_state": best_state,
                         "stop": ended}, elapsed)
        if ended is not None:
            stop = ended
            break
    model.load_state_dict(best_state)
    model.eval()
    return FitResult(history, best_epoch, best_val, stop, round(time.perf_counter() - t0, 2))


def _windows(obs: np.ndarray, actions: np.ndarray, rows: np.ndarray, horizon: int) -> tuple[torch.Tensor,
                                                                                            torch.Tensor]:
    o, a = gather_windows(obs, actions, rows, horizon)
    return torch.from_numpy(o), torch.from_numpy(a)


def fit_norm_from_rows(vae: SkillVAE, obs: np.ndarray, actions: np.ndarray, rows: np.ndarray,
                       max_windows: int = 20000, seed: int = 0) -> None:
    """Fit the VAE's standardisation on (a sample of) the steps of the training windows."""
    rng = np.random.default_rng(seed)
    pick = rows if rows.size <= max_windows else rng.choice(rows, max_windows, replace=False)
    o, a = gather_windows(obs, actions, pick, vae.config.horizon)
    vae.fit_norm(o.reshape(-1, o.shape[-1]), a.reshape(-1, a.shape[-1]))


def train_vae(
    vae: SkillVAE, obs: np.ndarray, actions: np.ndarray, train_rows: np.ndarray, val_rows: np.ndarray,
    cfg: SkillTrainConfig, csv_path: str | Path | None = None, progress: bool = True,
    state_path: str | Path | None = None, state_key: str = "",
) -> FitResult:
    """Train ``vae`` on windows starting at ``train_rows`` of the demonstration rows ``obs [M, D]`` /
    ``actions [M, 2]``; validation loss = recon (posterior mean) + beta KL on ``val_rows``. ``state_path``,
    ``state_key``: per-epoch state to go on from (`fit_loop`)."""
    h = vae.config.horizon
    fit_norm_from_rows(vae, obs, actions, train_rows, seed=cfg.seed)
    val_o, val_a = _windows(obs, actions, val_rows, h)

    def batch_loss(idx: np.ndarray) -> tuple[torch.Tensor, dict[str, float]]:
        o, a = _windows(obs, actions, train_rows[idx], h)
        return vae.loss(o, a)

    def validate() -> dict[str, float]:
        rec, kl = 0.0, 0.0
        for s in range(0, val_o.shape[0], 2048):
            o, a = val_o[s : s + 2048], val_a[s : s + 2048]
            recon, mu, logvar = vae(o, a, sample=False)
            rec += float(vae.recon_error(recon, a).sum())
            kl += float(vae.kl(mu, logvar).sum())
        n = max(1, val_o.shape[0])
        return {"loss": (rec + vae.config.beta * kl) / n, "recon": rec / n, "kl": kl / n}

    return fit_loop(vae, train_rows.size, batch_loss, validate, cfg, csv_path, "vae", progress, state_path, state_key)


@torch.no_grad()
def encode_windows(vae: SkillVAE, obs: np.ndarray, actions: np.ndarray, rows: np.ndarray,
                   batch_size: int = 4096) -> np.ndarray:
    """Posterior means ``[N, latent_dim]`` float32 of the windows starting at ``rows``."""
    vae.eval()
    out = np.empty((rows.size, vae.config.latent_dim), dtype=np.float32)
    for s in range(0, rows.size, batch_size):
        o, a = _windows(obs, actions, rows[s : s + batch_size], vae.config.horizon)
        out[s : s + batch_size] = vae.encode(o, a)[0].numpy()
    return out


def train_prior(
    prior: ConditionalRealNVP, z_train: np.ndarray, cond_train: np.ndarray, z_val: np.ndarray, cond_val: np.ndarray,
    cfg: SkillTrainConfig, csv_path: str | Path | None = None, progress: bool = True, desc: str = "prior",
    fit_norm: bool = True, state_path: str | Path | None = None, state_key: str = "",
) -> FitResult:
    """Fit ``prior`` by maximum likelihood of latents ``z [N, L]`` given states ``cond [N, D]``; the loss is the
    mean negative log-likelihood (nats per window). ``fit_norm`` False keeps the prior's standardisation (when
    fine-tuning a trained prior: refitting it would change the function being fine-tuned). ``state_path``,
    ``state_key``: per-epoch state to go on from (`fit_loop`)."""
    if fit_norm:
        prior.fit_norm(z_train, cond_train)
    zt, ct = torch.as_tensor(z_train, dtype=torch.float32), torch.as_tensor(cond_train, dtype=torch.float32)
    zv, cv = torch.as_tensor(z_val, dtype=torch.float32), torch.as_tensor(cond_val, dtype=torch.float32)

    def batch_loss(idx: np.ndarray) -> tuple[torch.Tensor, dict[str, float]]:
        i = torch.from_numpy(idx)
        return -prior.log_prob(zt[i], ct[i]).mean(), {}

    def validate() -> dict[str, float]:
        return {"loss": float(-prior.log_prob(zv, cv).mean())} if zv.shape[0] else {"loss": math.inf}

    return fit_loop(prior, zt.shape[0], batch_loss, validate, cfg, csv_path, desc, progress, state_path, state_key)
