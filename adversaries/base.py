"""The generator interface and the name registry used by configs and the CLI.

A generator sees the base scenario, that scenario's queue of the last K ego roll-outs (most recent last) and an
rng, and returns the adversary's behaviour for the next episode plus metadata. It never sees the upcoming ego
plan: roll-outs are past episodes only.
"""

from __future__ import annotations

import importlib
import os
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
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

@dataclass(frozen=True)
class GeneratorOption:
    """One constructor option of a generator, as configs and the command line give it."""

    name: str
    """Keyword argument of the generator's constructor."""
    model_file: bool = False
    """The value is a path to a fitted model (file or folder) that must exist before the generator is built."""
    builtins: tuple[str, ...] = ()
    """Values of a ``model_file`` option that name a built-in instead of a path (e.g. SEAL's ``objective: cat``)."""


@dataclass(frozen=True)
class GeneratorSpec:
    """A built-in generator: where it lives, its options and whether it is a training pipeline."""

    name: str
    """Registry name used in configs and on the command line."""
    module: str
    """Module whose import registers the class (imported on first lookup)."""
    options: tuple[GeneratorOption, ...] = ()
    """Constructor options settable from configs (``--gen-opt NAME.KEY=VALUE``, ``train.pipelines.NAME.kwargs``)."""
    pipeline: bool = False
    """A ``seal train`` / ``seal run`` pipeline of the same name trains the ego against this generator."""
    base: str | None = None
    """The generator this one modifies (``cat`` for ``cat-rcg``): the report compares their pipelines."""

    def model_files(self) -> tuple[str, ...]:
        """Names of the options that are model files."""
        return tuple(o.name for o in self.options if o.model_file)

    def option(self, name: str) -> GeneratorOption | None:
        return next((o for o in self.options if o.name == name), None)


def _opts(*names: str, models: tuple[str, ...] = (), builtins: dict[str, tuple[str, ...]] | None = None
          ) -> tuple[GeneratorOption, ...]:
    return tuple(GeneratorOption(n, model_file=n in models, builtins=(builtins or {}).get(n, ())) for n in names)


_CANDIDATE_OPTIONS = ("prior", "candidates", "follow", "stride", "decay", "n_kept_modes", "steer", "steer_vector",
                      "steer_alpha", "project_road")

GENERATORS: dict[str, GeneratorSpec] = {
    "replay": GeneratorSpec("replay", "seal.adversaries.replay"),
    "rule": GeneratorSpec("rule", "seal.adversaries.rule",
                          _opts("max_accel_mps2", "max_lat_accel_mps2", "min_arrival_s")),
    "goose": GeneratorSpec("goose", "seal.adversaries.goose.generator",
                           _opts("model", "deterministic", "max_updates", models=("model",)), pipeline=True),
    "cat": GeneratorSpec("cat", "seal.adversaries.cat.generator",
                         _opts(*_CANDIDATE_OPTIONS, models=("prior",)), pipeline=True),
    "seal": GeneratorSpec("seal", "seal.adversaries.seal.generator", _opts(
        *_CANDIDATE_OPTIONS, "objective", "prior_weight", "skills", "switch", "switch_offset_steps", "noise_scale",
        "skill_horizon",
        models=("prior", "objective", "skills"), builtins={"objective": ("cat",)}), pipeline=True),
    # CAT / SEAL's optional `steer` is a plain option (checked when the generator loads it), so their pipelines'
    # settings are unchanged; for `steered` it is a required model file.
    "steered": GeneratorSpec("steered", "seal.adversaries.steered",
                             _opts(*_CANDIDATE_OPTIONS, "steer_random_seed", models=("prior", "steer")),
                             pipeline=True),
    "cat-rcg": GeneratorSpec("cat-rcg", "seal.adversaries.rcg.generator", _opts(
        "prior", "candidates", "follow", "behavior", "n_knn", "n_int", "distance", "prior_weight",
        models=("prior", "behavior")),
        pipeline=True, base="cat"),
    "seal-rcg": GeneratorSpec("seal-rcg", "seal.adversaries.rcg.generator", _opts(
        "prior", "candidates", "follow", "behavior", "n_knn", "n_int", "distance", "prior_weight", "skills", "switch",
        "switch_offset_steps", "noise_scale", models=("prior", "behavior", "skills")), pipeline=True, base="seal"),
}
"""The built-in generators, one entry each (add a line per new generator). Each module is imported on first lookup
(so a name resolves without importing every generator, and even when ``adversaries/__init__.py`` did not run)."""

