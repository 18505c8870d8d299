"""The X-Gen evaluation protocol, once: the same (scenario, scenario index, ego, generator, seed) give the same
episodes wherever they are played (``seal eval generators``, ``seal eval runs``, the report's videos).

Per scenario (the ``index``-th of its split): one normal episode against the logged adversary, env seed
`episode_seed_of` ``(seed, index)``; then K sequential perturbation passes of a generator against the same ego,
each roll-out appended to the scenario's queue (which starts with the normal episode), pass ``j`` seeded
``episode_seed_of(seed, index) + 1 + j``; the generator draws from ``default_rng([seed, index, crc32(name)])``
with ``name`` the generator's registered name, so a generator's stream does not depend on which other generators
or settings are evaluated beside it. The last pass is the one scored (ARCHITECTURE.md, evaluation).
"""

from __future__ import annotations

import inspect
import zlib
from collections.abc import Mapping
from typing import Any

import numpy as np

from seal.adversaries.base import AdversaryGenerator, expand_user_paths, generator_class
from seal.adversaries.history import RolloutHistory
from seal.core.scenario import Scenario
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.episodes import PassRecord, perturbation_passes, run_episode
from seal.experiments.training.egos import Ego


def generator_name(label: str, kwargs: Mapping[str, Any]) -> str:
    """The registered generator behind a ``generators`` entry: its ``generator`` key, else the label itself."""
    return str(kwargs.get("generator", label))


def build_generator(name: str, kwargs: Mapping[str, Any], shared: Mapping[str, Any]) -> AdversaryGenerator:
    """Instantiate entry ``name`` (a generator name, or a label whose ``kwargs`` name the generator) with
    ``kwargs`` plus each ``shared`` option (None = not given) its constructor accepts (string options starting
    with ``~`` expanded, `expand_user_paths`)."""
    cls = generator_class(generator_name(name, kwargs))
    kwargs = {k: v for k, v in kwargs.items() if k != "generator"}
    params = inspect.signature(cls).parameters
    merged = {k: v for k, v in shared.items() if v is not None and k in params and k not in kwargs}
    return cls(**expand_user_paths({**merged, **kwargs}))


def generator_stream(name: str) -> int:
    """A stable rng stream id per generator name (independent of the order of generators / settings)."""
    return zlib.crc32(name.encode())


def episode_seed_of(seed: int, index: int) -> int:
    """Env seed of the normal episode of the ``index``-th scenario of a split (passes use the next K seeds)."""
    return seed * 1_000_003 + 1000 * index


def normal_episode(env: ScenarioEnv, scenario: Scenario, index: int, ego: Ego, seed: int) -> Rollout:
    """The normal episode (logged adversary) of the ``index``-th scenario of its split."""
    return run_episode(env, scenario, ego, seed=episode_seed_of(seed, index))


def generator_passes(
    env: ScenarioEnv, scenario: Scenario, index: int, ego: Ego, generator: AdversaryGenerator, k: int, seed: int,
    normal: Rollout,
) -> list[PassRecord]:
    """The K sequential perturbation passes of ``generator`` against ``ego`` after the ``normal`` episode of the
    ``index``-th scenario of its split; the last one is scored. Deterministic for (seed, index, generator name)."""
    history = RolloutHistory(k)
    history.append(scenario, normal)
    rng = np.random.default_rng([seed, index, generator_stream(generator.name)])
    return perturbation_passes(env, scenario, ego, generator, history, rng, k, seed=episode_seed_of(seed, index))


def scored_pass(
    env: ScenarioEnv, scenario: Scenario, index: int, ego: Ego, generator: AdversaryGenerator, k: int, seed: int,
    normal: Rollout,
) -> tuple[Rollout, list[float]]:
    """`generator_passes`' last (scored) roll-out and the generation times (s) of all K passes."""
    passes = generator_passes(env, scenario, index, ego, generator, k, seed, normal)
    return passes[-1].rollout, [p.generation.generation_time_s for p in passes]
