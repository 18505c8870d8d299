"""Training pi_score on a `LabelSet`: MSE on [f_coll, f_diff] over (previous roll-out, candidate) pairs, plus an
optional listwise ranking loss.

Batches are made of groups: a group is one (scenario s, previous roll-out i) with all its N candidates j, drawn at
random each epoch (``pairs_per_epoch`` / N groups). The loss is the MSE of both heads plus ``rank_weight`` times
a ListNet cross-entropy between the softmax (temperature ``rank_temperature``) of the simulated ``f_coll + f_diff``
over the group's candidates and that of the predicted sum: pi_score is used to rank candidates, and MSE alone
spends its capacity on the near-binary f_diff level rather than on the order. With ``mirror``, half of the groups
are reflected across the x axis (y and headings negated; the labels do not change). Features are computed on the
fly from the stored tracks (`seal.models.objective.features`), so memory stays at the size of the tracks.

A share of the training scenarios (``val_fraction``) is held out by scenario for early stopping and model
selection: with ``select="spearman"`` the kept state is the one with the best mean Spearman correlation of the
predicted sum with the simulated sum over the candidates of the validation groups (the logged-adversary roll-out
and 4 other roll-outs per validation scenario), with ``"mse"`` the one with the lowest validation MSE.

To tell over- from under-fitting, every epoch also records the mean Spearman on as many training scenarios as there
are validation scenarios (groups drawn the same way, with their own random stream so that training is unchanged),
and the fit records closeness's Spearman on both sets of groups once: the ranking pi_score starts from (with
``zero_init``) and has to beat (the scenarios differ, so each Spearman is read against its own closeness).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
import torch

from seal.core.config import check_keys
from seal.models.objective.features import candidate_prior_features
from seal.models.objective.labels import LOGGED_ROW, LabelSet
from seal.models.objective.losses import listnet_loss, pairwise_loss, pearson_rank_loss
from seal.models.objective.metrics import spearman
from seal.models.objective.model import ObjectiveModel
from seal.models.objective.network import ObjectiveConfig, ObjectiveNet
from seal.scoring.criticality import f_coll

logger = logging.getLogger(__name__)

PREV_MODES = ("all", "logged")
"""Which previous roll-outs make training pairs: all M of a scenario, or only the logged-adversary episode."""
SELECT_MODES = ("spearman", "mse")
"""Validation metric of early stopping / model selection."""
RANK_LOSSES = ("listnet", "pairwise", "pearson")
"""Ranking losses within a group of candidates (`listnet_loss`, `pairwise_loss`, `pearson_rank_loss`)."""
VAL_PREVS = 5
"""Previous roll-outs per validation scenario (the logged one and 4 drawn from the candidates' episodes)."""


@dataclass(frozen=True)
class ObjectiveTrainConfig:
    """Optimisation settings (see the module docstring).

    Attributes:
        batch_size: pairs per step (rounded down to whole groups of N candidates, at least one group).
        lr: Adam learning rate; cosine-decayed to 5% over ``max_epochs``.
        weight_decay: AdamW weight decay.
        max_epochs: epochs at most.
        pairs_per_epoch: pairs drawn per epoch (all pairs when larger).
        patience: epochs without validation improvement before stopping.
        max_minutes: wall-clock budget of the training loop (None: none, the epochs and ``patience`` alone decide,
            as on every machine; a budget that ends the fit makes the model depend on the machine's speed and load).
        val_fraction: share of the scenarios held out for early stopping.
        prev: ``"all"`` or ``"logged"`` (`PREV_MODES`).
        rank_weight: weight of the listwise ranking loss next to the MSE (0: MSE only).
        rank_temperature: softmax temperature of the ranking loss (units of f_coll + f_diff).
        rank_loss: ``"listnet"``, ``"pairwise"`` or ``"pearson"`` (`RANK_LOSSES`: `listnet_loss`, `pairwise_loss`,
            `pearson_rank_loss`).
        mirror: reflect a random half of the groups across the x axis (augmentation).
        correction_l2: weight of a penalty on the squared logit corrections of closeness (keeps the outputs
            near closeness unless the labels say otherwise).
        select: validation metric of early stopping (`SELECT_MODES`).
        logged_share: share of each epoch's training groups whose previous roll-out is the logged-adversary
            episode (None: as drawn, 1 in M = N + 1). SEAL's first generation of a scenario ranks against that
            episode alone, and it is the one roll-out whose adversary is not one of the candidates.
        seed: random seed.
    """

    batch_size: int = 512
    lr: float = 2e-3
    weight_decay: float = 1e-4
    max_epochs: int = 20
    pairs_per_epoch: int = 200_000
    patience: int = 4
    max_minutes: float | None = 5.0
    val_fraction: float = 0.1
    prev: str = "all"
    rank_weight: float = 0.0
    rank_temperature: float = 0.1
    rank_loss: str = "listnet"
    mirror: bool = False
    correction_l2: float = 0.0
    select: str = "spearman"
    logged_share: float | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("batch_size", "max_epochs", "pairs_per_epoch", "patience"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"objective training: {name} must be >= 1, got {getattr(self, name)}")
        if not (self.lr > 0 and (self.max_minutes is None or self.max_minutes > 0) and self.weight_decay >= 0):
            raise ValueError("objective training: lr and max_minutes (or null: no budget) must be > 0, weight_decay "
                             ">= 0")
        if not 0.0 < self.val_fraction < 1.0:
            raise ValueError(f"objective training: val_fraction must be in (0, 1), got {self.val_fraction}")
        if self.prev not in PREV_MODES:
            raise ValueError(f"objective training: prev must be one of {PREV_MODES}, got {self.prev!r}")
        if self.select not in SELECT_MODES:
            raise ValueError(f"objective training: select must be one of {SELECT_MODES}, got {self.select!r}")
        if not (self.rank_weight >= 0 and self.rank_temperature > 0):
            raise ValueError("objective training: rank_weight must be >= 0 and rank_temperature > 0")
        if self.logged_share is not None and not 0.0 <= self.logged_share <= 1.0:
            raise ValueError(f"objective training: logged_share must be in [0, 1] or null, got {self.logged_share}")
        if self.rank_loss not in RANK_LOSSES:
            raise ValueError(f"objective training: rank_loss must be one of {RANK_LOSSES}, got {self.rank_loss!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "objective training config") -> ObjectiveTrainConfig:
        check_keys(cls, d, where)
        return cls(**d)


@dataclass
class FitResult:
    """What `train_objective` did: per-epoch ``history`` rows (epoch, train_loss, val_loss = validation MSE,
    val_spearman, train_spearman = the same metric on training scenarios, seconds), the best epoch and its
    validation MSE and Spearman, closeness's Spearman on the validation and on those training scenarios, why it
    stopped and the wall time."""

    history: list[dict[str, float]] = field(default_factory=list)
    best_epoch: int = -1
    best_val: float = float("inf")
    best_val_spearman: float = float("nan")
    val_closeness_spearman: float = float("nan")
    train_closeness_spearman: float = float("nan")
    stop_reason: str = ""
    seconds: float = 0.0


class PairTensors:
    """A `LabelSet` as torch tensors, with the pairs of chosen scenarios and previous roll-outs."""

    def __init__(self, labels: LabelSet) -> None:
        self.cand_xy = torch.as_tensor(labels.cand_xy, dtype=torch.float32)
        self.cand_heading = torch.as_tensor(labels.cand_heading, dtype=torch.float32)
        self.ego_xy = torch.as_tensor(labels.ego_xy, dtype=torch.float32)
        self.ego_heading = torch.as_tensor(labels.ego_heading, dtype=torch.float32)
        self.ego_valid = torch.as_tensor(labels.ego_valid, dtype=torch.bool)
        self.adv_xy = torch.as_tensor(labels.adv_xy, dtype=torch.float32)
        self.adv_valid = torch.as_tensor(labels.adv_valid, dtype=torch.bool)
        self.cand_prior = candidate_prior_features(torch.as_tensor(labels.probs, dtype=torch.float64)).float()
        self.f_coll = torch.as_tensor(labels.f_coll, dtype=torch.float32)
        self.f_diff = torch.as_tensor(labels.f_diff, dtype=torch.float32)
        self.n_prev = labels.ego_xy.shape[1]
        self.n_cand = labels.n_candidates
        self.last_correction = torch.zeros(0, 2)
        """The logit corrections ``[B, 2]`` of the last `batch` (for the penalty)."""

    def pairs(self, scenarios: np.ndarray, prev: str) -> np.ndarray:
        """``[P, 3]`` int64 (scenario, previous roll-out, candidate) of every pair of ``scenarios``; the N
        candidates of one (scenario, previous roll-out) group are consecutive rows."""
        prevs = np.arange(self.n_prev) if prev == "all" else np.array([LOGGED_ROW])
        return self.group_pairs(self.groups(scenarios, prevs))

    @staticmethod
    def groups(scenarios: np.ndarray, prevs: np.ndarray) -> np.ndarray:
        """``[G, 2]`` int64 (scenario, previous roll-out) for every scenario and every row of ``prevs``."""
        s, i = np.meshgrid(scenarios, prevs, indexing="ij")
        return np.stack([s.ravel(), i.ravel()], axis=1).astype(np.int64)

    def group_pairs(self, groups: np.ndarray) -> np.ndarray:
        """``[G * N, 3]`` pairs of the groups ``[G, 2]``, group by group."""
        j = np.tile(np.arange(self.n_cand), len(groups))
        return np.concatenate([np.repeat(groups, self.n_cand, axis=0), j[:, None]], axis=1).astype(np.int64)

    def batch(self, net: ObjectiveNet, idx: np.ndarray, flip: np.ndarray | None = None
              ) -> tuple[torch.Tensor, torch.Tensor]:
        """Predictions and targets ``[B, 2]`` of the pairs ``idx [B, 3]``; pairs where ``flip [B]`` (bool) are
        mirrored across the x axis first."""
        s, i, j = (torch.as_tensor(idx[:, c]) for c in range(3))
        cand_xy, cand_h = self.cand_xy[s, j], self.cand_heading[s, j]
        ego_xy, ego_h, adv_xy = self.ego_xy[s, i], self.ego_heading[s, i], self.adv_xy[s, i]
        if flip is not None:
            sign = torch.where(torch.as_tensor(flip), -1.0, 1.0)
            mirror = torch.stack([torch.ones_like(sign), sign], dim=-1)[:, None]
            cand_xy, ego_xy, adv_xy = cand_xy * mirror, ego_xy * mirror, adv_xy * mirror
            cand_h, ego_h = cand_h * sign[:, None], ego_h * sign[:, None]
        pred, correction = net.score_pairs(cand_xy, cand_h, ego_xy, ego_h, self.ego_valid[s, i], with_correction=True,
                                           adv_xy=adv_xy, adv_valid=self.adv_valid[s, i],
                                           cand_prior=self.cand_prior[s, j])
        target = torch.stack([self.f_coll[s, j], self.f_diff[s, i, j]], dim=-1)
        self.last_correction = correction
        return pred, target


def predict_pairs(model: ObjectiveModel, tensors: PairTensors, idx: np.ndarray, batch_size: int = 4096
                  ) -> np.ndarray:
    """``[P, 2]`` predictions for the pairs ``idx [P, 3]`` (no gradient)."""
    out = []
    with torch.inference_mode():
        for start in range(0, len(idx), batch_size):
            pred, _ = tensors.batch(model.net, idx[start : start + batch_size])
            out.append(pred.numpy())
    return np.concatenate(out) if out else np.zeros((0, 2))


def _validate(net: ObjectiveNet, tensors: PairTensors, idx: np.ndarray, batch_size: int = 4096
              ) -> tuple[float, float]:
    """Validation MSE and mean Spearman over the groups of ``idx`` (whole groups, group by group)."""
    if len(idx) == 0:
        return float("nan"), float("nan")
    preds, targets = [], []
    with torch.inference_mode():
        for start in range(0, len(idx), batch_size):
            pred, target = tensors.batch(net, idx[start : start + batch_size])
            preds.append(pred.numpy())
            targets.append(target.numpy())
    pred_all, target_all = np.concatenate(preds), np.concatenate(targets)
    mse = float(((pred_all - target_all) ** 2).mean())
    n = tensors.n_cand
    rho = spearman(pred_all.sum(-1).reshape(-1, n), target_all.sum(-1).reshape(-1, n))
    return mse, float(rho.mean())


def validation_groups(tensors: PairTensors, scenarios: np.ndarray, prev: str, rng: np.random.Generator
                      ) -> np.ndarray:
    """``[G, 2]`` validation groups: per scenario the logged-adversary roll-out and (with ``prev="all"``) 4
    others drawn from the candidates' episodes."""
    if prev == "logged" or tensors.n_prev < 2:
        return tensors.groups(scenarios, np.array([LOGGED_ROW]))
    k = min(VAL_PREVS, tensors.n_prev) - 1
    rows = [np.r_[LOGGED_ROW, 1 + rng.choice(tensors.n_prev - 1, k, replace=False)] for _ in scenarios]
    return np.stack([np.repeat(scenarios, k + 1), np.concatenate(rows)], axis=1).astype(np.int64)


@dataclass(frozen=True)
class _FitData:
    """The scenario split of one fit and its training groups / validation pairs."""

    tensors: PairTensors
    train_s: np.ndarray
    val_s: np.ndarray
    train_groups: np.ndarray
    val_pairs: np.ndarray
    train_check_pairs: np.ndarray


def _split(labels: LabelSet, cfg: ObjectiveTrainConfig, rng: np.random.Generator) -> _FitData:
    """Hold out ``cfg.val_fraction`` of the scenarios (at least one, at most all but one) and build the groups."""
    order = rng.permutation(labels.n_scenarios)
    n_val = min(max(1, round(cfg.val_fraction * labels.n_scenarios)), labels.n_scenarios - 1)
    val_s, train_s = np.sort(order[:n_val]), np.sort(order[n_val:])
    tensors = PairTensors(labels)
    prevs = np.arange(tensors.n_prev) if cfg.prev == "all" else np.array([LOGGED_ROW])
    train_groups = tensors.groups(train_s, prevs)
    val_pairs = tensors.group_pairs(validation_groups(tensors, val_s, cfg.prev, rng))
    # Its own random stream: drawing these from ``rng`` would change every later draw, and so the fit.
    check_rng = np.random.default_rng([cfg.seed, 1])
    check_s = np.sort(check_rng.choice(train_s, min(len(train_s), len(val_s)), replace=False))
    check_pairs = tensors.group_pairs(validation_groups(tensors, check_s, cfg.prev, check_rng))
    return _FitData(tensors, train_s, val_s, train_groups, val_pairs, check_pairs)


def closeness_spearman(labels: LabelSet, pairs: np.ndarray) -> float:
    """Mean Spearman of closeness (``exp(-min_t d / 8)`` between candidate and previous roll-out: f_coll if the
    ego did not react, `seal.scoring.criticality.f_coll`) with the simulated ``f_coll + f_diff``, over the groups of
    ``pairs [G * N, 3]`` (whole groups, group by group, as `_validate`)."""
    if len(pairs) == 0:
        return float("nan")
    s, i, j = (pairs[:, c] for c in range(3))
    close = f_coll(labels.ego_xy[s, i], labels.cand_xy[s, j], valid=labels.ego_valid[s, i])
    target = labels.f_coll[s, j] + labels.f_diff[s, i, j]
    n = labels.n_candidates
    return float(spearman(close.reshape(-1, n), target.reshape(-1, n)).mean())


@dataclass(frozen=True)
class _Schedule:
    """Groups per optimiser step, groups drawn per epoch and steps per epoch."""

    groups_per_batch: int
    n_per_epoch: int
    steps_per_epoch: int

    @classmethod
    def of(cls, cfg: ObjectiveTrainConfig, n_cand: int, n_groups: int) -> _Schedule:
        groups_per_batch = max(1, cfg.batch_size // n_cand)
        n_per_epoch = min(max(1, cfg.pairs_per_epoch // n_cand), n_groups)
        return cls(groups_per_batch, n_per_epoch, max(1, -(-n_per_epoch // groups_per_batch)))


def _batch_loss(net: ObjectiveNet, tensors: PairTensors, groups: np.ndarray, cfg: ObjectiveTrainConfig,
                rng: np.random.Generator) -> tuple[torch.Tensor, int]:
    """The training loss of the pairs of ``groups`` (mirrored at random with ``cfg.mirror``) and their count."""
    n_cand = tensors.n_cand
    idx = tensors.group_pairs(groups)
    flip = np.repeat(rng.random(len(groups)) < 0.5, n_cand) if cfg.mirror else None
    pred, target = tensors.batch(net, idx, flip)
    loss = ((pred - target) ** 2).mean()
    if cfg.correction_l2 > 0:
        loss = loss + cfg.correction_l2 * (tensors.last_correction ** 2).mean()
    if cfg.rank_weight > 0:
        rank = {"listnet": listnet_loss, "pairwise": pairwise_loss, "pearson": pearson_rank_loss}[cfg.rank_loss]
        loss = loss + cfg.rank_weight * rank(pred, target, n_cand, cfg.rank_temperature)
    return loss, len(idx)


def _epoch_groups(groups: np.ndarray, n: int, logged_share: float | None, rng: np.random.Generator) -> np.ndarray:
    """Indices of the ``n`` training groups of one epoch, in random order: a random sample of ``groups [G, 2]``, or
    with ``logged_share`` that share of them from the logged-adversary groups (drawn again when there are fewer)
    and the rest from the others."""
    if logged_share is None:
        return rng.permutation(len(groups))[:n]
    logged = np.flatnonzero(groups[:, 1] == LOGGED_ROW)
    other = np.flatnonzero(groups[:, 1] != LOGGED_ROW)
    n_logged = n if other.size == 0 else 0 if logged.size == 0 else round(logged_share * n)
    pick = np.concatenate([rng.choice(logged, n_logged, replace=n_logged > logged.size),
                           rng.choice(other, min(n - n_logged, other.size), replace=False)])
    return pick[rng.permutation(len(pick))]


def _train_epoch(
    net: ObjectiveNet, opt: torch.optim.Optimizer, sched: torch.optim.lr_scheduler.LRScheduler, data: _FitData,
    cfg: ObjectiveTrainConfig, schedule: _Schedule, rng: np.random.Generator, epoch: int,
    on_step: Callable[[int, int, int], None] | None, start: float,
) -> tuple[float, bool]:
    """One epoch over ``schedule.n_per_epoch`` random training groups; returns the mean pair loss and whether the
    time budget ran out (the epoch then ends early)."""
    net.train()
    pick = _epoch_groups(data.train_groups, schedule.n_per_epoch, cfg.logged_share, rng)
    total, seen = 0.0, 0
    steps, per_batch = schedule.steps_per_epoch, schedule.groups_per_batch
    for step in range(steps):
        groups = data.train_groups[pick[step * per_batch : (step + 1) * per_batch]]
        if len(groups) == 0:
            break
        loss, n_pairs = _batch_loss(net, data.tensors, groups, cfg, rng)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        total += float(loss.detach()) * n_pairs
        seen += n_pairs
        if on_step is not None:
            on_step(epoch, step, steps)
        if cfg.max_minutes is not None and time.perf_counter() - start > 60.0 * cfg.max_minutes:
            return total / max(seen, 1), True
    return total / max(seen, 1), False


FIT_MARGIN = 0.01
"""Spearman difference from closeness below which `fit_diagnosis` calls a fit "no better than closeness"."""


def fit_diagnosis(result: FitResult, margin: float = FIT_MARGIN, whole_pool: bool = False) -> str:
    """One sentence on how the fit compares with closeness, the ranking it starts from (with ``zero_init``):
    better on validation scenarios; better only on training scenarios (over-fitting: more scenarios or a smaller
    model); or no better even on training scenarios (under-fitting: more epochs or capacity). Each Spearman is read
    against closeness on the same scenarios (`FitResult`). ``whole_pool``: the fit already trained on every
    scenario outside the held-out groups (``--split all-but-eval``), so more scenarios means a bigger pool."""
    train_gain = max((float(r["train_spearman"]) - result.train_closeness_spearman for r in result.history),
                     default=float("nan"))
    val_gain = result.best_val_spearman - result.val_closeness_spearman
    if not (np.isfinite(train_gain) and np.isfinite(val_gain)):
        return "no diagnosis: the fit recorded no Spearman against closeness"
    if val_gain > margin:
        return f"ranks validation scenarios better than closeness ({val_gain:+.3f})"
    if train_gain > margin:
        more = ("a bigger scenario pool (the fit already uses every scenario outside the held-out groups; "
                "seal data generate --n)" if whole_pool else "more training scenarios (e.g. --split all-but-eval: "
                "every scenario outside the held-out groups)")
        return (f"over-fits: up to {train_gain:+.3f} over closeness on training scenarios, {val_gain:+.3f} on "
                f"validation ones; {more} or a smaller model (model.hidden, model.dropout)")
    return (f"learns nothing beyond closeness, even on training scenarios (at best {train_gain:+.3f}; validation "
            f"{val_gain:+.3f}): more epochs or capacity (train.max_epochs, train.pairs_per_epoch, model.hidden)")


def _fit_info(cfg: ObjectiveTrainConfig, result: FitResult, data: _FitData) -> dict[str, Any]:
    """The training record stored with the model."""
    return {"train": cfg.to_dict(), "fit": {"best_epoch": result.best_epoch, "best_val_mse": result.best_val,
                                            "best_val_spearman": result.best_val_spearman,
                                            "val_closeness_spearman": result.val_closeness_spearman,
                                            "train_closeness_spearman": result.train_closeness_spearman,
                                            "stop_reason": result.stop_reason, "seconds": result.seconds,
                                            "epochs": len(result.history), "diagnosis": fit_diagnosis(result)},
            "train_scenarios": int(data.train_s.size), "val_scenarios": int(data.val_s.size)}


def train_objective(
    labels: LabelSet,
    model_config: ObjectiveConfig | None = None,
    config: ObjectiveTrainConfig | None = None,
    on_step: Callable[[int, int, float], None] | None = None,
) -> tuple[ObjectiveModel, FitResult]:
    """Train a fresh pi_score on ``labels`` (see the module docstring); one INFO line per epoch to this module's
    logger.

    Args:
        labels: training scenarios (at least 2: one is held out for validation).
        model_config: architecture; ``n_steps`` is taken from the labels.
        config: optimisation settings.
        on_step: called after every optimiser step with (epoch, step in epoch, steps per epoch) for progress.
    """
    cfg = config or ObjectiveTrainConfig()
    if labels.n_scenarios < 2:
        raise ValueError(f"objective training needs at least 2 labelled scenarios, got {labels.n_scenarios}")
    mcfg = replace(model_config or ObjectiveConfig(), n_steps=labels.n_steps)
    rng = np.random.default_rng(cfg.seed)
    torch.manual_seed(cfg.seed)
    data = _split(labels, cfg, rng)
    net = ObjectiveNet(mcfg)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    schedule = _Schedule.of(cfg, data.tensors.n_cand, len(data.train_groups))
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.max_epochs * schedule.steps_per_epoch,
                                                       eta_min=0.05 * cfg.lr)
    result = FitResult()
    best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
    best_key = -float("inf")
    start = time.perf_counter()
    bad = 0
    result.val_closeness_spearman = closeness_spearman(labels, data.val_pairs)
    result.train_closeness_spearman = closeness_spearman(labels, data.train_check_pairs)
    for epoch in range(cfg.max_epochs):
        train_loss, out_of_time = _train_epoch(net, opt, sched, data, cfg, schedule, rng, epoch, on_step, start)
        net.eval()
        val, val_rho = _validate(net, data.tensors, data.val_pairs)
        _, train_rho = _validate(net, data.tensors, data.train_check_pairs)
        row = {"epoch": epoch, "train_loss": train_loss, "val_loss": val, "val_spearman": val_rho,
               "train_spearman": train_rho, "seconds": round(time.perf_counter() - start, 1)}
        result.history.append(row)
        logger.info(f"objective epoch {epoch}: train loss {row['train_loss']:.5f}, val MSE {val:.5f}, val Spearman "
                    f"{val_rho:.4f} (closeness {result.val_closeness_spearman:.4f}), on training scenarios "
                    f"{train_rho:.4f} (closeness {result.train_closeness_spearman:.4f}) ({row['seconds']} s)")
        key = val_rho if cfg.select == "spearman" else -val
        if key > best_key:
            best_key, result.best_val, result.best_val_spearman, result.best_epoch, bad = key, val, val_rho, epoch, 0
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        else:
            bad += 1
        if out_of_time:
            result.stop_reason = f"time budget {cfg.max_minutes} min"
            break
        if bad >= cfg.patience:
            result.stop_reason = f"no validation improvement for {cfg.patience} epochs"
            break
    else:
        result.stop_reason = f"max_epochs {cfg.max_epochs}"
    net.load_state_dict(best_state)
    net.eval()
    result.seconds = round(time.perf_counter() - start, 1)
    return ObjectiveModel(mcfg, net, _fit_info(cfg, result, data)), result
