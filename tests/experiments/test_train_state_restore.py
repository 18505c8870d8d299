"""What a checkpoint of `seal.experiments.training.state` restores and what it refuses, on small SB3 models in process
(mutation-testing survivors, issue 24): the run folder's documented layout as its readers expect it, saved models
without training state, the counters and rng states through ``state.json``, the extra models of a ReSkill run, SAC's
entropy coefficient, and model files that are partial or carry a pickle."""

from __future__ import annotations

import base64
import errno
import json
import pickle
import random
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch

from seal.experiments.training import sb3_load
from seal.experiments.training import state as ts


def _td3(seed: int, steps: int) -> Any:
    from stable_baselines3 import TD3
    from stable_baselines3.common.noise import NormalActionNoise

    model = TD3("MlpPolicy", gym.make("Pendulum-v1"), learning_starts=20, batch_size=8, buffer_size=300,
                policy_kwargs={"net_arch": [8]}, seed=seed, device="cpu",
                action_noise=NormalActionNoise(np.zeros(1), 0.1 * np.ones(1)))
    model.learn(steps)
    return model


@pytest.fixture(scope="module")
def model() -> Any:
    """A TD3 on Pendulum with action noise after one finished episode (200 steps) and 10 more steps."""
    return _td3(seed=3, steps=210)


@pytest.fixture(scope="module")
def residual() -> Any:
    """A second TD3 (another seed, another number of updates): the extra model of a ReSkill checkpoint."""
    return _td3(seed=5, steps=40)


def _workers() -> list[dict[str, np.ndarray]]:
    return [{"meta": np.array(json.dumps({"worker": 0}))}]


def _params(model: Any) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in model.policy.state_dict().items()}


def test_the_run_folder_layout_is_the_documented_one(tmp_path: Path, model: Any) -> None:
    """The names of the module docstring and README: `seal eval` finds the final model and the run config of a
    checkpoint, `seal compare` reads progress.csv, `seal run` and `seal train` read done.json."""
    run = tmp_path / "run"
    run.mkdir()
    (run / ts.CONFIG).write_text("algo: td3\n")
    folder = ts.write_checkpoint(run, model, _workers(), {})
    model.save(run / ts.FINAL_MODEL, exclude=ts.SAVE_EXCLUDE)
    (run / ts.PROGRESS).write_text("time/total_timesteps\n210\n")
    assert ts.run_status(run) == "unfinished"
    (run / ts.DONE).write_text('{"steps": 210}')
    assert sorted(p.name for p in run.iterdir()) == [
        "checkpoints", "config.yaml", "done.json", "final_model.zip", "progress.csv"]
    assert folder == run / "checkpoints" / "step_210" and (run / "checkpoints" / "latest.json").is_file()
    assert ts.run_status(run) == "done" and ts.read_done(run) == {"steps": 210}
    assert sb3_load.find_model(run) == run / "final_model.zip"
    assert sb3_load.find_run_config(folder / "model.zip") == (run / "config.yaml", {"algo": "td3"})


def test_saved_models_hold_no_training_state(tmp_path: Path, model: Any) -> None:
    """Only what defines the model is saved; the runtime state SB3 would pickle (last observation, episode
    buffers, action noise, the learning-rate schedule) is left out, and the checkpoint loads with the safe loader."""
    folder = ts.write_checkpoint(tmp_path, model, _workers(), {})
    data = json.loads(zipfile.ZipFile(folder / "model.zip").read("data"))
    runtime = {"action_noise", "_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer",
               "ep_success_buffer", "replay_buffer_kwargs", "lr_schedule"}
    assert not runtime & set(data), sorted(runtime & set(data))
    assert model.ep_info_buffer and model.action_noise is not None and model._last_obs is not None  # all were set
    loaded = sb3_load.load_sb3_model(folder / "model.zip", "td3", model.observation_space, model.action_space)
    obs = np.array([0.5, -0.5, 0.1], np.float32)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0],
                               atol=1e-6)


def test_the_counters_and_rng_states_come_back_through_state_json(tmp_path: Path, model: Any) -> None:
    assert model._episode_num == 1 and model._n_updates > 0
    np.random.seed(21)
    random.seed(22)
    torch.manual_seed(23)
    model.action_space.seed(24)
    folder = ts.write_checkpoint(tmp_path, model, _workers(), {"wall_s": 2.0})
    expected = (np.random.normal(size=3), random.random(), torch.rand(3), model.action_space.sample())
    np.random.seed(0)
    random.seed(0)
    torch.manual_seed(0)
    model.action_space.seed(0)
    state, rng_arrays, _ = ts.read_checkpoint_state(folder)
    assert (state["episode_num"], state["n_updates"], state["wall_s"]) == (1, model._n_updates, 2.0)
    ts.set_rng_state(model, state["rng"], rng_arrays)
    got = (np.random.normal(size=3), random.random(), torch.rand(3), model.action_space.sample())
    np.testing.assert_array_equal(got[0], expected[0])
    assert got[1] == expected[1] and torch.equal(got[2], expected[2])
    np.testing.assert_array_equal(got[3], expected[3])


