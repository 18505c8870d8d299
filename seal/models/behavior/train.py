"""The two training stages of the behaviour embedding (thesis 7.3.3, 7.3.4, constants of 7.5.2 as defaults).

* `pretrain`: ``L = L_recon + lambda L_ProtoNCE`` (eq. 7.5) over everyday behaviours with SafeShift labels, every
  parameter but the LoRA adapter trained; ``contrastive=False`` trains ``L_recon`` alone (the "No CL" ablation).
* `finetune`: every parameter frozen but the adapter A, B; ``L_ProtoNCE`` alone on the crash set.

Prototypes are recomputed once per epoch over all current embeddings of the stage's data (`update_prototypes`);
fine-tuning starts from the pre-training prototypes and keeps smoothing them with momentum.
"""

from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from seal.core.config import check_keys
from seal.models.behavior.features import BehaviorInputs
from seal.models.behavior.losses import Prototypes, proto_nce, recon_loss, update_prototypes
from seal.models.behavior.network import BehaviorNet

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class BehaviorTrainConfig:
    """Training settings of both stages.

    Attributes:
        epochs: pre-training epochs.
        batch_size: pre-training batch size.
        lr: pre-training Adam learning rate.
        weight_decay: AdamW weight decay.
        contrastive: add ``lambda L_ProtoNCE`` in pre-training (False: the "No CL" ablation).
        lam: lambda of eq. 7.5 (thesis 10).
        tau: contrastive temperature of eq. 7.2 (thesis 0.05).
        eta: prototype momentum (thesis 0.8).
        alpha: concentration smoothing of eq. 7.4 (thesis 10).
        finetune_epochs: fine-tuning epochs on the crash set.
        finetune_batch_size: fine-tuning batch size.
        finetune_lr: fine-tuning learning rate of A, B.
        max_minutes: wall-clock cap of each stage (min; None: none, the epochs alone decide, as on every machine;
            a cap that ends a stage makes the embedding depend on the machine's speed and load).
        seed: torch seed (initialisation and batch order).
    """

    epochs: int = 20
    batch_size: int = 128
    lr: float = 1e-3
    weight_decay: float = 1e-4
    contrastive: bool = True
    lam: float = 10.0
    tau: float = 0.05
    eta: float = 0.8
    alpha: float = 10.0
    finetune_epochs: int = 30
    finetune_batch_size: int = 64
    finetune_lr: float = 1e-3
    max_minutes: float | None = 30.0
    seed: int = 0

    def __post_init__(self) -> None:
        for key in ("epochs", "batch_size", "finetune_epochs", "finetune_batch_size"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"behaviour training: field {key!r} must be >= 1, got {getattr(self, key)}")
        for key in ("lr", "finetune_lr", "tau") + (() if self.max_minutes is None else ("max_minutes",)):
            if not float(getattr(self, key)) > 0:
                raise ValueError(f"behaviour training: field {key!r} must be > 0, got {getattr(self, key)}")
        if not 0.0 <= self.eta < 1.0 or self.alpha < 0 or self.lam < 0 or self.weight_decay < 0:
            raise ValueError("behaviour training: need 0 <= eta < 1 and alpha, lam, weight_decay >= 0, got "
                             f"eta={self.eta}, alpha={self.alpha}, lam={self.lam}, weight_decay={self.weight_decay}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "behaviour training config") -> BehaviorTrainConfig:
        check_keys(cls, d, where)
        return cls(**d)


@dataclass(frozen=True)
class Tensors:
    """A sample set as tensors (targets in units of the feature position scale)."""

    agents: torch.Tensor
    mask: torch.Tensor
    target: torch.Tensor
    valid: torch.Tensor
    labels: torch.Tensor

    @classmethod
    def of(cls, inputs: BehaviorInputs, labels: np.ndarray, pos_scale_m: float) -> Tensors:
        if len(inputs) != len(labels):
            raise ValueError(f"behaviour training: {len(inputs)} samples but {len(labels)} labels")
        return cls(torch.from_numpy(inputs.agents), torch.from_numpy(inputs.mask),
                   torch.from_numpy(inputs.target_xy / pos_scale_m), torch.from_numpy(inputs.target_valid),
                   torch.as_tensor(labels, dtype=torch.long))

    def __len__(self) -> int:
        return int(self.labels.shape[0])


@torch.no_grad()
def embed_all(net: BehaviorNet, data: Tensors, batch: int = 512, lora: bool = True) -> torch.Tensor:
    """``v [N, proj_dim]`` of every sample (eval mode)."""
    net.eval()
    parts = [net.project(net.encode(data.agents[i:i + batch], data.mask[i:i + batch]), lora=lora)
             for i in range(0, len(data), batch)]
    return torch.cat(parts) if parts else torch.zeros(0, net.cfg.proj_dim)


def _epoch_log(stage: str, epoch: int, sums: dict[str, float], n: int) -> dict[str, float]:
    row = {"stage": stage, "epoch": epoch, **{k: round(v / max(n, 1), 5) for k, v in sums.items()}}
    logger.info("%s", row)
    return row  # type: ignore[return-value]


def _over(start: float, max_minutes: float | None) -> bool:
    """Whether a stage that began at ``start`` (`time.monotonic`) has used up its cap (never without one)."""
    return max_minutes is not None and time.monotonic() - start > 60.0 * max_minutes


def pretrain(net: BehaviorNet, data: Tensors, cfg: BehaviorTrainConfig) -> tuple[Prototypes, list[dict[str, Any]]]:
    """Pre-train ``net`` in place (see the module docstring); returns the last prototypes and one log row per
    epoch (mean ``recon_reg``, ``recon_cls``, ``inst``, ``proto`` losses)."""
    torch.manual_seed(cfg.seed)
    gen = torch.Generator().manual_seed(cfg.seed)
    opt = torch.optim.AdamW(net.base_parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    start, log = time.monotonic(), []
    protos = update_prototypes(embed_all(net, data), data.labels, cfg.eta, cfg.alpha)
    for epoch in range(cfg.epochs):
        net.train()
        sums = {"recon_reg": 0.0, "recon_cls": 0.0, "inst": 0.0, "proto": 0.0}
        batches = 0
        for rows in torch.randperm(len(data), generator=gen).split(cfg.batch_size):
            z = net.encode(data.agents[rows], data.mask[rows])
            traj, logits = net.decode(z)
            reg, cls = recon_loss(traj, logits, data.target[rows], data.valid[rows])
            loss = reg + cls
            if cfg.contrastive:
                _, inst, proto = proto_nce(net.project(z), data.labels[rows], protos, cfg.tau)
                loss = loss + cfg.lam * (inst + proto)
                sums["inst"] += inst.item()
                sums["proto"] += proto.item()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sums["recon_reg"] += reg.item()
            sums["recon_cls"] += cls.item()
            batches += 1
        log.append(_epoch_log("pretrain", epoch, sums, batches))
        protos = update_prototypes(embed_all(net, data), data.labels, cfg.eta, cfg.alpha, protos)
        if _over(start, cfg.max_minutes):
            logger.info("pre-training stopped at the %.1f min cap after %d epochs", cfg.max_minutes, epoch + 1)
            break
    net.eval()
    return protos, log


def finetune(net: BehaviorNet, data: Tensors, cfg: BehaviorTrainConfig, protos: Prototypes
             ) -> tuple[Prototypes, list[dict[str, Any]]]:
    """Fine-tune the LoRA adapter of ``net`` in place on ``data`` (the crash set) with ``L_ProtoNCE`` alone."""
    torch.manual_seed(cfg.seed + 1)
    gen = torch.Generator().manual_seed(cfg.seed + 1)
    for p in net.parameters():
        p.requires_grad_(False)
    for adapter in net.lora_parameters():
        adapter.requires_grad_(True)
    opt = torch.optim.Adam(net.lora_parameters(), lr=cfg.finetune_lr)
    start, log = time.monotonic(), []
    protos = update_prototypes(embed_all(net, data), data.labels, cfg.eta, cfg.alpha, protos)
    try:
        for epoch in range(cfg.finetune_epochs):
            net.eval()  # frozen backbone: no dropout; only A, B move
            sums = {"inst": 0.0, "proto": 0.0}
            batches = 0
            for rows in torch.randperm(len(data), generator=gen).split(cfg.finetune_batch_size):
                with torch.no_grad():
                    z = net.encode(data.agents[rows], data.mask[rows])
                loss, inst, proto = proto_nce(net.project(z), data.labels[rows], protos, cfg.tau)
                opt.zero_grad()
                loss.backward()
                opt.step()
                sums["inst"] += inst.item()
                sums["proto"] += proto.item()
                batches += 1
            log.append(_epoch_log("finetune", epoch, sums, batches))
            protos = update_prototypes(embed_all(net, data), data.labels, cfg.eta, cfg.alpha, protos)
            if _over(start, cfg.max_minutes):
                logger.info("fine-tuning stopped at the %.1f min cap after %d epochs", cfg.max_minutes, epoch + 1)
                break
    finally:
        for p in net.parameters():
            p.requires_grad_(True)
    return protos, log
