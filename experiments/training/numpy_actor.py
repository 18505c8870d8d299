"""SB3 TD3 and SAC actors in numpy, for one observation at a time.

SB3's ``model.predict`` spends ~0.3-0.8 ms a call on a 2-core machine (tensor conversion, checks, torch's
per-operation overhead) where the actor's three small matrix products take ~30-50 us in numpy. An evaluation calls
it every step of every episode (a TD3 ego) or every skill horizon (the ReSkill ego's high-level agent), and the
ReSkill env workers run the residual actor every step; there numpy is 10-15x cheaper.

`NumpyMLP` is a copy of an actor's ``mu`` network (every Linear, the activation between them, the output Tanh),
read from the torch modules so that any hidden activation of `seal.experiments.training.zoo.ACTIVATIONS`
(``policy_kwargs.activation_fn``) is computed as torch computes it. `deterministic_actor` is the numpy twin of
``model.predict(obs, deterministic=True)`` for a TD3 / DDPG / SAC model (flattened Box observation, squashed Box
action); results agree with SB3's to float32 rounding (~1e-6; the same products summed in another order). A
copy does not follow later training: take a new one after the weights change.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np


def _softplus(x: np.ndarray, beta: float = 1.0, threshold: float = 20.0) -> np.ndarray:
    bx = beta * x
    return np.where(bx > threshold, x, np.log1p(np.exp(np.minimum(bx, threshold))) / beta)


_erf = np.vectorize(math.erf, otypes=[np.float64])
_SELU_ALPHA, _SELU_SCALE = 1.6732632423543772, 1.0507009873554805

Activation = tuple[str, tuple[Any, ...]]
"""An activation as data (picklable, for the env workers): the ``torch.nn`` class name and its parameters."""


def _elu(x: np.ndarray, alpha: float, scale: float = 1.0) -> np.ndarray:
    """``alpha * (exp(scale * x) - 1)`` for x <= 0, x above (ELU: scale 1; CELU: scale 1 / alpha)."""
    return np.where(x > 0.0, x, alpha * np.expm1(np.minimum(x, 0.0) * scale))


def _gelu(x: np.ndarray, approximate: str) -> np.ndarray:
    if approximate == "tanh":
        return 0.5 * x * (1.0 + np.tanh(math.sqrt(2.0 / math.pi) * (x + 0.044715 * x**3)))
    return 0.5 * x * (1.0 + _erf(x / math.sqrt(2.0)))


_APPLY: dict[str, Callable[[np.ndarray, tuple[Any, ...]], np.ndarray]] = {
    "ReLU": lambda x, p: np.maximum(x, 0.0),
    "Tanh": lambda x, p: np.tanh(x),
    "Identity": lambda x, p: x,
    "Sigmoid": lambda x, p: 1.0 / (1.0 + np.exp(-x)),
    "SiLU": lambda x, p: x / (1.0 + np.exp(-x)),
    "LeakyReLU": lambda x, p: np.where(x >= 0.0, x, p[0] * x),
    "PReLU": lambda x, p: np.where(x >= 0.0, x, p[0] * x),
    "ELU": lambda x, p: _elu(x, p[0]),
    "CELU": lambda x, p: _elu(x, p[0], 1.0 / p[0]),
    "SELU": lambda x, p: _SELU_SCALE * _elu(x, _SELU_ALPHA),
    "Softplus": lambda x, p: _softplus(x, *p),
    "Mish": lambda x, p: x * np.tanh(_softplus(x)),
    "Hardtanh": lambda x, p: np.clip(x, p[0], p[1]),
    "Hardswish": lambda x, p: x * np.clip(x + 3.0, 0.0, 6.0) / 6.0,
    "GELU": lambda x, p: _gelu(x, p[0]),
}
"""Each activation's numpy function of (input, parameters), as torch computes it."""

_PARAMS: dict[str, Callable[[Any], tuple[Any, ...]]] = {
    "LeakyReLU": lambda m: (float(m.negative_slope),),
    "PReLU": lambda m: (m.weight.detach().cpu().numpy().astype(np.float32).copy(),),
    "ELU": lambda m: (float(m.alpha),),
    "CELU": lambda m: (float(m.alpha),),
    "Softplus": lambda m: (float(m.beta), float(m.threshold)),
    "Hardtanh": lambda m: (float(m.min_val), float(m.max_val)),
    "GELU": lambda m: (str(m.approximate),),
}
"""The parameters an activation module carries (the others have none)."""


def activation_of(module: Any) -> Activation:
    """The `Activation` of a ``torch.nn`` activation module (with its slopes, alphas, bounds); ValueError for one
    `apply_activation` cannot compute."""
    name = type(module).__name__
    if name not in _APPLY:
        raise ValueError(f"no numpy version of the activation {name}")
    return name, _PARAMS[name](module) if name in _PARAMS else ()


