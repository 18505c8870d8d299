"""The GOOSE agent's network and its file.

Network: SB3's ``MultiInputPolicy`` (SAC or TD3) with `GooseExtractor` in front of the actor and the critics: a
GRU over the roll-out time series of the observation (``[n_time, F]``, see `seal.adversaries.goose.obs`), its last
hidden state concatenated with the curve state and the normalised achieved / desired goals.

File (a zip, written atomically): ``goose.json`` (format, algorithm, `GooseSpec`, network sizes, training
summary) and ``policy.pt`` (the policy's ``state_dict``, read back with ``torch.load(weights_only=True)``). SB3's
own ``.zip`` would unpickle (cloudpickle) spaces and schedules on load; this format holds only JSON and tensors,
and the policy is rebuilt from the JSON.
"""

from __future__ import annotations

import contextlib
import io
import json
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from seal.adversaries.goose.curve import N_ACTION
from seal.adversaries.goose.goals import GOAL_SCALES, MAX_TERM
from seal.adversaries.goose.obs import N_ROLLOUT_FEATURES, observation_space
from seal.adversaries.goose.spec import GooseSpec
from seal.core.atomic import atomic_write_bytes

FORMAT = "seal-goose-agent"
VERSION = 1
ALGOS = ("sac", "td3")


class GooseExtractor(BaseFeaturesExtractor):
    """GRU over the roll-out part of ``observation`` + the rest of it + normalised goals.

    Args:
        observation_space: the GOOSE Dict space.
        n_time, n_features: layout of the roll-out block at the start of ``observation`` (row-major).
        gru_hidden: GRU state size; the output has ``gru_hidden + (obs_dim - n_time * n_features) + 6`` features.
    """

    goal_scale: torch.Tensor  # buffer [6]: scale of the achieved and desired goals

    def __init__(self, observation_space: spaces.Dict, n_time: int, n_features: int, gru_hidden: int = 32) -> None:
        obs_shape = observation_space["observation"].shape
        if obs_shape is None:
            raise ValueError("the GOOSE observation space needs a shaped 'observation' entry")
        obs_dim = int(obs_shape[0])
        n_seq = n_time * n_features
        if obs_dim <= n_seq:
            raise ValueError(f"observation has {obs_dim} values, fewer than the roll-out block {n_time}x{n_features}")
        super().__init__(observation_space, features_dim=gru_hidden + obs_dim - n_seq + 6)
        self.n_time, self.n_features, self.n_seq = n_time, n_features, n_seq
        self.gru = nn.GRU(n_features, gru_hidden, batch_first=True)
        self.register_buffer("goal_scale", torch.as_tensor(np.tile(GOAL_SCALES, 2)))

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        x = observations["observation"]
        seq = x[:, : self.n_seq].reshape(-1, self.n_time, self.n_features)
        _, h = self.gru(seq)
        goals = torch.cat([observations["achieved_goal"], observations["desired_goal"]], dim=1) / self.goal_scale
        return torch.cat([h[-1], x[:, self.n_seq :], goals.clamp(max=MAX_TERM)], dim=1)


def policy_kwargs(spec: GooseSpec, net_arch: list[int], gru_hidden: int) -> dict[str, Any]:
    """SB3 ``policy_kwargs`` for GOOSE (the same for training and for rebuilding from a file)."""
    return {
        "net_arch": list(net_arch),
        "features_extractor_class": GooseExtractor,
        "features_extractor_kwargs": {"n_time": spec.n_time, "n_features": N_ROLLOUT_FEATURES,
                                      "gru_hidden": int(gru_hidden)},
    }


def policy_class(algo: str) -> type[BasePolicy]:
    """SB3 ``MultiInputPolicy`` class of ``algo`` (``"sac"`` or ``"td3"``)."""
    if algo == "sac":
        from stable_baselines3.sac.policies import MultiInputPolicy as SACPolicy

        return SACPolicy
    if algo == "td3":
        from stable_baselines3.td3.policies import MultiInputPolicy as TD3Policy

        return TD3Policy
    raise ValueError(f"GOOSE algo must be one of {ALGOS}, got {algo!r}")


def action_space() -> spaces.Box:
    return spaces.Box(-1.0, 1.0, shape=(N_ACTION,), dtype=np.float32)


