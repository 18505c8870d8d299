"""Episode rows for results-store tests (all columns, outcome flags consistent with the outcome)."""

from __future__ import annotations

import numpy as np

from seal.experiments.evaluation.metrics import histogram_counts
from seal.scoring.realism import ACC_BINS, YAW_RATE_BINS


def hist(values, bins) -> list[int]:
    return histogram_counts(np.asarray(values, dtype=np.float64), bins).tolist()


def episode(run: str = "r0", setting: str = "normal", scenario_id: str = "s0", outcome: str = "success",
            pipeline: str = "noadv", seed: int = 0, **extra) -> dict:
    row = {
        "run": run, "dataset": "/data", "setting": setting, "scenario_id": scenario_id, "pipeline": pipeline,
        "seed": seed, "ego": run, "split": "eval", "k": 0, "outcome": outcome,
        "success": outcome == "success", "crash": outcome == "crash", "out_of_road": outcome == "out_of_road",
        "timeout": outcome == "timeout", "route_completion": 1.0 if outcome == "success" else 0.4,
        "episode_return": 50.0, "adv_collision": outcome == "crash", "min_gap_m": 3.5, "close_call": False,
        "collision_speed_mps": float("nan"), "head_on": False, "severe_head_on": False, "yaw_wd": 0.1,
        "acc_wd": 0.2, "road_wd": 0.0, "realism": 0.1, "adv_offroad_share": 0.0, "log_offroad_share": 0.0,
        "adv_yaw_hist": hist([0.1, 0.3, 0.3], YAW_RATE_BINS), "adv_acc_hist": hist([-2.0, 1.0], ACC_BINS),
        "log_yaw_hist": hist([0.0, 0.1], YAW_RATE_BINS), "log_acc_hist": hist([0.0, 0.5, 0.2], ACC_BINS),
        "generations": 0, "generation_ms_mean": None, "generation_ms_max": None,
    }
    row.update(extra)
    return row
