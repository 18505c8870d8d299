"""What the safe SB3 loader checks, keeps and refuses (mutation-testing survivors of
`seal.experiments.training.sb3_load`, issue 24): spaces of other shapes, algorithms outside its list, the run
config's algorithm, ``policy_kwargs`` values it cannot rebuild, the training-size replay buffer and its settings."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from seal.experiments.training.sb3_load import ModelLoadError, find_run_config, infer_algo, load_sb3_model


class SpacesEnv(gym.Env):
    """An env of the given observation / action shapes whose episodes end at once (models are saved untrained)."""

    def __init__(self, obs_shape: tuple[int, ...] = (100,), act_shape: tuple[int, ...] = (2,)) -> None:
        self.observation_space = spaces.Box(-np.inf, np.inf, obs_shape, np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, act_shape, np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        return np.zeros(self.observation_space.shape, np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        return np.zeros(self.observation_space.shape, np.float32), 0.0, True, False, {}


def _obs(seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=100).astype(np.float32)


def _same_actions(a: Any, b: Any) -> None:
    for seed in range(3):
        np.testing.assert_allclose(a.predict(_obs(seed), deterministic=True)[0],
                                   b.predict(_obs(seed), deterministic=True)[0], atol=1e-6)


def _td3(path: Path, env: gym.Env | None = None, **kwargs: Any) -> Any:
    from stable_baselines3 import TD3

    model = TD3("MlpPolicy", env or SpacesEnv(), seed=0, device="cpu", policy_kwargs={"net_arch": [8]},
                **{"buffer_size": 10, **kwargs})
    model.save(path)
    return model


def _edit_data(path: Path, edit: Any) -> Path:
    """A copy of the model zip ``path`` whose JSON ``data`` went through ``edit`` (what a hand edit or another
    tool could write)."""
    with zipfile.ZipFile(path) as zf:
        entries = {n: zf.read(n) for n in zf.namelist()}
    data = json.loads(entries["data"])
    edit(data)
    entries["data"] = json.dumps(data).encode()
    out = path.with_name(f"edited_{path.name}")
    with zipfile.ZipFile(out, "w") as zf:
        for name, blob in entries.items():
            zf.writestr(name, blob)
    return out


@pytest.mark.parametrize(("obs_shape", "act_shape", "culprit"), [
    ((5,), (2,), r"observation_space has shape \(5,\), seal's ego needs \(100,\)"),
    ((100,), (3,), r"action_space has shape \(3,\), seal's ego needs \(2,\)"),
])
def test_a_model_of_other_shapes_is_refused_naming_the_space(tmp_path: Path, obs_shape: tuple[int, ...],
                                                             act_shape: tuple[int, ...], culprit: str) -> None:
    _td3(tmp_path / "other.zip", SpacesEnv(obs_shape, act_shape))
    with pytest.raises(ModelLoadError, match=culprit):
        load_sb3_model(tmp_path / "other.zip", "td3")


def test_an_algorithm_outside_the_list_is_refused(tmp_path: Path) -> None:
    _td3(tmp_path / "m.zip")
    with pytest.raises(ModelLoadError, match="unknown SB3 algorithm 'DQN'; one of td3, sac, ddpg, ppo, a2c"):
        load_sb3_model(tmp_path / "m.zip", "dqn")  # an SB3 algorithm, but with discrete actions


@pytest.mark.parametrize("key", ["algo", "algorithm"])
def test_the_run_config_names_the_algorithm_the_file_cannot(tmp_path: Path, key: str) -> None:
    """DDPG saves TD3's policy class, so the file alone says TD3; the run's config says DDPG."""
    from stable_baselines3 import DDPG

    DDPG("MlpPolicy", SpacesEnv(), seed=0, device="cpu", buffer_size=10,
         policy_kwargs={"net_arch": [8]}).save(tmp_path / "final_model.zip")
    assert infer_algo(tmp_path / "final_model.zip") == "TD3"
    (tmp_path / "config.yaml").write_text(f"{key}: ddpg\n")
    assert type(load_sb3_model(tmp_path)).__name__ == "DDPG"


def test_the_nearest_config_naming_an_algorithm_within_three_folders_is_used(tmp_path: Path) -> None:
    model = tmp_path / "run" / "checkpoints" / "step_10" / "model.zip"
    model.parent.mkdir(parents=True)
    (model.parent / "config.yaml").write_text("note: not a run config\n")  # names no algorithm: passed over
    (tmp_path / "run" / "config.yaml").write_text("algo: sac\n")
    found = find_run_config(model)
    assert found is not None and found[0] == tmp_path / "run" / "config.yaml"
    deep = tmp_path / "a" / "b" / "c" / "model.zip"  # tmp_path is the fourth folder above it
    deep.parent.mkdir(parents=True)
    (tmp_path / "config.yaml").write_text("algo: sac\n")
    assert find_run_config(deep) is None
    (tmp_path / "a" / "config.yml").write_text("algo: ppo\n")
    found = find_run_config(deep)
    assert found is not None and found[1] == {"algo": "ppo"}


def test_plain_policy_kwargs_are_kept_and_objects_refused(tmp_path: Path) -> None:
    import torch.nn as nn
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", SpacesEnv(), seed=0, device="cpu", n_steps=8, batch_size=8,
                policy_kwargs={"net_arch": [16], "activation_fn": nn.ELU})
    model.save(tmp_path / "ppo.zip")
    loaded = load_sb3_model(tmp_path / "ppo.zip")
    assert loaded.policy_kwargs["net_arch"] == [16] and loaded.policy_kwargs["activation_fn"] is nn.ELU
    _same_actions(loaded, model)

    def functional(data: dict) -> None:  # what SB3 writes for a function it had to pickle
        data["policy_kwargs"]["activation_fn"] = "<function relu at 0x7f0000000000>"

    with pytest.raises(ModelLoadError, match=r"policy_kwargs\['activation_fn'\] = <function relu at 0x7f0000000000> "
                                             "is an object that cannot be rebuilt safely"):
        load_sb3_model(_edit_data(tmp_path / "ppo.zip", functional))


def test_null_policy_kwargs_load_as_the_defaults(tmp_path: Path) -> None:
    from stable_baselines3 import PPO

    model = PPO("MlpPolicy", SpacesEnv(), seed=0, device="cpu", n_steps=8, batch_size=8)
    model.save(tmp_path / "ppo.zip")

    def null(data: dict) -> None:
        data["policy_kwargs"] = None

    _same_actions(load_sb3_model(_edit_data(tmp_path / "ppo.zip", null)), model)


def test_the_training_replay_buffer_is_not_allocated(tmp_path: Path) -> None:
    model = _td3(tmp_path / "big.zip", buffer_size=5000)
    loaded = load_sb3_model(tmp_path / "big.zip")
    assert model.replay_buffer.buffer_size == 5000 and loaded.replay_buffer.buffer_size < 10
    _same_actions(loaded, model)


@pytest.mark.parametrize("kwargs", [
    {"n_steps": 3},  # SB3's n-step replay buffer: its (n_steps, gamma) settings do not fit the plain buffer
    {"replay_buffer_kwargs": {"handle_timeout_termination": np.bool_(True)}},  # pickled: not JSON
])
def test_replay_buffer_settings_do_not_stop_a_model_loading(tmp_path: Path, kwargs: dict[str, Any]) -> None:
    model = _td3(tmp_path / "m.zip", **kwargs)
    data = json.loads(zipfile.ZipFile(tmp_path / "m.zip").read("data"))
    assert data["replay_buffer_kwargs"]  # the file carries settings of the training buffer
    loaded = load_sb3_model(tmp_path / "m.zip")
    assert type(loaded.replay_buffer).__name__ == "ReplayBuffer"
    _same_actions(loaded, model)
