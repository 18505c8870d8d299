"""Load any Stable-Baselines3 model file for inference without unpickling it.

An SB3 ``.zip`` keeps its settings in the JSON entry ``data``; whatever JSON cannot hold (spaces, the policy class,
``policy_kwargs`` with an activation class, schedules, the last observation, episode buffers) is cloudpickled
there, which would run arbitrary code on load. `load_sb3_model` replaces every pickled entry before SB3 sees it:

* spaces: the ego's observation (100 floats) and action (``[steering, acceleration]``) spaces, after checking the
  shapes the file records in plain JSON beside the pickle;
* the policy class: the algorithm's ``MlpPolicy``; buffer classes: SB3's plain ones, with a 1-transition replay
  buffer and none of the training buffer's settings (n-step returns); schedules: a constant (inference);
* ``policy_kwargs``: rebuilt from the JSON copy SB3 writes beside the pickle; classes are accepted by name from
  `SAFE_CLASSES` (``torch.nn`` activations, ``torch.optim`` optimisers) and nothing else;
* training-only state (`TRAINING_STATE`: last observation, episode buffers, action noise): dropped;
* anything else: refused, naming the entry and what to do.

Parameters are read by SB3 with ``torch.load(weights_only=True)``. The algorithm comes from ``--algo``, else the
run's ``config.yaml`` (a seal run folder or checkpoint), else the file itself (`infer_algo`). VecNormalize
statistics saved beside the model (`VECNORMALIZE_FILES`) are read with seal's restricted unpickler
(`read_vecnormalize`) and applied to every observation (`ObsNormalizer`).
"""

from __future__ import annotations

import json
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from seal.core.errors import SealError
from seal.experiments.training.zoo import ACTIVATIONS

MODEL_FILES = ("model.zip", "final_model.zip", "best_model.zip")
CONFIG_FILES = ("config.yaml", "config.yml")
VECNORMALIZE_FILES = ("vecnormalize.pkl", "vec_normalize.pkl")
"""Names of VecNormalize statistics beside a model (rl-zoo writes ``vecnormalize.pkl``)."""
ALGOS = ("TD3", "SAC", "DDPG", "PPO", "A2C")
"""SB3 algorithms with continuous actions that seal can evaluate."""
TRAINING_STATE = (
    "_last_obs", "_last_original_obs", "_last_episode_starts", "ep_info_buffer", "ep_success_buffer",
    "action_noise", "_episode_storage",
)
"""Pickled entries that only training uses: dropped for inference."""
SCHEDULES = ("learning_rate", "lr_schedule", "clip_range", "clip_range_vf", "exploration_schedule")
_OPTIMIZERS = ("Adam", "AdamW", "RMSprop", "SGD")
_CONFIG_SEARCH_DEPTH = 3
"""Folders above a model searched for a run config (``RUN/checkpoints/step_N/model.zip`` is three deep)."""


class ModelLoadError(SealError, ValueError):
    """An SB3 model file cannot be loaded safely or does not fit the ego's spaces."""


def safe_classes() -> dict[str, Any]:
    """``"<class 'torch.nn.modules.activation.ReLU'>"`` (SB3's text for a class) -> the class, for the classes a
    ``policy_kwargs`` may name."""
    import torch

    out: dict[str, Any] = {}
    for name in ACTIVATIONS:
        cls = getattr(torch.nn, name)
        out[f"<class '{cls.__module__}.{cls.__qualname__}'>"] = cls
    for name in _OPTIMIZERS:
        cls = getattr(torch.optim, name)
        out[f"<class '{cls.__module__}.{cls.__qualname__}'>"] = cls
    return out


def find_model(path: Path) -> Path:
    """``path`` itself if a file, else the first of `MODEL_FILES` in the folder ``path``."""
    if path.is_file():
        return path
    for name in MODEL_FILES:
        if (path / name).is_file():
            return path / name
    raise FileNotFoundError(f"run folder {path} has none of {', '.join(MODEL_FILES)}")


def find_run_config(model: Path) -> tuple[Path, dict[str, Any]] | None:
    """The nearest ``config.yaml`` at most `_CONFIG_SEARCH_DEPTH` folders above ``model`` that names an ``algo``
    (a seal run folder, its final model or a checkpoint), with its contents; None when there is none."""
    folder = model.parent
    for _ in range(_CONFIG_SEARCH_DEPTH):
        for name in CONFIG_FILES:
            cfg_path = folder / name
            if cfg_path.is_file():
                cfg = yaml.safe_load(cfg_path.read_text()) or {}
                if isinstance(cfg, dict) and (cfg.get("algo") or cfg.get("algorithm")):
                    return cfg_path, cfg
        folder = folder.parent
    return None


def read_data(model: Path) -> dict[str, Any]:
    """The JSON ``data`` entry of an SB3 model zip (nothing unpickled)."""
    try:
        with zipfile.ZipFile(model) as zf:
            return dict(json.loads(zf.read("data")))
    except (zipfile.BadZipFile, KeyError, json.JSONDecodeError) as exc:
        raise ModelLoadError(f"{model}: not a Stable-Baselines3 model file ({type(exc).__name__}: {exc})") from None