@dataclass
class GooseAgent:
    """A loaded GOOSE agent.

    Attributes:
        policy: the SB3 policy (eval mode, CPU).
        spec: the spec it was trained with.
        algo: ``"sac"`` or ``"td3"``.
        meta: the rest of ``goose.json`` (network sizes, training summary).
    """

    policy: BasePolicy
    spec: GooseSpec
    algo: str
    meta: dict[str, Any] = field(default_factory=dict)

    def act(self, observation: dict[str, np.ndarray], deterministic: bool = True) -> np.ndarray:
        """Action ``[12]`` in [-1, 1] for one Dict observation."""
        with _one_thread():
            action, _ = self.policy.predict(observation, deterministic=deterministic)
        return np.asarray(action, dtype=np.float64).reshape(-1)


@contextlib.contextmanager
def _one_thread() -> Iterator[None]:
    """Run torch single-threaded inside the block: for one small forward pass, thread hand-offs cost more than
    they save (2.4 ms vs 15 ms per action on a busy 2-core machine); the previous setting is restored.

    Scoped on purpose, the one thread setting outside entry points: an entry point cannot set it for GOOSE's
    forward passes alone, and a process-wide single thread would change the thread count of the other torch work in
    the same process (ego policies, SEAL's models) in ``seal eval generators`` / ``seal bench generators``."""
    previous = torch.get_num_threads()
    if previous == 1:
        yield
        return
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def build_policy(algo: str, spec: GooseSpec, net_arch: list[int], gru_hidden: int) -> BasePolicy:
    """A freshly initialised policy with the GOOSE spaces and network."""
    cls = policy_class(algo)
    return cls(observation_space(spec), action_space(), lambda _: 0.0, **policy_kwargs(spec, net_arch, gru_hidden))


def save_goose_agent(
    path: str | Path, policy: BasePolicy, algo: str, spec: GooseSpec, net_arch: list[int], gru_hidden: int,
    summary: dict[str, Any] | None = None,
) -> None:
    """Write the agent file atomically (see the module docstring)."""
    meta = {
        "format": FORMAT, "version": VERSION, "algo": algo, "spec": spec.to_dict(), "net_arch": list(net_arch),
        "gru_hidden": int(gru_hidden), "summary": summary or {},
    }
    weights = io.BytesIO()
    torch.save({k: v.detach().cpu() for k, v in policy.state_dict().items()}, weights)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("goose.json", json.dumps(meta, indent=2, sort_keys=True, default=float))
        zf.writestr("policy.pt", weights.getvalue())
    atomic_write_bytes(path, buf.getvalue())


def load_goose_agent(path: str | Path) -> GooseAgent:
    """Read an agent file written by `save_goose_agent`; errors name the file and the bad field."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"GOOSE agent file {path} does not exist (train one with `seal fit goose`)")
    try:
        with zipfile.ZipFile(path) as zf:
            meta = json.loads(zf.read("goose.json"))
            raw = zf.read("policy.pt")
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a GOOSE agent file (zip with goose.json and policy.pt): {exc}") from None
    if meta.get("format") != FORMAT:
        raise ValueError(f"{path}: field 'format' is {meta.get('format')!r}, expected {FORMAT!r}")
    if meta.get("version") != VERSION:
        raise ValueError(f"{path}: field 'version' is {meta.get('version')!r}, this seal reads {VERSION}")
    for key in ("algo", "spec", "net_arch", "gru_hidden"):
        if key not in meta:
            raise ValueError(f"{path}: field {key!r} is missing from goose.json")
    # Files written before these options replayed the logged speed profile and observed no control-point targets.
    spec = GooseSpec.from_dict({"timing": "log", "obs_targets": False, **meta["spec"]}, where=f"{path}: field 'spec'")
    policy = build_policy(meta["algo"], spec, meta["net_arch"], meta["gru_hidden"])
    state = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    try:
        policy.load_state_dict(state)
    except RuntimeError as exc:
        raise ValueError(f"{path}: policy.pt does not match the network in goose.json: {exc}") from None
    policy.set_training_mode(False)
    return GooseAgent(policy, spec, meta["algo"], {k: v for k, v in meta.items() if k not in ("spec", "algo")})
