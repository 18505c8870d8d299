"""Numpy copies of SB3 TD3 and SAC actors (`seal.experiments.training.numpy_actor`) against SB3's own predict."""

from __future__ import annotations

import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from torch import nn

from seal.experiments.training.egos import PolicyEgo, make_ego
from seal.experiments.training.numpy_actor import (
    activation_of,
    actor_mlp,
    apply_activation,
    deterministic_actor,
    mlp_of,
)
from seal.experiments.training.zoo import ACTIVATIONS


class _Spaces(gym.Env):
    """Only spaces: SB3 builds its networks from them (never stepped)."""

    def __init__(self, obs_dim: int, low: list[float], high: list[float]) -> None:
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32)
        self.action_space = gym.spaces.Box(np.array(low, np.float32), np.array(high, np.float32))

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        return np.zeros(self.observation_space.shape, np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        return np.zeros(self.observation_space.shape, np.float32), 0.0, True, False, {}


def _td3(activation: str = "ReLU", low: tuple[float, ...] = (-1.0, -1.0), high: tuple[float, ...] = (1.0, 1.0),
         obs_dim: int = 100, seed: int = 0) -> object:
    from stable_baselines3 import TD3

    model = TD3("MlpPolicy", _Spaces(obs_dim, list(low), list(high)), seed=seed, device="cpu",
                policy_kwargs={"net_arch": [64, 32], "activation_fn": getattr(nn, activation)})
    # Trained-looking weights: SB3's initial last layer is small, which would hide errors behind the tanh.
    with torch.no_grad():
        for p in model.actor.parameters():
            p.mul_(3.0)
    return model


@pytest.mark.parametrize("name", ACTIVATIONS)
def test_every_configurable_activation_matches_torch(name: str) -> None:
    non_default = {"LeakyReLU": {"negative_slope": 0.2}, "ELU": {"alpha": 0.5}, "CELU": {"alpha": 2.0},
                   "Softplus": {"beta": 2.0, "threshold": 5.0}, "Hardtanh": {"min_val": -2.0, "max_val": 3.0}}
    modules = [getattr(nn, name)(), getattr(nn, name)(**non_default.get(name, {}))]
    if name == "GELU":
        modules.append(nn.GELU(approximate="tanh"))
    if name == "PReLU":
        with torch.no_grad():
            modules[1].weight.fill_(-0.7)
    x = np.linspace(-30.0, 30.0, 2001, dtype=np.float32)
    for m in modules:
        with torch.no_grad():
            want = m(torch.as_tensor(x)).numpy()
        got = apply_activation(activation_of(m), x)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6, err_msg=repr(m))


def test_an_unknown_module_is_refused_with_its_name() -> None:
    with pytest.raises(ValueError, match="LayerNorm"):
        mlp_of(nn.Sequential(nn.Linear(3, 4), nn.LayerNorm(4), nn.Linear(4, 1)))
    with pytest.raises(ValueError, match="Softmax"):
        activation_of(nn.Softmax(dim=-1))


@pytest.mark.parametrize(("activation", "low", "high"), [("ReLU", (-1.0, -1.0), (1.0, 1.0)),
                                                         ("Tanh", (-2.0, 0.0), (1.0, 3.0)),
                                                         ("ELU", (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0))])
def test_deterministic_actor_gives_sb3_predict_actions(activation: str, low: tuple[float, ...],
                                                      high: tuple[float, ...]) -> None:
    model = _td3(activation, low, high)
    act = deterministic_actor(model)
    assert act is not None
    rng = np.random.default_rng(0)
    obs = rng.normal(0.0, 2.0, (300, 100)).astype(np.float32)
    want = np.stack([model.predict(o, deterministic=True)[0] for o in obs])  # type: ignore[attr-defined]
    got = np.stack([act(o) for o in obs])
    assert got.shape == want.shape == (300, len(low)) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-5)
    # The actions span the space (not all saturated at one bound), so the comparison means something.
    assert np.all(got.std(axis=0) > 0.05 * (np.array(high) - np.array(low)))


def test_the_copy_pickles_for_the_env_workers() -> None:
    model = _td3("LeakyReLU")
    mlp = actor_mlp(model)
    again = pickle.loads(pickle.dumps(mlp))
    x = np.random.default_rng(1).normal(size=100).astype(np.float32)
    np.testing.assert_array_equal(again(x), mlp(x))


@pytest.mark.parametrize("activation", ["ReLU", "Tanh"])
def test_a_sac_actor_gives_sb3_predict_actions(activation: str) -> None:
    """SAC's deterministic action is the mode of its squashed Gaussian, tanh(mu(latent_pi(obs))), unscaled."""
    from stable_baselines3 import SAC

    low, high = (-2.0, 0.0, -1.0), (1.0, 3.0, 1.0)
    model = SAC("MlpPolicy", _Spaces(100, list(low), list(high)), seed=3, device="cpu",
                policy_kwargs={"net_arch": [64, 32], "activation_fn": getattr(nn, activation)})
    with torch.no_grad():
        model.actor.mu.weight.mul_(40.0)  # trained-looking output layer, as for TD3 above
    act = deterministic_actor(model)
    assert act is not None
    obs = np.random.default_rng(2).normal(0.0, 2.0, (300, 100)).astype(np.float32)
    want = np.stack([model.predict(o, deterministic=True)[0] for o in obs])
    got = np.stack([act(o) for o in obs])
    assert got.shape == want.shape == (300, 3) and got.dtype == np.float32
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert np.all(got.std(axis=0) > 0.05 * (np.array(high) - np.array(low)))


def test_policies_without_a_numpy_twin_fall_back_to_predict() -> None:
    from stable_baselines3 import PPO, SAC

    from seal.envs.heuristic import HeuristicDriver

    env = _Spaces(8, [-1.0, -1.0], [1.0, 1.0])
    assert deterministic_actor(SAC("MlpPolicy", env, device="cpu", use_sde=True)) is None
    assert deterministic_actor(PPO("MlpPolicy", env, device="cpu", n_steps=8, batch_size=8)) is None
    assert deterministic_actor(HeuristicDriver()) is None
    assert PolicyEgo(HeuristicDriver(), "heuristic", numpy_actor=True)._fast is None


def test_a_saved_td3_ego_acts_through_numpy_like_predict(tmp_path: Path) -> None:
    model = _td3("ReLU", obs_dim=100)
    path = tmp_path / "ego.zip"
    model.save(path)  # type: ignore[attr-defined]
    ego = make_ego(str(path), algo="td3")
    assert isinstance(ego, PolicyEgo) and ego._fast is not None
    slow = PolicyEgo(ego.model, "slow")
    rng = np.random.default_rng(2)
    for step, obs in enumerate(rng.normal(0.0, 2.0, (50, 100))):
        np.testing.assert_allclose(ego.act(obs, step), slow.act(obs, step), atol=1e-5)
