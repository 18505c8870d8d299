"""`seal.experiments.training.saturation`: the share of actions at the box edge and their spread over states."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3 import PPO, TD3
from stable_baselines3.common.envs import IdentityEnvBox

from seal.experiments.training.saturation import actor_saturation


def _td3_with_states(n: int = 64) -> TD3:
    env = IdentityEnvBox(low=-1.0, high=1.0, eps=0.05)
    model = TD3("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, buffer_size=200, seed=0)
    rng = np.random.default_rng(0)
    for _ in range(n):
        obs = rng.uniform(-1, 1, (1, 1)).astype(np.float32)
        model.replay_buffer.add(obs, obs, obs, np.zeros(1), np.zeros(1), [{}])
    return model


def _set_last_layer(model: TD3, weight: float, bias: float) -> None:
    last = [m for m in model.actor.mu if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():
        last.weight.fill_(weight)
        last.bias.fill_(bias)


def test_a_constant_action_at_the_edge_and_a_varied_one_inside() -> None:
    model = _td3_with_states()
    _set_last_layer(model, 0.0, 10.0)  # tanh(10): every state gets the same action at the edge
    stuck = actor_saturation(model, 128, np.random.default_rng(1))
    assert stuck["edge_share"] == 1.0 and stuck["action_std"] == pytest.approx(0.0, abs=1e-6)
    _set_last_layer(model, 0.0, 0.0)  # tanh(0): one action for all, in the middle
    middle = actor_saturation(model, 128, np.random.default_rng(1))
    assert middle == {"edge_share": 0.0, "action_std": pytest.approx(0.0, abs=1e-6)}
    with torch.no_grad():  # actions that depend on the state, inside the box
        first = model.actor.mu[0]
        first.weight.fill_(1.0)
        first.bias.fill_(0.0)
    _set_last_layer(model, 0.2, 0.0)
    varied = actor_saturation(model, 128, np.random.default_rng(1))
    draw = np.random.default_rng(1)  # the same states, drawn as the function draws them
    rows, envs = draw.integers(0, 64, 128), draw.integers(0, 1, 128)
    states = torch.as_tensor(model.replay_buffer.observations[rows, envs])
    with torch.no_grad():
        expected = model.policy._predict(states, deterministic=True).numpy().reshape(128, -1)
    assert np.abs(expected).max() < 0.99 and varied["edge_share"] == 0.0
    assert varied["action_std"] == pytest.approx(float(expected.std(axis=0).mean())) and varied["action_std"] > 0.01


def test_the_draw_leaves_numpys_global_stream_alone_and_needs_a_buffer() -> None:
    model = _td3_with_states()
    np.random.seed(3)
    reference = np.random.random()
    np.random.seed(3)
    actor_saturation(model, 32, np.random.default_rng(0))
    assert np.random.random() == reference  # SB3 samples its batches from this stream
    empty = TD3("MlpPolicy", IdentityEnvBox(), buffer_size=10, seed=0)
    assert actor_saturation(empty, 8, np.random.default_rng(0)) == {}
    ppo = PPO("MlpPolicy", IdentityEnvBox(), n_steps=8, batch_size=8, seed=0)
    assert actor_saturation(ppo, 8, np.random.default_rng(0)) == {}
    assert isinstance(IdentityEnvBox().action_space, spaces.Box)
