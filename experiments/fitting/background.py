"""``seal fit background``: train the RAPID background model (paper 004) on a dataset's logged tracks.

Samples (`seal.models.rapid.data`) from the training split's scenarios (every ``stride``-th step), held-out
denoising loss on the first ``eval_limit`` scenarios of ``eval_split``; writes ``OUT/model.pt`` (the model file
`seal.models.rapid.load_rapid` reads, with ``background: rapid`` in `ScenarioEnv`) and ``OUT/report.json``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from seal.core.atomic import atomic_write_json
from seal.core.config import ConfigError, load_config, to_dict
from seal.core.dataset import load_split
from seal.experiments import presets
from seal.models.rapid.data import build_samples
from seal.models.rapid.train import RapidTrainConfig, save_rapid, train_rapid

log = logging.getLogger(__name__)

PRESETS = ("quick", "standard")


@dataclass(frozen=True)
class BackgroundFitConfig:
    """Settings of ``seal fit background`` (presets: ``experiments/configs/background_<preset>.yaml``)."""

    split: str = "train"
    """Split of the training scenarios."""
    limit: int | None = None
    """Use the first N training scenarios (None: all)."""
    eval_split: str = "eval"
    """Held-out split of the validation loss."""
    eval_limit: int | None = 20
    """Held-out scenarios of the validation loss (None: all)."""
    stride: int = 2
    """Use every stride-th step of each scenario."""
    drop_intent: float = 0.15
    """Probability that a training sample's desired speed / destination is replaced by "missing"."""
    dim: int = 64
    """Network width."""
    epochs: int = 6
    """Passes over the samples."""
    batch_size: int = 1024
    """Samples per gradient step."""
    lr: float = 2e-3
    """AdamW learning rate."""
    seed: int = 0
    """Random seed."""
    threads: int = 1
    """Torch threads (set by the command-line entry point)."""

    def __post_init__(self) -> None:
        if self.stride < 1:
            raise ConfigError(f"stride must be >= 1, got {self.stride}")
        if not 0.0 <= self.drop_intent < 1.0:
            raise ConfigError(f"drop_intent must be in [0, 1), got {self.drop_intent}")
        for name in ("dim", "epochs", "batch_size"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be >= 1, got {getattr(self, name)}")


def resolve_config(preset: str | None = "standard", config_file: str | Path | None = None, sets: Sequence[str] = (),
                   **values: Any) -> BackgroundFitConfig:
    """Defaults < preset < YAML config file < ``values`` (None values ignored) < ``sets`` (``key=value``)."""
    preset_path = None if preset is None else presets.preset_file("background", preset, PRESETS)
    return load_config(BackgroundFitConfig, preset=preset_path, file=config_file, values=values, overrides=sets)


def fit_background(dataset: str | Path, out: str | Path, config: BackgroundFitConfig, progress: bool = True
                   ) -> dict[str, Any]:
    """Train and write ``OUT/model.pt`` and ``OUT/report.json``; returns the report."""
    from tqdm import tqdm

    out = Path(out)
    train_scen = load_split(dataset, config.split, config.limit, what="training")
    eval_scen = load_split(dataset, config.eval_split, config.eval_limit, what="held-out")
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    train = build_samples(train_scen, config.seed, config.drop_intent, config.stride)
    val = build_samples(eval_scen, config.seed + 1, config.drop_intent, config.stride)
    data_s = time.perf_counter() - start
    log.info("RAPID samples: %d train, %d held-out (%.0f s)", len(train), len(val), data_s)
    train_cfg = RapidTrainConfig(config.dim, config.epochs, config.batch_size, config.lr, config.seed)
    bar = tqdm(total=None, desc="fit background", disable=not progress, unit="batch")

    def tick(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    start = time.perf_counter()
    net, history = train_rapid(train, val, train_cfg, tick)
    bar.close()
    report = {
        "dataset": str(dataset), "train_scenarios": len(train_scen), "eval_scenarios": len(eval_scen),
        "train_samples": len(train), "eval_samples": len(val), "data_seconds": round(data_s, 1),
        "train_seconds": round(time.perf_counter() - start, 1), "torch_threads": torch.get_num_threads(),
        "parameters": sum(p.numel() for p in net.parameters()), "history": history, "config": to_dict(config),
    }
    save_rapid(out / "model.pt", net, train_cfg, {"fit": report})
    atomic_write_json(out / "report.json", report)
    return report


def format_summary(report: dict[str, Any]) -> str:
    """A few lines for the terminal."""
    h = report["history"]
    return (f"RAPID background model: {report['parameters']} parameters, {report['train_samples']} samples from "
            f"{report['train_scenarios']} scenarios, {report['train_seconds']} s; loss train "
            f"{h['train_loss'][-1]:.4f}, held-out {h['val_loss'][-1] if h['val_loss'] else float('nan'):.4f}")
