"""The generator interface and the name registry used by configs and the CLI.

A generator sees the base scenario, that scenario's queue of the last K ego roll-outs (most recent last) and an
rng, and returns the adversary's behaviour for the next episode plus metadata. It never sees the upcoming ego
plan: roll-outs are past episodes only.
"""

from __future__ import annotations

import importlib
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from seal.core.scenario import Scenario
from seal.envs.behaviors import AdversaryBehavior
from seal.envs.rollout import Rollout

K_ROLLOUTS = 5
"""Length of the per-scenario ego roll-out queue (CAT / SEAL)."""


@dataclass
class Generation:
    """A generator's output for one episode.

    Attributes:
        behavior: drives the adversary in the next episode.
        chosen_candidate: index of the chosen candidate trajectory, or None when not candidate-based.
        predicted_step: predicted collision / closest-approach step (scenario step index), or None.
        generation_time_s: wall-clock seconds spent in `AdversaryGenerator.generate`.
        extra: generator-specific JSON-serialisable details.
    """

    behavior: AdversaryBehavior
    chosen_candidate: int | None = None
    predicted_step: int | None = None
    generation_time_s: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)


class AdversaryGenerator(ABC):
    """Base class: subclasses implement `_generate`; `generate` times it."""

    name: ClassVar[str]

    def generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        """Adversary behaviour for the next episode of ``scenario`` given the past ego roll-outs."""
        start = time.perf_counter()
        generation = self._generate(scenario, history, rng)
        generation.generation_time_s = time.perf_counter() - start
        return generation

    @abstractmethod
    def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        ...


_REGISTRY: dict[str, Callable[..., AdversaryGenerator]] = {}

GENERATOR_MODULES: dict[str, str] = {
    "replay": "seal.adversaries.replay",
    "rule": "seal.adversaries.rule",
    "cat": "seal.adversaries.cat.generator",
    "goose": "seal.adversaries.goose.generator",
    "seal": "seal.adversaries.seal.generator",
}
"""Module that registers each built-in generator, imported on first lookup (so a name resolves without importing
every generator, and even when ``adversaries/__init__.py`` did not run). Add a line per new generator."""


def register(name: str) -> Callable[[type[AdversaryGenerator]], type[AdversaryGenerator]]:
    """Class decorator: make a generator available as ``name`` in configs and on the command line."""

    def decorate(cls: type[AdversaryGenerator]) -> type[AdversaryGenerator]:
        if name in _REGISTRY:
            raise ValueError(f"generator name {name!r} is already registered")
        cls.name = name
        _REGISTRY[name] = cls
        return cls

    return decorate


def available_generators() -> list[str]:
    return sorted(set(_REGISTRY) | set(GENERATOR_MODULES))


def generator_class(name: str) -> Callable[..., AdversaryGenerator]:
    """The class (factory) registered as ``name``; unknown names get an error listing the known ones."""
    if name not in _REGISTRY and name in GENERATOR_MODULES:
        importlib.import_module(GENERATOR_MODULES[name])
    if name not in _REGISTRY:
        raise ValueError(f"unknown generator {name!r}; available: {', '.join(available_generators())}")
    return _REGISTRY[name]


def make_generator(name: str, **kwargs: Any) -> AdversaryGenerator:
    """Instantiate a registered generator; unknown names get an error listing the known ones."""
    return generator_class(name)(**kwargs)
