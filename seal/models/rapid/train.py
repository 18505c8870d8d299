"""Training the RAPID denoiser (x0-parametrised DDPM loss on the next-step acceleration) and its model file."""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.atomic import atomic_write_bytes
from seal.core.errors import SealError
from seal.core.weights_file import check_header, read_weights_file
from seal.models.rapid.data import RapidSamples
from seal.models.rapid.network import RapidNet
from seal.models.rapid.sampler import N_DIFFUSION, schedule

log = logging.getLogger(__name__)

FORMAT = "seal-rapid-background"
FORMAT_VERSION = 1


class RapidFileError(SealError):
    """A RAPID model file is missing, unreadable or not a RAPID model (the message names the file and field)."""


@dataclass(frozen=True)
class RapidTrainConfig:
    """Training options of `train_rapid`.

    Attributes:
        dim: network width D.
        epochs: passes over the samples.
        batch_size: samples per gradient step.
        lr: AdamW learning rate (cosine-decayed to 5 % over the run).
        seed: torch / numpy seed of the run.
    """

    dim: int = 64
    epochs: int = 6
    batch_size: int = 1024
    lr: float = 2e-3
    seed: int = 0


def _batch(samples: RapidSamples, idx: np.ndarray
           ) -> tuple[dict[str, torch.Tensor], torch.Tensor, np.ndarray, torch.Tensor]:
    """Inputs, targets, the batch's distinct scenario indices and each sample's position among them."""
    inp = {k: torch.from_numpy(v[idx]) for k, v in samples.inputs.items()}
    scenes, inverse = np.unique(samples.scene[idx], return_inverse=True)
    return inp, torch.from_numpy(samples.target[idx]), scenes, torch.from_numpy(inverse)


def batch_loss(net: RapidNet, samples: RapidSamples, idx: np.ndarray, alpha_bar: torch.Tensor,
               gen: torch.Generator) -> torch.Tensor:
    """Mean squared error of the denoiser's x0 on the samples ``idx`` at random diffusion steps."""
    inp, target, scenes, inverse = _batch(samples, idx)
    tokens = torch.from_numpy(samples.tokens[scenes])
    pad = torch.from_numpy(samples.token_pad[scenes])
    anchors = torch.from_numpy(samples.anchors[scenes])
    z = net.map(tokens, anchors, pad)[inverse]
    ctx = net.agent(inp, z)
    k = torch.randint(0, len(alpha_bar), (len(idx),), generator=gen)
    ab = alpha_bar[k][:, None]
    noisy = ab.sqrt() * target + (1 - ab).sqrt() * torch.randn(target.shape, generator=gen)
    return torch.mean((net.denoiser(noisy, k, ctx) - target) ** 2)


SCENES_PER_BATCH = 16
"""Scenarios a training batch draws from (the map encoder runs once per scenario in a batch)."""


def scene_grouped_order(scene: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random order of the samples in which consecutive samples come from random groups of
    `SCENES_PER_BATCH` scenarios (shuffled inside each group), so a batch runs the map encoder a few times only."""
    n_scenes = int(scene.max()) + 1
    group = rng.permutation(n_scenes) // SCENES_PER_BATCH
    order = rng.permutation(len(scene))
    return order[np.argsort(group[scene[order]], kind="stable")]


def train_rapid(train: RapidSamples, val: RapidSamples | None, config: RapidTrainConfig,
                progress: Callable[[int, int], None] | None = None) -> tuple[RapidNet, dict[str, Any]]:
    """Fit a `RapidNet` on ``train``; returns it and a history (per epoch: train loss, held-out loss on ``val``)."""
    torch.manual_seed(config.seed)
    rng = np.random.default_rng(config.seed)
    gen = torch.Generator().manual_seed(config.seed)
    net = RapidNet(config.dim)
    alpha_bar = schedule()
    opt = torch.optim.AdamW(net.parameters(), lr=config.lr, weight_decay=1e-4)
    n_batches = max(1, len(train) // config.batch_size)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, config.epochs * n_batches, eta_min=0.05 * config.lr)
    history: dict[str, list[float]] = {"train_loss": [], "val_loss": []}
    for epoch in range(config.epochs):
        net.train()
        order = scene_grouped_order(train.scene, rng)
        total = 0.0
        for b in range(n_batches):
            loss = batch_loss(net, train, order[b * config.batch_size:(b + 1) * config.batch_size], alpha_bar, gen)
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            sched.step()
            total += float(loss.detach())
            if progress is not None:
                progress(epoch * n_batches + b + 1, config.epochs * n_batches)
        history["train_loss"].append(total / n_batches)
        if val is not None and len(val):
            history["val_loss"].append(evaluate_loss(net, val, config.seed))
        log.info("epoch %d: train %.4f val %s", epoch, history["train_loss"][-1], history["val_loss"][-1:])
    net.eval()
    return net, history


@torch.no_grad()
def evaluate_loss(net: RapidNet, samples: RapidSamples, seed: int, batch: int = 4096) -> float:
    """Mean denoising loss on ``samples`` (seeded diffusion steps and noise)."""
    net.eval()
    gen = torch.Generator().manual_seed(seed + 1)
    alpha_bar = schedule()
    losses = [float(batch_loss(net, samples, np.arange(i, min(i + batch, len(samples))), alpha_bar, gen))
              for i in range(0, len(samples), batch)]
    return float(np.mean(losses))


def save_rapid(path: Path, net: RapidNet, config: RapidTrainConfig, extra: dict[str, Any]) -> None:
    """Write the model file atomically (weights only: ``torch.load(weights_only=True)`` reads it back)."""
    import io

    state = {"format": FORMAT, "format_version": FORMAT_VERSION, "dim": net.dim, "n_diffusion": N_DIFFUSION,
             "state_dict": net.state_dict(), "config": asdict(config), "extra": extra}
    buf = io.BytesIO()
    torch.save(state, buf)
    atomic_write_bytes(path, buf.getvalue())


def load_rapid_net(path: Path) -> tuple[RapidNet, dict[str, Any]]:
    """The network of a model file (eval mode) and the file's fields; `RapidFileError` names what is wrong."""
    state = read_weights_file(path, "RAPID background model file", "seal fit background", RapidFileError)
    state = check_header(state, str(path), FORMAT, FORMAT_VERSION, ("dim", "state_dict", "n_diffusion"),
                         RapidFileError, " (write one with `seal fit background`)")
    if state["n_diffusion"] != N_DIFFUSION:
        raise RapidFileError(f"{path}: field 'n_diffusion' is {state['n_diffusion']}; this seal samples {N_DIFFUSION}")
    net = RapidNet(int(state["dim"]))
    try:
        net.load_state_dict(state["state_dict"])
    except RuntimeError as exc:
        raise RapidFileError(f"{path}: field 'state_dict' does not fit the network ({exc})") from None
    net.eval()
    return net, state