def test_an_extra_model_round_trips_with_its_buffer_and_update_count(tmp_path: Path, model: Any,
                                                                     residual: Any) -> None:
    assert residual._n_updates not in (0, model._n_updates)
    folder = ts.write_checkpoint(tmp_path, model, _workers(), {}, extra_models={"residual": residual})
    assert {"residual.zip", "residual_replay_buffer.npz"} <= {p.name for p in folder.iterdir()}
    state, _, _ = ts.read_checkpoint_state(folder)
    assert state["models"] == {"residual": {"n_updates": residual._n_updates}}
    assert ts.checkpoint_problem(folder, {"replay_buffer.npz", "residual_replay_buffer.npz"}) is None
    fresh = _td3(seed=9, steps=0)
    ts.load_extra_model(fresh, folder, "residual", state)
    assert fresh._n_updates == residual._n_updates
    for key, value in _params(residual).items():
        assert torch.equal(value, fresh.policy.state_dict()[key]), key
    assert fresh.replay_buffer.pos == residual.replay_buffer.pos == 40
    np.testing.assert_array_equal(fresh.replay_buffer.observations[:40], residual.replay_buffer.observations[:40])


def test_sac_entropy_coefficient_is_restored(tmp_path: Path) -> None:
    """SAC keeps its learned entropy coefficient as a torch variable beside the state dicts."""
    from stable_baselines3 import SAC

    def sac(seed: int, steps: int) -> Any:
        m = SAC("MlpPolicy", gym.make("Pendulum-v1"), learning_starts=10, batch_size=8, buffer_size=100,
                policy_kwargs={"net_arch": [8]}, seed=seed, device="cpu")
        m.learn(steps)
        return m

    trained, fresh = sac(1, 40), sac(2, 0)
    assert not torch.equal(trained.log_ent_coef, fresh.log_ent_coef)
    folder = ts.write_checkpoint(tmp_path, trained, _workers(), {})
    ts.load_model_state(fresh, folder / "model.zip")
    assert torch.equal(fresh.log_ent_coef, trained.log_ent_coef)


def _rewrite(path: Path, drop: str = "", data: dict | None = None) -> None:
    with zipfile.ZipFile(path) as zf:
        entries = {n: zf.read(n) for n in zf.namelist() if n != drop}
    if data is not None:
        entries["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as zf:
        for name, blob in entries.items():
            zf.writestr(name, blob)


def test_a_model_file_missing_a_state_dict_is_refused(tmp_path: Path, model: Any) -> None:
    folder = ts.write_checkpoint(tmp_path, model, _workers(), {})
    _rewrite(folder / "model.zip", drop="actor.optimizer.pth")  # the restore would keep the fresh optimiser
    fresh = _td3(seed=9, steps=0)
    with pytest.raises(ValueError, match="actor.optimizer"):
        ts.load_model_state(fresh, folder / "model.zip")


class _Touch:
    """Unpickled, creates the file ``path`` (what a hostile pickle could do instead)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self) -> tuple[Any, tuple[Path]]:
        return Path.touch, (self.path,)


def test_restoring_a_model_never_unpickles_its_settings(tmp_path: Path, model: Any) -> None:
    folder = ts.write_checkpoint(tmp_path, model, _workers(), {})
    marker = tmp_path / "pickle_ran"
    data = json.loads(zipfile.ZipFile(folder / "model.zip").read("data"))
    data["payload"] = {":type:": "<class 'object'>",
                       ":serialized:": base64.b64encode(pickle.dumps(_Touch(marker))).decode()}
    _rewrite(folder / "model.zip", data=data)
    fresh = _td3(seed=9, steps=0)
    ts.load_model_state(fresh, folder / "model.zip")
    assert not marker.exists()
    for key, value in _params(model).items():
        assert torch.equal(value, fresh.policy.state_dict()[key]), key


def test_a_failed_checkpoint_is_named_and_the_previous_one_stays(tmp_path: Path, model: Any,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    previous = ts.write_checkpoint(tmp_path, model, _workers(), {})
    root = tmp_path / ts.CHECKPOINTS
    left: list[Path] = []

    def failing(tmp: Path, *args: Any) -> None:
        left.append(tmp)
        raise OSError(errno.ENOSPC, "No space left on device")  # a failed write names no file

    monkeypatch.setattr(ts, "_write_checkpoint_files", failing)
    model.num_timesteps = 300
    try:
        with pytest.raises(OSError, match=rf"No space left on device \(writing {root / 'step_300'}; the previous "
                                          "checkpoint stays in force\\)"):
            ts.write_checkpoint(tmp_path, model, _workers(), {})
        assert sorted(p.name for p in root.iterdir()) == [ts.LATEST, previous.name]
        # A kill leaves the temporary folder behind (no handler runs): the next checkpoint removes it.
        left[0].mkdir()
        (left[0] / "model.zip").write_bytes(b"partial")
        monkeypatch.undo()
        ts.write_checkpoint(tmp_path, model, _workers(), {})
    finally:
        model.num_timesteps = 210
    assert sorted(p.name for p in root.iterdir()) == [ts.LATEST, previous.name, "step_300"]
    assert ts.latest_checkpoint(tmp_path) == root / "step_300"
