"""``seal fit goose`` checkpoints: learning in chunks changes nothing, and a fit killed part way goes on from its
last checkpoint to the same agent as an uninterrupted fit."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from seal.adversaries.goose.agent import load_goose_agent
from seal.core.dataset import write_dataset
from seal.core.scenario import Scenario
from seal.experiments.fitting import goose_state
from seal.experiments.fitting.goose import GooseFitConfig, fit_goose

STEPS = 36


@pytest.fixture(scope="module")
def dataset(lane_change: Scenario, highway: list[Scenario], tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("goose_resume") / "ds"
    ds = write_dataset(root, [lane_change, *highway])
    ds.update_manifest(splits={"train": [s.scenario_id for s in [lane_change, *highway[:2]]],
                               "eval": [highway[2].scenario_id]})
    return root


def _config(**changes: Any) -> GooseFitConfig:
    base = GooseFitConfig(total_steps=STEPS, learning_starts=8, batch_size=8, net_arch=(16, 16), gru_hidden=8,
                          log_every=6, checkpoint_every=10, seed=5, spec={"max_updates": 3}, eval_split=None)
    return dataclasses.replace(base, **changes)


def _weights(path: Path) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in load_goose_agent(path).policy.state_dict().items()}


def _same(a: dict[str, torch.Tensor], b: dict[str, torch.Tensor]) -> bool:
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


@pytest.fixture(scope="module")
def uninterrupted(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, Any]]:
    out = tmp_path_factory.mktemp("goose_full") / "agent.zip"
    summary = fit_goose(dataset, out, _config(), progress=False)
    return out, summary


def test_chunks_change_nothing_that_is_learnt(dataset: Path, uninterrupted: tuple[Path, dict[str, Any]],
                                              tmp_path: Path) -> None:
    out, summary = uninterrupted
    assert summary["env_steps"] == STEPS and summary["resumed_from_step"] is None
    assert not (out.parent / "agent_run" / goose_state.CHECKPOINT).exists()  # removed once the agent is saved
    one_chunk = fit_goose(dataset, tmp_path / "one.zip", _config(checkpoint_every=0), progress=False)
    assert _same(_weights(tmp_path / "one.zip"), _weights(out))
    assert one_chunk["success_curve"] == [{**r, "elapsed_s": one_chunk["success_curve"][i]["elapsed_s"],
                                           "steps_per_s": one_chunk["success_curve"][i]["steps_per_s"]}
                                          for i, r in enumerate(summary["success_curve"])]


def _interrupt_after(n: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Make the ``n``-th checkpoint of the next fit its last act (a kill right after it was written)."""
    write = goose_state.write_checkpoint
    calls = {"n": 0}

    def write_then_die(*args: Any, **kwargs: Any) -> None:
        write(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] == n:
            raise KeyboardInterrupt

    monkeypatch.setattr(goose_state, "write_checkpoint", write_then_die)


def test_a_killed_fit_goes_on_to_the_same_agent(dataset: Path, uninterrupted: tuple[Path, dict[str, Any]],
                                                tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    full_out, full = uninterrupted
    out = tmp_path / "agent.zip"
    with monkeypatch.context() as m:
        _interrupt_after(2, m)
        with pytest.raises(KeyboardInterrupt):
            fit_goose(dataset, out, _config(), progress=False)
    run = tmp_path / "agent_run"
    assert (run / goose_state.CHECKPOINT / "state.json").is_file() and not out.exists()
    progress_rows = (run / "progress.csv").read_text().splitlines()
    summary = fit_goose(dataset, out, _config(), progress=False)
    assert summary["resumed_from_step"] == 20
    assert _same(_weights(out), _weights(full_out))  # fails unless buffer, rngs, counters and env are restored
    keep = ("steps", "episodes", "success_rate", "success_rate_all", "mean_final_gap_m")
    assert [{k: r[k] for k in keep} for r in summary["success_curve"]] == [
        {k: r[k] for k in keep} for r in full["success_curve"]]
    assert (summary["train_solved_at_start"], summary["train_scenarios_drawn"]) == (
        full["train_solved_at_start"], full["train_scenarios_drawn"])
    assert not (run / goose_state.CHECKPOINT).exists()
    after = (run / "progress.csv").read_text().splitlines()
    assert after[0] == progress_rows[0] and len(after) >= len(progress_rows)  # rows of the killed session kept


def test_other_settings_or_a_damaged_checkpoint_start_over(dataset: Path, uninterrupted: tuple[Path, dict[str, Any]],
                                                           tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                           caplog: pytest.LogCaptureFixture) -> None:
    out = tmp_path / "agent.zip"
    with monkeypatch.context() as m:
        _interrupt_after(1, m)
        with pytest.raises(KeyboardInterrupt):
            fit_goose(dataset, out, _config(), progress=False)
    model_zip = tmp_path / "agent_run" / goose_state.CHECKPOINT / "model.zip"
    model_zip.write_bytes(model_zip.read_bytes()[:200])
    with caplog.at_level(logging.WARNING):
        summary = fit_goose(dataset, out, _config(), progress=False)
    assert summary["resumed_from_step"] is None and "does not read back" in caplog.text
    assert _same(_weights(out), _weights(uninterrupted[0]))  # started over, same seed: the same agent

    other = tmp_path / "other.zip"
    with monkeypatch.context() as m:
        _interrupt_after(1, m)
        with pytest.raises(KeyboardInterrupt):
            fit_goose(dataset, other, _config(), progress=False)
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        changed = fit_goose(dataset, other, _config(learning_rate=0.002), progress=False)
    assert changed["resumed_from_step"] is None and "other settings" in caplog.text


def test_checkpoints_come_between_whole_train_cycles() -> None:
    with pytest.raises(ValueError, match="multiple of train_freq"):
        _config(train_freq=4, checkpoint_every=10)
    assert _config(train_freq=5, checkpoint_every=10).checkpoint_every == 10


def test_env_state_round_trip(lane_change: Scenario, highway: list[Scenario]) -> None:
    from seal.adversaries.goose.env import GooseEnv

    env = GooseEnv([lane_change, *highway], skip_solved=False)
    env.reset(seed=3)
    env.step(np.full(12, 0.5, dtype=np.float32))
    state = env.get_state()
    twin = GooseEnv([lane_change, *highway], skip_solved=False)
    twin.reset(seed=99)
    twin.set_state(state)
    assert twin.curve is not None and env.curve is not None
    assert np.array_equal(twin.curve.ctrl, env.curve.ctrl) and np.array_equal(twin.curve.weights, env.curve.weights)
    assert twin.start_counts == env.start_counts
    action = np.linspace(-1, 1, 12).astype(np.float32)
    a, b = env.step(action), twin.step(action)
    assert all(np.array_equal(a[0][k], b[0][k]) for k in a[0]) and a[1:4] == b[1:4]
    assert env.reset()[1]["scenario_id"] == twin.reset()[1]["scenario_id"]  # same rng