def infer_algo(model: Path, data: dict[str, Any] | None = None) -> str | None:
    """The algorithm of an SB3 zip from its own contents: the policy class's module
    (``stable_baselines3.sac.policies`` -> SAC) or, for the shared actor-critic policy, PPO's ``n_epochs`` /
    ``clip_range`` (else A2C); None when the file does not say."""
    data = read_data(model) if data is None else data
    module = str((data.get("policy_class") or {}).get("__module__", ""))
    match = re.fullmatch(r"stable_baselines3\.(\w+)\.policies", module)
    if match and match.group(1).upper() in ALGOS:
        return match.group(1).upper()
    if module == "stable_baselines3.common.policies":
        return "PPO" if ("n_epochs" in data or "clip_range" in data) else "A2C"
    return None


def resolve_algo(model: Path, algo: str | None = None) -> str:
    """``algo`` if given, else the run config's ``algo``, else `infer_algo`; upper case."""
    if algo:
        return str(algo).upper()
    found = find_run_config(model)
    if found is not None:
        cfg_path, cfg = found
        return str(cfg.get("algo") or cfg.get("algorithm")).upper()
    inferred = infer_algo(model)
    if inferred is None:
        raise ModelLoadError(f"{model}: cannot tell which SB3 algorithm saved it; pass --algo "
                             f"({'|'.join(a.lower() for a in ALGOS)})")
    return inferred


def _policy_kwargs(model: Path, entry: dict[str, Any]) -> dict[str, Any]:
    """``policy_kwargs`` from the JSON copy beside its pickle: plain values as they are, classes by name."""
    classes = safe_classes()
    out: dict[str, Any] = {}
    for key, value in entry.items():
        if key.startswith(":"):
            continue
        if isinstance(value, str) and value.startswith("<class "):
            if value not in classes:
                raise ModelLoadError(
                    f"{model}: policy_kwargs[{key!r}] = {value} cannot be rebuilt safely (allowed: torch.nn "
                    f"activations {', '.join(ACTIVATIONS)}; torch.optim {', '.join(_OPTIMIZERS)}); evaluate the "
                    "policy from Python instead (seal.experiments.evaluation.policies.evaluate_policy)"
                )
            out[key] = classes[value]
        elif isinstance(value, str) and value.startswith("<"):
            raise ModelLoadError(f"{model}: policy_kwargs[{key!r}] = {value} is an object that cannot be rebuilt "
                                 "safely; evaluate the policy from Python instead")
        else:
            out[key] = value
    return out


def _check_shape(model: Path, key: str, entry: dict[str, Any], want: tuple[int, ...]) -> None:
    shape = entry.get("_shape")
    if shape is not None and tuple(shape) != want:
        raise ModelLoadError(f"{model}: {key} has shape {tuple(shape)}, seal's ego needs {want} (the observation "
                             "of seal/Scenario-v0, with the deadline slots for a time-aware ego, and [steering, "
                             "acceleration] actions)")


def _ego_observation_space(data: dict[str, Any]) -> Any:
    """The ego observation space a saved model was trained on: the observation, or a time-aware ego's observation
    plus the deadline slots (`seal.envs.deadline`), told apart by the stored shape."""
    from seal.envs.deadline import DEADLINE_OBS_DIM, deadline_observation_space
    from seal.envs.observation import observation_space

    entry = data.get("observation_space")
    shape = entry.get("_shape") if isinstance(entry, dict) else None
    return deadline_observation_space() if shape is not None and tuple(shape) == (DEADLINE_OBS_DIM,) \
        else observation_space()


def load_sb3_model(path: Path, algo_name: str | None = None, observation_space: Any = None,
                   action_space: Any = None) -> Any:
    """Load an SB3 model for inference without unpickling anything (module docstring). ``path``: a model zip or
    a folder holding one (`MODEL_FILES`); ``algo_name`` (default: `resolve_algo`) and the spaces (default: the
    ego's observation and ``[steering, acceleration]``) are for models of other shapes (the ReSkill agents)."""
    import stable_baselines3 as sb3
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer

    model_path = find_model(Path(path))
    algo_name = resolve_algo(model_path, algo_name)
    algo = getattr(sb3, algo_name, None)
    if algo is None or algo_name not in ALGOS:
        raise ModelLoadError(f"{model_path}: unknown SB3 algorithm {algo_name!r}; one of "
                             f"{', '.join(a.lower() for a in ALGOS)}")
    data = read_data(model_path)
    obs_space = observation_space if observation_space is not None else _ego_observation_space(data)
    act_space = action_space if action_space is not None else spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
    safe: dict[str, Any] = {
        "observation_space": obs_space, "action_space": act_space,
        "policy_class": algo.policy_aliases["MlpPolicy"],
        "rollout_buffer_class": RolloutBuffer, "replay_buffer_class": ReplayBuffer, "train_freq": (1, "step"),
    }
    # Inference only: a 1-transition plain replay buffer instead of allocating the training-size one. Its
    # settings go too: an n-step buffer's (n_steps, gamma) do not fit SB3's plain ReplayBuffer, and pickled ones
    # would become None, which SB3 cannot copy.
    custom: dict[str, Any] = {key: value for key, value in (("buffer_size", 1), ("replay_buffer_kwargs", {}))
                              if key in data}
    for key, value in data.items():
        if not (isinstance(value, dict) and ":serialized:" in value):
            continue
        if key in ("observation_space", "action_space"):
            _check_shape(model_path, key, value, tuple(safe[key].shape))
        if key in custom:
            continue
        if key in safe:
            custom[key] = safe[key]
        elif key == "policy_kwargs":
            custom[key] = _policy_kwargs(model_path, value)
        elif key.endswith("schedule") or key in SCHEDULES:
            custom[key] = _constant_zero
        elif key in TRAINING_STATE:
            custom[key] = None
        else:
            raise ModelLoadError(
                f"{model_path}: entry {key!r} is pickled and cannot be loaded safely; re-save the model without "
                f"it (model.save(path, exclude=[{key!r}])) or evaluate the policy from Python "
                "(seal.experiments.evaluation.policies.evaluate_policy)"
            )
    if "policy_kwargs" in data and not isinstance(data["policy_kwargs"], dict):
        custom["policy_kwargs"] = {}
    return algo.load(model_path, device="cpu", custom_objects=custom)


