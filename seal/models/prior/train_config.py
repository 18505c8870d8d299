"""Training settings of the trajectory prior (recorded in every saved model)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from seal.core.config import check_keys
from seal.models.prior.samples import TargetFilter


@dataclass(frozen=True)
class PriorTrainConfig:
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
    def from_dict(cls, d: dict[str, Any]) -> PriorTrainConfig:
        d = dict(d)
        check_keys(cls, d, "training config")
        targets = d.pop("targets", {})
        if isinstance(targets, dict):
            check_keys(TargetFilter, targets, "training config: targets")
            targets = TargetFilter(**targets)
        return cls(targets=targets, **d)
