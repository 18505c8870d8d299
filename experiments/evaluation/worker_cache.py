"""What the evaluation chunks one process plays share (`seal.experiments.evaluation.parallel`): the egos, the
splits, the envs and the generators, kept for one evaluation session.

Loading a trained ego or building a generator (a prior, a GOOSE agent, skill models) costs more than a chunk of
episodes, so a worker keeps them across its chunks. Everything is dropped when a new session starts (`use_session`:
a token per `seal eval runs` call), so a later evaluation in the same process never sees an earlier one's egos,
datasets or generator state. Generators are kept per ego, as one process builds them once per ego; their state is
per scenario (e.g. GOOSE's kept curves), and a scenario never spans two chunks.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

from seal.core.scenario import Scenario

_CACHE: dict[str, dict[Any, Any]] = {"egos": {}, "splits": {}, "envs": {}, "generators": {}}
_SESSION: dict[str, str] = {"token": ""}


def use_session(token: str) -> None:
    """Make ``token`` this process's evaluation session; a new token drops everything cached for the last one."""
    if token != _SESSION["token"]:
        for cache in _CACHE.values():
            for value in cache.values():
                close = getattr(value, "close", None)
                if callable(close) and cache is _CACHE["envs"]:
                    close()
            cache.clear()
        _SESSION["token"] = token


def cached_ego(spec: str, algo: str | None = None) -> Any:
    """`seal.experiments.training.egos.make_ego` of ``spec`` (egos act deterministically: one serves every chunk)."""
    from seal.experiments.training.egos import make_ego

    egos = _CACHE["egos"]
    if (spec, algo) not in egos:
        egos[(spec, algo)] = make_ego(spec, algo)
    return egos[(spec, algo)]


def cached_split(dataset: str, split: str | None, limit: int | None) -> list[Scenario]:
    """`seal.core.dataset.load_split` of (dataset, split, limit)."""
    from seal.core.dataset import load_split

    splits, key = _CACHE["splits"], (dataset, split, limit)
    if key not in splits:
        splits[key] = load_split(dataset, split, limit)
    return splits[key]


def cached_env(dataset: str, split: str | None, config: Mapping[str, Any], reactive: bool = False) -> Any:
    """One `ScenarioEnv` per (dataset, split, env config): every episode resets it with its own seed, so one env
    serves every ego and chunk alike. ``reactive``: the env of ``normal-reactive`` (config ``background``, and
    ``background_model`` for ``rapid``)."""
    from seal.envs.scenario_env import ScenarioEnv

    env_config = dict(config.get("env") or {})
    model = None
    if reactive:
        env_config["background"] = config.get("background", "idm")
        if env_config["background"] == "rapid":
            from seal.models.rapid import load_rapid

            model = load_rapid(str(config["background_model"]))
    envs, key = _CACHE["envs"], (dataset, split, json.dumps(env_config, sort_keys=True, default=str),
                                 config.get("background_model") if reactive else None)
    if key not in envs:
        envs[key] = ScenarioEnv(cached_split(dataset, split, config.get("limit")), config=env_config,
                                background_model=model)
    return envs[key]


def cached_generator(run: str, name: str, config: Mapping[str, Any], setting: str = "") -> Any:
    """Generator ``name`` for ego ``run`` (built once per ego, as one process does); ``setting``: one instance per
    setting that uses it (``cat`` and ``cat-reactive`` each get their own: some generators keep per-scenario
    state across the K passes)."""
    from seal.experiments.evaluation.protocol import build_generator

    kwargs = config["generators"].get(name, {})
    gens, key = _CACHE["generators"], (run, name, setting, json.dumps(kwargs, sort_keys=True, default=str))
    if key not in gens:
        shared = {"prior": config.get("prior"), "candidates": config.get("candidates")}
        gens[key] = build_generator(name, kwargs, shared)
    return gens[key]