def apply_activation(activation: Activation, x: np.ndarray) -> np.ndarray:
    """``x`` through `Activation` ``activation``, as torch computes it."""
    name, params = activation
    return _APPLY[name](x, params)


@dataclass(frozen=True)
class NumpyMLP:
    """A copy of an MLP ``Linear, act, ..., Linear[, out]`` in numpy (float32 weights); picklable, so it can be
    sent to env worker processes.

    Attributes:
        layers: (weight ``[out, in]``, bias ``[out]``) float32 of every Linear, input first.
        activations: the `Activation` after each Linear (None: none), one per layer.
    """

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    activations: tuple[Activation | None, ...]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """The output ``[out]`` float32 for one input ``[in]``."""
        h = np.asarray(x, dtype=np.float32).reshape(-1)
        for (w, b), act in zip(self.layers, self.activations, strict=True):
            h = w @ h + b
            if act is not None:
                h = apply_activation(act, h)
        return np.asarray(h, dtype=np.float32)


def mlp_of(seq: Any) -> NumpyMLP:
    """The `NumpyMLP` of a ``torch.nn.Sequential`` of Linear layers and activations (Dropout ignored: inference);
    ValueError for any other module or an activation numpy cannot compute."""
    from torch import nn

    layers: list[tuple[np.ndarray, np.ndarray]] = []
    acts: list[Activation | None] = []
    for m in seq:
        if isinstance(m, nn.Linear):
            layers.append((m.weight.detach().cpu().numpy().astype(np.float32).copy(),
                           m.bias.detach().cpu().numpy().astype(np.float32).copy()))
            acts.append(None)
        elif isinstance(m, nn.Dropout):
            continue
        elif layers and acts[-1] is None:
            acts[-1] = activation_of(m)
        else:
            raise ValueError(f"unexpected module {type(m).__name__} in an MLP")
    if not layers:
        raise ValueError("an MLP without a Linear layer")
    return NumpyMLP(tuple(layers), tuple(acts))


def actor_mlp(model: Any) -> NumpyMLP:
    """The numpy copy of an SB3 TD3 / DDPG model's (or policy's) actor network ``actor.mu`` (its output in
    [-1, 1])."""
    return mlp_of(model.actor.mu)


def sac_actor_mlp(policy: Any) -> NumpyMLP:
    """The numpy copy of an SB3 SAC policy's deterministic actor: ``tanh(mu(latent_pi(obs)))`` (the mode of its
    squashed Gaussian, in [-1, 1])."""
    body = mlp_of(policy.actor.latent_pi) if len(policy.actor.latent_pi) else None
    head = mlp_of([policy.actor.mu])
    layers = (body.layers if body else ()) + head.layers
    acts = (body.activations if body else ()) + (("Tanh", ()),)
    return NumpyMLP(layers, acts)


def _numpy_policy(policy: Any) -> NumpyMLP | None:
    """The numpy actor of a TD3 / DDPG policy with a squashed output or of a SAC policy without gSDE; else None."""
    from stable_baselines3.sac.policies import SACPolicy
    from stable_baselines3.td3.policies import TD3Policy

    try:
        if isinstance(policy, TD3Policy) and policy.squash_output:
            return actor_mlp(policy)
        if isinstance(policy, SACPolicy) and not policy.actor.use_sde:
            return sac_actor_mlp(policy)
    except ValueError:
        return None
    return None


def deterministic_actor(model: Any) -> Callable[[np.ndarray], np.ndarray] | None:
    """The numpy twin of ``model.predict(obs, deterministic=True)[0]`` for one observation, or None when
    ``model`` is not an SB3 TD3 / DDPG / SAC model with a flattened Box observation and a squashed Box action (PPO,
    SAC with gSDE, image or dict observations, other feature extractors: use ``predict``)."""
    from gymnasium import spaces
    from stable_baselines3.common.torch_layers import FlattenExtractor

    policy: Any = getattr(model, "policy", None)
    mlp = _numpy_policy(policy)  # None for anything but a TD3 / DDPG / SAC policy
    if mlp is None:
        return None
    if not isinstance(policy.observation_space, spaces.Box) or not isinstance(policy.action_space, spaces.Box):
        return None
    if not isinstance(policy.actor.features_extractor, FlattenExtractor) or len(policy.observation_space.shape) != 1:
        return None
    low = np.asarray(policy.action_space.low, dtype=np.float32)
    high = np.asarray(policy.action_space.high, dtype=np.float32)
    shape = policy.action_space.shape

    def act(observation: np.ndarray) -> np.ndarray:
        scaled = mlp(observation)
        # SB3's unscale_action, in the same float32 operations.
        return (low + (np.float32(0.5) * (scaled + np.float32(1.0)) * (high - low))).reshape(shape)

    return act
