"""Smoke test of the env benchmark (speed is measured by ``seal bench env``, not asserted here)."""

from __future__ import annotations

from pathlib import Path

from experiments.bench_env import run_env_bench
from seal.dataset import write_dataset
from seal.scenario import Scenario


def test_bench_runs_on_a_dataset(tmp_path: Path, highway: list[Scenario]) -> None:
    write_dataset(tmp_path / "ds", highway)
    result = run_env_bench(tmp_path / "ds", n_steps=60, seed=0)
    assert result["scenarios"] == len(highway) and result["n_steps"] == 60
    assert result["scenario_env_steps_per_s"] > 0 and result["highway_v0_steps_per_s"] > 0
    ratio = result["scenario_env_steps_per_s"] / result["highway_v0_steps_per_s"]
    assert abs(result["ratio"] - ratio) < 0.02
    assert isinstance(result["meets_target"], bool)