GENERATOR_MODULES: dict[str, str] = {name: spec.module for name, spec in GENERATORS.items()}
"""Module that registers each built-in generator (from `GENERATORS`)."""

NO_ADVERSARY = "noadv"
"""The training pipeline without an adversary (the ego sees logged traffic only)."""


def pipeline_names() -> tuple[str, ...]:
    """Training pipelines in their canonical order: `NO_ADVERSARY`, then each generator marked ``pipeline``."""
    return (NO_ADVERSARY, *(name for name, spec in GENERATORS.items() if spec.pipeline))


def generator_spec(name: str) -> GeneratorSpec | None:
    """The built-in spec of generator ``name`` (None for one registered only at run time)."""
    return GENERATORS.get(name)


def model_file_options(name: str) -> dict[str, tuple[str, ...]]:
    """Options of generator ``name`` that are model files -> their built-in (non-path) values."""
    spec = GENERATORS.get(name)
    return {} if spec is None else {o.name: o.builtins for o in spec.options if o.model_file}


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
    """Every generator name: built-ins, ones registered by imported modules and ``--plugin`` files, and the
    installed packages' ``seal.generators`` entry points (`seal.core.plugins`; not imported by this call)."""
    from seal.core.plugins import GENERATOR_GROUP, entry_point_names, load_env_plugins

    load_env_plugins()
    return sorted(set(_REGISTRY) | set(GENERATOR_MODULES) | set(entry_point_names(GENERATOR_GROUP)))


def generator_class(name: str) -> Callable[..., AdversaryGenerator]:
    """The class (factory) registered as ``name``: a built-in (its module imported on first lookup), one registered
    by a ``--plugin`` module, or an installed ``seal.generators`` entry point; unknown names get an error listing
    the known ones."""
    if name not in _REGISTRY and name in GENERATOR_MODULES:
        importlib.import_module(GENERATOR_MODULES[name])
    if name not in _REGISTRY:
        _load_plugin_generator(name)
    if name not in _REGISTRY:
        raise ValueError(f"unknown generator {name!r}; available: {', '.join(available_generators())}")
    return _REGISTRY[name]


def _load_plugin_generator(name: str) -> None:
    """Look ``name`` up in the inherited ``--plugin`` modules, then in the ``seal.generators`` entry points: an
    entry point naming a module registers on import; one naming an `AdversaryGenerator` subclass is registered
    here under the entry point's name."""
    from seal.core.plugins import GENERATOR_GROUP, PluginError, load_entry_point, load_env_plugins

    load_env_plugins()
    if name in _REGISTRY:
        return
    target = load_entry_point(GENERATOR_GROUP, name)
    if name in _REGISTRY or target is None:
        return
    if isinstance(target, type) and issubclass(target, AdversaryGenerator):
        register(name)(target)
        return
    raise PluginError(
        f"entry point {GENERATOR_GROUP}:{name} gave {target!r}: it must name a module that registers {name!r} "
        "with @seal.adversaries.base.register, or an AdversaryGenerator subclass"
    )


def expand_user_paths(kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """``kwargs`` with every string option that starts with ``~`` expanded to the home folder (model paths written
    as ``~/runs/...`` in a YAML config or ``--gen-opt``; the shell expands only unquoted command-line words)."""
    return {k: os.path.expanduser(v) if isinstance(v, str) and v.startswith("~") else v for k, v in kwargs.items()}


def make_generator(name: str, **kwargs: Any) -> AdversaryGenerator:
    """Instantiate a registered generator (string options starting with ``~`` expanded, `expand_user_paths`);
    unknown names get an error listing the known ones."""
    return generator_class(name)(**expand_user_paths(kwargs))
