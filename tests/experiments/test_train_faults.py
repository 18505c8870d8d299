"""Tests that catch the faults a hostile review injected (issue 24): the curriculum's draw, the curriculum
callback in training, what a resume restores, and the safe model loader's refusal."""

from __future__ import annotations

import copy
import csv
import json
import types
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
from train_fixtures import tiny_dataset, tiny_train_config

from seal.adversaries.closed_loop import ClosedLoopAdversary


class _CountingGenerator:
    name = "counting"

    def generate(self, scenario, queue, rng):  # noqa: ANN001, ANN201
        return types.SimpleNamespace(behavior=object(), chosen_candidate=0, predicted_step=0, generation_time_s=0.0)


class _NoHistory:
    def queue(self, scenario):  # noqa: ANN001, ANN201
        return []


@pytest.mark.parametrize("p", [0.1, 0.3, 0.7])
def test_the_generator_perturbs_a_share_p_of_episodes(p: float) -> None:
    """The curriculum's p is the share of perturbed episodes (a draw of ``< p ** 2`` would give 0.01 / 0.09 / 0.49)."""
    adversary = ClosedLoopAdversary(_CountingGenerator(), _NoHistory(), perturb_prob=p)  # type: ignore[arg-type]
    rng = np.random.default_rng(0)
    n = 4000
    perturbed = 0
    for _ in range(n):
        adversary(None, rng)  # type: ignore[arg-type]
        perturbed += adversary.last["perturbed"]
    assert perturbed / n == pytest.approx(p, abs=4 * np.sqrt(p * (1 - p) / n))


def _snapshot(model) -> dict:  # noqa: ANN001
    buffer = model.replay_buffer
    return {
        "policy": {k: v.detach().clone() for k, v in model.policy.state_dict().items()},
        "actor_opt": copy.deepcopy(model.actor.optimizer.state_dict()),
        "critic_opt": copy.deepcopy(model.critic.optimizer.state_dict()),
        "buffer_pos": int(buffer.pos),
        "buffer_full": bool(buffer.full),
        "buffer_obs": buffer.observations[: buffer.pos].copy(),
        "buffer_actions": buffer.actions[: buffer.pos].copy(),
        "buffer_rewards": buffer.rewards[: buffer.pos].copy(),
        "n_updates": int(model._n_updates),
    }


def _same_optimizer_state(a: dict, b: dict) -> bool:
    if a["param_groups"] != b["param_groups"] or a["state"].keys() != b["state"].keys():
        return False
    for key, state in a["state"].items():
        for name, value in state.items():
            other = b["state"][key][name]
            if isinstance(value, torch.Tensor):
                if not torch.equal(value, other):
                    return False
            elif value != other:
                return False
    return True


def test_resume_restores_weights_optimisers_buffer_and_the_curriculum(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    from seal.experiments.training import callbacks as train_callbacks
    from seal.experiments.training import state as ts
    from seal.experiments.training.train import train_run

    run = tmp_path / "run"
    config = tiny_train_config(tiny_dataset(tmp_path))
    saved: dict = {}
    original_ckpt = train_callbacks.CheckpointCallback._on_rollout_start
    original_stats = train_callbacks.EpisodeStatsCallback._on_step

    def capturing_ckpt(self: train_callbacks.CheckpointCallback) -> None:
        before = self.next_step
        original_ckpt(self)  # saves (after flushing overlapped updates) when a checkpoint is due
        if self.next_step != before and self.num_timesteps == 80:
            saved.update(_snapshot(self.model))  # the state that went into checkpoints/step_80

    def killing_stats(self: train_callbacks.EpisodeStatsCallback) -> bool:
        if self.num_timesteps >= 100:
            raise KeyboardInterrupt
        return original_stats(self)

    monkeypatch.setattr(train_callbacks.CheckpointCallback, "_on_rollout_start", capturing_ckpt)
    monkeypatch.setattr(train_callbacks.EpisodeStatsCallback, "_on_step", killing_stats)
    with pytest.raises(KeyboardInterrupt):
        train_run(config, run, progress=False)
    monkeypatch.setattr(train_callbacks.CheckpointCallback, "_on_rollout_start", original_ckpt)
    monkeypatch.setattr(train_callbacks.EpisodeStatsCallback, "_on_step", original_stats)
    assert ts.latest_checkpoint(run).name == "step_80" and "policy" in saved

    restored: dict = {}
    original_restore = train_callbacks.RestoreCallback._on_training_start

    def capturing_restore(self: train_callbacks.RestoreCallback) -> None:
        original_restore(self)
        restored.update(_snapshot(self.model))

    monkeypatch.setattr(train_callbacks.RestoreCallback, "_on_training_start", capturing_restore)
    train_run({}, run, resume=True, progress=False)

    for key, value in saved["policy"].items():
        assert torch.equal(value, restored["policy"][key]), f"weights {key} not restored"
    assert _same_optimizer_state(saved["actor_opt"], restored["actor_opt"]), "actor optimiser not restored"
    assert _same_optimizer_state(saved["critic_opt"], restored["critic_opt"]), "critic optimiser not restored"
    assert (restored["buffer_pos"], restored["buffer_full"]) == (saved["buffer_pos"], saved["buffer_full"])
    for key in ("buffer_obs", "buffer_actions", "buffer_rewards"):
        np.testing.assert_array_equal(restored[key], saved[key], err_msg=key)
    assert restored["n_updates"] == saved["n_updates"]

    # The curriculum callback is installed for a perturbing pipeline: p is logged and reaches its cap.
    rows = list(csv.DictReader((run / ts.PROGRESS).open()))
    p = [float(r["curriculum/p"]) for r in rows if r.get("curriculum/p")]
    assert p and max(p) == pytest.approx(0.9) and p == sorted(p)


def test_the_safe_loader_refuses_an_unknown_pickled_entry(tmp_path: Path) -> None:
    from seal.experiments.training.egos import load_sb3_model

    model = tmp_path / "model.zip"
    data = {"policy_class": {":type:": "<class 'abc.ABCMeta'>", ":serialized:": "gAWVAAAA"},
            "sneaky_hook": {":type:": "<class 'function'>", ":serialized:": "gAWVAAAA"}}
    with zipfile.ZipFile(model, "w") as zf:
        zf.writestr("data", json.dumps(data))
    with pytest.raises(ValueError, match="entry 'sneaky_hook' is pickled and cannot be loaded safely"):
        load_sb3_model(model, algo_name="TD3")
