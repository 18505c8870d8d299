"""Configuration of ``seal train``: the ``train:`` section of a preset YAML (``experiments/configs/<preset>.yaml``)
resolved for one pipeline and seed.

Resolution: `DEFAULTS` < the file's ``train:`` section < overrides (dotted keys, e.g.
``{"pipeline": "cat", "seed": 1, "hyperparams.td3.learning_starts": 500}``). The resolved config (what a run
folder's ``config.yaml`` records) keeps the chosen algorithm's hyper-parameters only and the pipeline's generator
as ``generator: {name, kwargs}`` (``name`` None for ``noadv``). Other top-level sections of a preset file
(``data``, ``fit``, ``eval``, ``pipelines``, ``seeds``) belong to the orchestrator and are not read here.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

ALGOS = ("td3", "sac", "ppo")
PIPELINES = ("noadv", "goose", "cat", "seal")

DEFAULTS: dict[str, Any] = {
    "algo": "td3",
    "pipeline": "cat",
    "seed": 0,
    "total_timesteps": 1_000_000,
    "dataset": None,
    "train_split": "train",
    "train_limit": None,
    "eval_split": "eval",
    "n_envs": None,
    "k": 5,
    "curriculum": {"slope": 1.8, "cap": 0.9},
    "env": {"terminate_on_crash": False},
    "eval_env": {"terminate_on_crash": True},
    "eval_every": 50_000,
    "eval_episodes": 100,
    "checkpoint_every": 50_000,
    "torch_threads": 1,
    "device": "cpu",
    "hyperparams": {
        "td3": {
            "learning_rate": 3e-4, "gamma": 0.99, "tau": 0.005, "batch_size": 256, "learning_starts": 10_000,
            "buffer_size": 1_000_000, "net_arch": [256, 256], "train_freq": 1, "gradient_steps": -1,
            "policy_delay": 2, "action_noise_std": 0.1,
        },
        "sac": {
            "learning_rate": 3e-4, "gamma": 0.99, "tau": 0.005, "batch_size": 256, "learning_starts": 10_000,
            "buffer_size": 1_000_000, "net_arch": [256, 256], "train_freq": 1, "gradient_steps": -1,
            "ent_coef": "auto",
        },
        "ppo": {
            "learning_rate": 3e-4, "gamma": 0.99, "n_steps": 1024, "batch_size": 256, "n_epochs": 10,
            "gae_lambda": 0.95, "clip_range": 0.2, "ent_coef": 0.0, "net_arch": [256, 256],
        },
    },
    "pipelines": {
        "noadv": None,
        "goose": {"name": "goose", "kwargs": {"model": None}},
        "cat": {"name": "cat", "kwargs": {"prior": None}},
        "seal": {"name": "seal", "kwargs": {"prior": None, "objective": None, "skills": None}},
    },
}
"""Keys of the ``train:`` section:

* ``algo``: td3 | sac | ppo (SB3); ``hyperparams.<algo>``: its settings. Off-policy: ``train_freq`` in vec-env
  steps (each is ``n_envs`` env steps), ``gradient_steps`` per training call (-1: as many as env steps collected,
  i.e. one gradient step per env step as in CAT), ``action_noise_std`` (TD3: Gaussian exploration noise, 0 = none).
* ``pipeline``: noadv | goose | cat | seal; ``pipelines.<name>``: ``{name: generator, kwargs: {...}}`` (None for
  noadv); paths in the kwargs (prior, GOOSE model, objective, skills) are filled in by the preset or ``seal run``.
* ``seed``; ``total_timesteps``: env steps of the run (a multiple of ``n_envs``; PPO: of ``n_envs * n_steps``).
* ``dataset``: dataset directory; ``train_split`` / ``train_limit``: the training scenarios (first N of the split);
  ``eval_split``: the Normal evaluation split; ``eval_every`` (env steps, 0 = never) / ``eval_episodes`` (the first
  N scenarios of the split, one deterministic episode each).