def _constant_zero(_progress: float) -> float:
    return 0.0


# ------------------------------------------------------------------------------------------------ VecNormalize
@dataclass(frozen=True)
class ObsNormalizer:
    """VecNormalize's observation normalisation: ``clip((obs - mean) / sqrt(var + epsilon), -clip, clip)``.

    Attributes:
        mean: running mean of the observations ``[100]``.
        var: running variance ``[100]``.
        epsilon: added to the variance.
        clip_obs: bound of the normalised observation.
    """

    mean: np.ndarray
    var: np.ndarray
    epsilon: float
    clip_obs: float

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        obs = np.asarray(observation, dtype=np.float64)
        return np.clip((obs - self.mean) / np.sqrt(self.var + self.epsilon), -self.clip_obs, self.clip_obs)


class _Record:
    """Stand-in for every object of a VecNormalize pickle: keeps the state pickle gives it, runs nothing."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args

    def __new__(cls, *args: Any, **kwargs: Any) -> _Record:
        return super().__new__(cls)

    def __setstate__(self, state: Any) -> None:
        if isinstance(state, dict):
            self.__dict__.update(state)
        else:  # a bit generator's tuple state and the like: kept, never interpreted
            self.__dict__["state"] = state


_VECNORMALIZE_NAMES = (
    ("stable_baselines3.common.vec_env.vec_normalize", "VecNormalize"),
    ("stable_baselines3.common.running_mean_std", "RunningMeanStd"),
    ("gymnasium.spaces.box", "Box"), ("gymnasium.spaces.dict", "Dict"),
    ("numpy.random._pickle", "__generator_ctor"), ("numpy.random._pickle", "__bit_generator_ctor"),
    ("numpy.random._pickle", "__randomstate_ctor"), ("numpy.random._pcg64", "PCG64"),
    ("numpy.random.bit_generator", "__pyx_unpickle_SeedSequence"), ("numpy.random.bit_generator", "SeedSequence"),
    ("numpy.random._mt19937", "MT19937"), ("numpy.random._philox", "Philox"), ("numpy.random._sfc64", "SFC64"),
)
"""What a VecNormalize pickle names besides numpy arrays (its class, the running statistics, the spaces and their
random generators: numpy pickles a ``Generator`` or ``RandomState`` through its ``_pickle`` constructors, never by
class name): each becomes an inert `_Record`."""


def find_vecnormalize(model: Path) -> Path | None:
    """VecNormalize statistics beside ``model`` or in its run folder (`VECNORMALIZE_FILES`), if any."""
    for folder in (model.parent, model.parent.parent):
        for name in VECNORMALIZE_FILES:
            if (folder / name).is_file():
                return folder / name
    return None


def read_vecnormalize(path: Path) -> ObsNormalizer | None:
    """The observation statistics of a saved ``VecNormalize`` (None when it did not normalise observations).
    Unpickled with seal's restricted unpickler: numpy arrays, plain containers and inert stand-ins for
    VecNormalize's own classes; anything else is refused."""
    from seal.core.importers.safe_pickle import safe_load

    state = safe_load(path, extra={name: _Record for name in _VECNORMALIZE_NAMES})
    attrs = vars(state) if isinstance(state, _Record) else {}
    if not attrs.get("norm_obs", True):
        return None
    rms = attrs.get("obs_rms")
    stats = vars(rms) if isinstance(rms, _Record) else {}
    if "mean" not in stats or "var" not in stats:
        raise ModelLoadError(f"{path}: not a VecNormalize file (no obs_rms with mean / var); for a dict "
                             "observation space, evaluate the policy from Python")
    return ObsNormalizer(np.asarray(stats["mean"], np.float64), np.asarray(stats["var"], np.float64),
                         float(attrs.get("epsilon", 1e-8)), float(attrs.get("clip_obs", 10.0)))
