"""A tiny dataset and a tiny TD3 training config for the training tests (a run of 160 env steps on 2 envs)."""

from __future__ import annotations

from pathlib import Path

import scenario_factory as sf

from seal.core.dataset import Dataset, write_dataset
from seal.experiments.training.config import load_train_config

CONFIG_DIR = Path(__file__).resolve().parents[1] / "experiments" / "configs"


def tiny_scenarios() -> list:
    return [sf.lane_change_scenario(), sf.curve_scenario(), sf.stopped_adversary_scenario(),
            *(sf.highway_scenario(i) for i in range(3))]


def tiny_dataset(tmp_path: Path) -> Path:
    """Six hand-built scenarios, 4 in train and 2 in eval, at ``tmp_path / "data"``."""
    root = tmp_path / "data"
    scenarios = tiny_scenarios()
    write_dataset(root, scenarios)
    ids = [s.scenario_id for s in scenarios]
    Dataset.open(root).update_manifest(splits={"train": ids[:4], "eval": ids[4:]})
    return root


def tiny_train_config(data: Path) -> dict:
    """The quick preset's TD3 shrunk to 160 env steps on 2 envs, checkpoints every 40, the rule generator as CAT."""
    over = {
        "pipeline": "cat", "seed": 1, "dataset": str(data), "total_timesteps": 160, "n_envs": 2,
        "checkpoint_every": 40, "eval_every": 80, "eval_episodes": 2,
        "pipelines.cat": {"name": "rule", "kwargs": {}},  # the rule generator: no fitted model needed
        "hyperparams.td3": {"learning_starts": 30, "batch_size": 16, "net_arch": [16, 16], "buffer_size": 400,
                            "train_freq": 1, "gradient_steps": 1},
    }
    return load_train_config(CONFIG_DIR / "quick.yaml", over)
