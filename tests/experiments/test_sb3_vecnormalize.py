"""VecNormalize statistics read by the safe SB3 loader (mutation-testing survivors of
`seal.experiments.training.sb3_load`, issue 24): the file's own epsilon and clip bound, no normalisation when it
did not normalise observations, refusals that name the file, and every numpy random generator a space may pickle."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from seal.experiments.training.sb3_load import ModelLoadError, read_vecnormalize


def _venv(steps: int = 30, env_id: str = "Pendulum-v1", **kwargs: Any) -> Any:
    """A VecNormalize over Pendulum (3 observations) after ``steps`` random steps (seeded)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([lambda: gym.make(env_id)]), **kwargs)
    venv.seed(0)
    venv.action_space.seed(0)
    venv.reset()
    for _ in range(steps):
        venv.step(np.array([venv.action_space.sample()]))
    return venv


def _observations() -> np.ndarray:
    """Observations inside and far outside what the statistics saw (the clip bound matters for the latter)."""
    return np.random.default_rng(1).normal(0.0, 5.0, size=(20, 3)).astype(np.float32)


def test_the_files_epsilon_and_clip_bound_are_applied(tmp_path: Path) -> None:
    venv = _venv(epsilon=0.25, clip_obs=0.5)
    venv.save(str(tmp_path / "vecnormalize.pkl"))
    normalise = read_vecnormalize(tmp_path / "vecnormalize.pkl")
    assert normalise is not None and (normalise.epsilon, normalise.clip_obs) == (0.25, 0.5)
    obs = _observations()
    expected = venv.normalize_obs(obs)
    assert np.abs(expected).max() == pytest.approx(0.5)  # some observations reach the clip bound
    np.testing.assert_allclose(normalise(obs), expected, rtol=1e-6, atol=1e-6)


def test_statistics_that_did_not_normalise_observations_give_none(tmp_path: Path) -> None:
    _venv(norm_obs=False).save(str(tmp_path / "vecnormalize.pkl"))
    assert read_vecnormalize(tmp_path / "vecnormalize.pkl") is None


def _drop_var(venv: Any) -> None:
    del venv.obs_rms.var


@pytest.mark.parametrize("damage", ["not VecNormalize", "no variance"])
def test_a_file_without_observation_statistics_is_refused_naming_it(tmp_path: Path, damage: str) -> None:
    path = tmp_path / "vecnormalize.pkl"
    if damage == "not VecNormalize":
        path.write_bytes(pickle.dumps({"mean": np.zeros(3), "var": np.ones(3)}))
    else:
        venv = _venv(steps=3)
        _drop_var(venv)
        venv.save(str(path))
    with pytest.raises(ModelLoadError, match=f"{path}: not a VecNormalize file"):
        read_vecnormalize(path)


class DictObsEnv(gym.Env):
    observation_space = spaces.Dict({"position": spaces.Box(-1.0, 1.0, (3,), np.float32)})
    action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        return {"position": np.zeros(3, np.float32)}, {}

    def step(self, action: np.ndarray) -> tuple[dict, float, bool, bool, dict]:
        return {"position": np.full(3, 0.5, np.float32)}, 0.0, False, False, {}


def test_statistics_of_a_dict_observation_say_to_evaluate_from_python(tmp_path: Path) -> None:
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    venv = VecNormalize(DummyVecEnv([DictObsEnv]))
    venv.observation_space.seed(0)  # the Dict space and its Box each pickle a seeded generator
    venv.reset()
    venv.step(np.zeros((1, 2), np.float32))
    venv.save(str(tmp_path / "vecnormalize.pkl"))
    with pytest.raises(ModelLoadError, match="for a dict observation space, evaluate the policy from Python"):
        read_vecnormalize(tmp_path / "vecnormalize.pkl")


@pytest.mark.parametrize("generator", ["MT19937", "Philox", "SFC64", "RandomState"])
def test_spaces_with_any_numpy_generator_load(tmp_path: Path, generator: str) -> None:
    """A space's random generator is pickled with the statistics; each numpy bit generator, and the legacy
    RandomState, is read back as inert state."""
    venv = _venv(steps=5)
    rng = (np.random.RandomState(3) if generator == "RandomState"
           else np.random.Generator(getattr(np.random, generator)(3)))
    venv.observation_space._np_random = rng
    venv.save(str(tmp_path / "vecnormalize.pkl"))
    normalise = read_vecnormalize(tmp_path / "vecnormalize.pkl")
    assert normalise is not None
    np.testing.assert_allclose(normalise(_observations()), venv.normalize_obs(_observations()), rtol=1e-6, atol=1e-6)
