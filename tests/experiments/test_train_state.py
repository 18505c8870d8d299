"""Checkpoint writing and reading of `seal.experiments.training.state` on a small SB3 model, in process (issue 24:
mutation testing found these untested outside the slow kill-and-resume runs): the files and their contents, the
pruning of old checkpoints, the rng round trip and the restore of weights and optimiser states."""

from __future__ import annotations

import json
import random
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

from seal.experiments.training import state as ts


@pytest.fixture(scope="module")
def model():  # noqa: ANN201
    """A TD3 on Pendulum with 60 transitions in its buffer and some gradient updates (tests leave it as it was)."""
    from stable_baselines3 import TD3

    m = TD3("MlpPolicy", gym.make("Pendulum-v1"), learning_starts=20, batch_size=8, buffer_size=300,
            policy_kwargs={"net_arch": [8]}, seed=3, device="cpu")
    m.learn(60)
    return m


def _workers(n: int) -> list[dict[str, np.ndarray]]:
    return [{"meta": np.array(json.dumps({"worker": i})), "tracks_0": np.full((2, 3), float(i))} for i in range(n)]


def test_a_checkpoint_holds_every_file_and_the_counters(tmp_path: Path, model) -> None:  # noqa: ANN001
    folder = ts.write_checkpoint(tmp_path, model, _workers(2), {"wall_s": 1.5})
    assert folder == tmp_path / ts.CHECKPOINTS / "step_60"
    assert {p.name for p in folder.iterdir()} == {"model.zip", "replay_buffer.npz", "rng.npz", "state.json",
                                                  "worker_0.npz", "worker_1.npz"}
    assert json.loads((tmp_path / ts.CHECKPOINTS / ts.LATEST).read_text()) == {"step": 60, "dir": "step_60"}
    state, rng_arrays, workers = ts.read_checkpoint_state(folder)
    assert (state["step"], state["n_updates"], state["n_workers"], state["wall_s"]) == (60, model._n_updates, 2, 1.5)
    assert state["episode_num"] == model._episode_num and "models" not in state
    assert set(rng_arrays) == {"numpy_keys", "torch"}
    assert [json.loads(str(w["meta"])) for w in workers] == [{"worker": 0}, {"worker": 1}]
    np.testing.assert_array_equal(workers[1]["tracks_0"], np.full((2, 3), 1.0))
    assert ts.checkpoint_problem(folder, {"replay_buffer.npz"}) is None
    (folder / "worker_1.npz").unlink()
    with pytest.raises(ValueError, match="worker_1.npz is missing"):
        ts.read_checkpoint_state(folder)


def test_only_the_last_two_checkpoints_stay_and_only_the_newest_keeps_its_buffer(tmp_path: Path, model) -> None:  # noqa: ANN001
    root = tmp_path / ts.CHECKPOINTS
    for step in (60, 70, 80):
        model.num_timesteps = step
        ts.write_checkpoint(tmp_path, model, _workers(1), {})
    (root / ".tmp_step_85").mkdir()  # left by a kill during a checkpoint
    model.num_timesteps = 90
    ts.write_checkpoint(tmp_path, model, _workers(1), {})
    model.num_timesteps = 60
    assert sorted(p.name for p in root.iterdir()) == [ts.LATEST, "step_80", "step_90"]
    assert not (root / "step_80" / "replay_buffer.npz").exists() and (root / "step_90" / "replay_buffer.npz").exists()
    assert (root / "step_80" / "model.zip").exists()
    assert ts.latest_checkpoint(tmp_path) == root / "step_90"


def test_rng_states_round_trip(model) -> None:  # noqa: ANN001
    np.random.seed(11)
    random.seed(12)
    torch.manual_seed(13)
    model.action_space.seed(14)
    np.random.normal()  # a cached Gaussian is part of numpy's legacy state
    json_part, arrays = ts.rng_state(model)
    json_part = json.loads(json.dumps(json_part))  # what state.json stores
    expected = (np.random.normal(size=3), random.random(), torch.rand(3), model.action_space.sample())
    np.random.seed(0)
    random.seed(0)
    torch.manual_seed(0)
    model.action_space.seed(0)
    ts.set_rng_state(model, json_part, arrays)
    got = (np.random.normal(size=3), random.random(), torch.rand(3), model.action_space.sample())
    np.testing.assert_array_equal(got[0], expected[0])
    assert got[1] == expected[1] and torch.equal(got[2], expected[2])
    np.testing.assert_array_equal(got[3], expected[3])


def test_load_model_state_restores_weights_and_optimisers(tmp_path: Path, model) -> None:  # noqa: ANN001
    from stable_baselines3 import TD3

    folder = ts.write_checkpoint(tmp_path, model, _workers(1), {})
    fresh = TD3("MlpPolicy", gym.make("Pendulum-v1"), learning_starts=20, batch_size=8, buffer_size=300,
                policy_kwargs={"net_arch": [8]}, seed=99, device="cpu")
    ts.load_model_state(fresh, folder / "model.zip")
    for key, value in model.policy.state_dict().items():
        assert torch.equal(value, fresh.policy.state_dict()[key]), key
    saved, loaded = model.actor.optimizer.state_dict(), fresh.actor.optimizer.state_dict()
    assert saved["state"].keys() == loaded["state"].keys() and saved["state"]
    for index, entry in saved["state"].items():
        assert torch.equal(entry["exp_avg"], loaded["state"][index]["exp_avg"])
    ts.load_replay_buffer(fresh.replay_buffer, folder / "replay_buffer.npz")
    assert fresh.replay_buffer.pos == model.replay_buffer.pos == 60
    np.testing.assert_array_equal(fresh.replay_buffer.actions[:60], model.replay_buffer.actions[:60])