* ``n_envs``: env worker processes (None: the machine's cores); ``k``: roll-out queue length.
* ``curriculum``: ``slope`` and ``cap`` of p(t) = min(slope t / T, cap).
* ``env`` / ``eval_env``: `ScenarioEnv` config overrides for training (CAT: episodes go on after a crash) and
  evaluation (a crash ends the episode).
* ``checkpoint_every``: env steps between checkpoints (model, replay buffer, queues, rng); ``torch_threads``;
  ``device``.
"""

RESOLVED_ONLY = ("generator", "preset", "hyperparams")


def _merge(base: dict[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Deep merge; a pipeline entry that names its generator (``pipelines.X: {name: ...}``) replaces the old
    entry whole (its kwargs belong to that generator), one without ``name`` (``pipelines.X.kwargs.prior``) merges."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if k == "pipelines" and isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = {**out[k]}
            for name, spec in v.items():
                keep = isinstance(spec, Mapping) and "name" not in spec and isinstance(out[k].get(name), dict)
                out[k][name] = _merge(out[k][name], spec) if keep else copy.deepcopy(spec)
        elif isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _check_keys(given: Mapping[str, Any], known: Mapping[str, Any], where: str) -> None:
    unknown = sorted(set(given) - set(known))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")


def _dotted(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``{"a.b": 1}`` -> ``{"a": {"b": 1}}`` (plain keys kept)."""
    nested: dict[str, Any] = {}
    for key, value in overrides.items():
        parts = key.split(".")
        node = nested
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return nested


PRESETS = ("quick", "standard", "paper")
DEFAULT_PRESET = "standard"


def preset_path(name_or_path: str | Path) -> Path:
    """A preset name (quick | standard | paper) -> ``experiments/configs/<name>.yaml`` of the installed package;
    anything else is taken as a path."""
    from seal.experiments.presets import CONFIG_DIR

    text = str(name_or_path)
    return CONFIG_DIR / f"{text}.yaml" if text in PRESETS else Path(text)


def read_train_section(path: str | Path) -> dict[str, Any]:
    """The ``train:`` mapping of the YAML file ``path`` (keys checked against `DEFAULTS`)."""
    path = preset_path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"--config {path}: no such file (presets: experiments/configs/quick|standard|paper.yaml)"
        )
    loaded = yaml.safe_load(path.read_text()) or {}
    if not isinstance(loaded, dict) or not isinstance(loaded.get("train"), dict):
        raise ValueError(f"{path}: no 'train:' section (a mapping of the keys of "
            f"seal.experiments.training.config.DEFAULTS)")
    section = loaded["train"]
    _check_keys(section, DEFAULTS, f"{path}: train")
    return section


def load_train_config(path: str | Path, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Resolve the run config from the preset file ``path`` (or a preset name, `preset_path`; its ``train:``
    section) and ``overrides`` (dotted keys; None values ignored): `DEFAULTS` < file < overrides, then `resolve`.
    ``preset`` is the file's stem."""
    section = read_train_section(path)
    given = _dotted({k: v for k, v in (overrides or {}).items() if v is not None})
    _check_keys(given, DEFAULTS, "train config overrides")
    config = _merge(_merge(DEFAULTS, section), given)
    return resolve(config, preset=preset_path(path).stem)


def resolve(config: Mapping[str, Any], preset: str) -> dict[str, Any]:
    """Validate a merged config and reduce it to the run's settings (module docstring)."""
    c = dict(config)
    algo = str(c["algo"]).lower()
    if algo not in ALGOS:
        raise ValueError(f"train.algo must be one of {ALGOS}, got {c['algo']!r}")
    pipeline = str(c["pipeline"])
    if pipeline not in c["pipelines"]:
        raise ValueError(f"--pipeline must be one of {sorted(c['pipelines'])}, got {pipeline!r}")
    spec = c["pipelines"][pipeline]
    if spec is None:
        generator: dict[str, Any] = {"name": None, "kwargs": {}}
    else:
        if not isinstance(spec, Mapping) or "name" not in spec:
            raise ValueError(f"train.pipelines.{pipeline}: expected {{name: GENERATOR, kwargs: {{...}}}} or null")
        generator = {"name": str(spec["name"]), "kwargs": dict(spec.get("kwargs") or {})}
    for key in ("total_timesteps", "k", "eval_episodes", "torch_threads"):
        if int(c[key]) < 1:
            raise ValueError(f"train.{key} must be >= 1, got {c[key]}")
    for key in ("eval_every", "checkpoint_every"):
        if int(c[key]) < 0:
            raise ValueError(f"train.{key} must be >= 0, got {c[key]}")
    if c["n_envs"] is not None and int(c["n_envs"]) < 1:
        raise ValueError(f"train.n_envs must be >= 1 or null (all cores), got {c['n_envs']}")
    _check_keys(c["curriculum"], DEFAULTS["curriculum"], "train.curriculum")
    hyper = dict(c["hyperparams"].get(algo) or {})
    _check_keys(hyper, DEFAULTS["hyperparams"][algo], f"train.hyperparams.{algo}")
    hyper = {**DEFAULTS["hyperparams"][algo], **hyper}
    out = {k: v for k, v in c.items() if k not in ("pipelines", "hyperparams")}
    out.update(algo=algo, pipeline=pipeline, seed=int(c["seed"]), total_timesteps=int(c["total_timesteps"]),
               generator=generator, hyperparams=hyper, preset=preset)
    return out


def check_resolved(config: Mapping[str, Any], source: str) -> dict[str, Any]:
    """A run folder's recorded config (``source`` names the file), checked for the keys a run needs."""
    if not isinstance(config, Mapping):
        raise ValueError(f"{source}: expected a mapping")
    need = set(DEFAULTS) - {"pipelines"} | set(RESOLVED_ONLY)
    missing = sorted(need - set(config))
    if missing:
        raise ValueError(f"{source}: missing key(s) {missing}; not a `seal train` run config")
    return dict(config)
