"""The safe SB3 loader finds models, configs and VecNormalize files by every name it documents, infers every
algorithm it lists, and loads entries that only training or schedules pickle (mutation-testing survivors of
`seal.experiments.training.sb3_load`, issue 24)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf

from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.training.sb3_load import (
    find_model,
    find_run_config,
    find_vecnormalize,
    infer_algo,
    load_sb3_model,
)


@pytest.mark.parametrize("present", [["final_model.zip"], ["best_model.zip"], ["model.zip", "final_model.zip"],
                                     ["final_model.zip", "best_model.zip"]])
def test_a_run_folder_yields_its_model_by_each_documented_name(tmp_path: Path, present: list[str]) -> None:
    for name in present:
        (tmp_path / name).write_bytes(b"")
    assert find_model(tmp_path) == tmp_path / present[0]  # the first present name in the documented order


def test_a_folder_without_a_model_names_what_it_looked_for(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="model.zip, final_model.zip, best_model.zip"):
        find_model(tmp_path)


@pytest.mark.parametrize("name", ["config.yaml", "config.yml"])
def test_the_run_config_is_found_under_either_extension(tmp_path: Path, name: str) -> None:
    model = tmp_path / "checkpoints" / "step_10" / "model.zip"
    model.parent.mkdir(parents=True)
    (tmp_path / name).write_text("algo: sac\n")
    found = find_run_config(model)
    assert found is not None and found[0] == tmp_path / name and found[1]["algo"] == "sac"


@pytest.mark.parametrize("name", ["vecnormalize.pkl", "vec_normalize.pkl"])
@pytest.mark.parametrize("where", ["beside", "run folder"])
def test_vecnormalize_is_found_under_either_name(tmp_path: Path, name: str, where: str) -> None:
    model = tmp_path / "sub" / "model.zip"
    model.parent.mkdir()
    stats = (model.parent if where == "beside" else tmp_path) / name
    stats.write_bytes(b"")
    assert find_vecnormalize(model) == stats


@pytest.mark.parametrize(("module", "extra", "algo"), [
    ("stable_baselines3.td3.policies", {}, "TD3"),
    ("stable_baselines3.sac.policies", {}, "SAC"),
    ("stable_baselines3.ddpg.policies", {}, "DDPG"),
    ("stable_baselines3.common.policies", {"n_epochs": 10}, "PPO"),
    ("stable_baselines3.common.policies", {"clip_range": 0.2}, "PPO"),
    ("stable_baselines3.common.policies", {}, "A2C"),
    ("stable_baselines3.dqn.policies", {}, None),  # discrete actions: not an ego seal can drive
])
def test_every_listed_algorithm_is_inferred_from_the_file(tmp_path: Path, module: str, extra: dict[str, int],
                                                         algo: str | None) -> None:
    data = {"policy_class": {"__module__": module}, **extra}
    assert infer_algo(tmp_path / "unused.zip", data) == algo


def _obs(env: ScenarioEnv) -> np.ndarray:
    obs, _ = env.reset(seed=0)
    return np.asarray(obs)


def test_td3_with_action_noise_and_a_schedule_loads(tmp_path: Path) -> None:
    """A TD3 trained with action noise and a learning-rate schedule pickles both; inference needs neither."""
    import json
    import zipfile

    from stable_baselines3 import TD3
    from stable_baselines3.common.noise import NormalActionNoise

    env = ScenarioEnv(sf.curve_scenario())
    model = TD3("MlpPolicy", env, seed=0, device="cpu", buffer_size=100, learning_starts=8, batch_size=8,
                action_noise=NormalActionNoise(np.zeros(2), 0.1 * np.ones(2)),
                learning_rate=lambda progress: 1e-3 * progress)
    model.learn(16)
    model.save(tmp_path / "noisy_td3")
    data = json.loads(zipfile.ZipFile(tmp_path / "noisy_td3.zip").read("data"))
    assert ":serialized:" in data["action_noise"] and ":serialized:" in data["learning_rate"]
    loaded = load_sb3_model(tmp_path / "noisy_td3.zip")
    obs = _obs(env)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0],
                               model.predict(obs, deterministic=True)[0], atol=1e-6)


def test_ppo_with_a_value_clip_schedule_loads(tmp_path: Path) -> None:
    import json
    import zipfile

    from stable_baselines3 import PPO

    env = ScenarioEnv(sf.curve_scenario())
    model = PPO("MlpPolicy", env, seed=0, device="cpu", n_steps=16, batch_size=16, n_epochs=1, clip_range_vf=0.2)
    model.learn(16)
    model.save(tmp_path / "ppo_vf")
    data = json.loads(zipfile.ZipFile(tmp_path / "ppo_vf.zip").read("data"))
    assert ":serialized:" in data["clip_range_vf"]
    loaded = load_sb3_model(tmp_path / "ppo_vf.zip")
    obs = _obs(env)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0],
                               model.predict(obs, deterministic=True)[0], atol=1e-6)


def test_a2c_loads(tmp_path: Path) -> None:
    from stable_baselines3 import A2C

    env = ScenarioEnv(sf.curve_scenario())
    model = A2C("MlpPolicy", env, seed=0, device="cpu", n_steps=8)
    model.learn(16)
    model.save(tmp_path / "a2c")
    loaded = load_sb3_model(tmp_path / "a2c.zip")
    assert type(loaded).__name__ == "A2C"
    obs = _obs(env)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0],
                               model.predict(obs, deterministic=True)[0], atol=1e-6)
