"""``"${fit.NAME}"`` references of a ``seal run`` preset: which generators and fitted models the plan uses.

`seal.experiments.pipeline.run` runs the steps and `seal.experiments.pipeline.plan` checks them; both read the
preset through these helpers.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.adversaries.base import NO_ADVERSARY

REF = re.compile(r"^\$\{fit\.(\w+)\}(.*)$")
"""``"${fit.NAME}"`` or ``"${fit.NAME}/file inside it"`` in generator kwargs: a fitted model's path."""
RUN_REF = re.compile(r"^\$\{runs\.([\w.-]+)\}$")
"""``"${runs.NAME}"`` in a fit's options: the folder of this plan's training run NAME, e.g. pi_score labelled against
a trained ego as well (``egos: [heuristic, "${runs.noadv-td3-s0}"]``). Such a fit runs after the training runs that
do not need it (`late_fits`), and the runs whose generator uses its model train after it (`late_runs`)."""


VARIANT_KEYS = ("generator", "kwargs", "train")


def variant_of(config: Mapping[str, Any], pipeline: str) -> dict[str, Any]:
    """The ``variants`` entry of ``pipeline`` (empty for a plain pipeline), its keys checked."""
    variant = (config.get("variants") or {}).get(pipeline)
    if variant is None:
        return {}
    if not isinstance(variant, Mapping) or not variant.get("generator"):
        raise ValueError(f"variants.{pipeline}: expected a mapping with 'generator' (and optional 'kwargs', 'train')")
    unknown = sorted(set(variant) - set(VARIANT_KEYS))
    if unknown:
        raise ValueError(f"variants.{pipeline}: unknown key(s) {unknown}; known: {list(VARIANT_KEYS)}")
    for key in ("kwargs", "train"):
        if not isinstance(variant.get(key) or {}, Mapping):
            raise ValueError(f"variants.{pipeline}.{key}: expected a mapping, got {variant.get(key)!r}")
    return dict(variant)


def generator_of(pipeline: str, config: Mapping[str, Any] | None = None) -> str | None:
    """The adversary generator a training pipeline uses (None for ``noadv`` and for a variant of it, ``generator:
    noadv``; else a variant's ``generator``)."""
    if pipeline == NO_ADVERSARY:
        return None
    variant = variant_of(config or {}, pipeline)
    if not variant:
        return pipeline
    return None if variant["generator"] == NO_ADVERSARY else str(variant["generator"])


def dotted(prefix: str, value: Any) -> dict[str, Any]:
    """Nested mapping -> ``{"a.b": leaf}`` (a variant's train overrides as `load_train_config` takes them)."""
    if not isinstance(value, Mapping):
        return {prefix: value}
    return {k: v for key, sub in value.items() for k, v in dotted(f"{prefix}.{key}" if prefix else key, sub).items()}


def generators_in_use(config: Mapping[str, Any]) -> list[str]:
    """Generators of the training pipelines and of the eval settings, in order of first use."""
    from seal.adversaries.base import available_generators

    names = [generator_of(p, config) for p in config["pipelines"]]
    names += [s for s in (config.get("eval") or {}).get("settings", []) if s in available_generators()]
    return [n for n in dict.fromkeys(names) if n]


def _refs(value: Any, pattern: re.Pattern[str] = REF) -> list[str]:
    """Names referenced anywhere in ``value``: fitted models (``"${fit.NAME}"``), or what ``pattern`` matches."""
    if isinstance(value, dict):
        return [r for v in value.values() for r in _refs(v, pattern)]
    if isinstance(value, list):
        return [r for v in value for r in _refs(v, pattern)]
    m = pattern.match(value) if isinstance(value, str) else None
    return [m.group(1)] if m else []


def run_refs(value: Any) -> list[str]:
    """Names of the training runs referenced (``"${runs.NAME}"``) anywhere in ``value``."""
    return _refs(value, RUN_REF)


def late_fits(config: Mapping[str, Any]) -> list[str]:
    """The fits in use that wait for training runs: those whose options reference a run (``"${runs.NAME}"``) and
    those that use such a fit's model; in `fits_needed` order."""
    fit = config.get("fit") or {}
    late: list[str] = []
    for name in fits_needed(config):
        spec = dict(fit[name] or {})
        if not spec.get("path") and (run_refs(spec) or any(dep in late for dep in fit_dependencies(spec))):
            late.append(name)
    return late


def late_runs(config: Mapping[str, Any]) -> list[str]:
    """The training runs that need a late fit's model (their generator's kwargs, their variant's or the train
    section reference it, directly or through another fit): they train after the late fits."""
    late = set(late_fits(config))
    if not late:
        return []
    fit, gens = config.get("fit") or {}, config.get("generators") or {}

    def uses_late(refs: list[str]) -> bool:
        seen: set[str] = set()
        while refs:
            name = refs.pop()
            if name in late:
                return True
            if name not in seen and name in fit:
                seen.add(name)
                refs.extend(fit_dependencies(fit[name]))
        return False

    shared = _refs(config.get("train") or {})
    return [run for run, (pipeline, _, _) in planned_runs(config).items()
            if uses_late([*shared, *_refs(variant_of(config, pipeline)),
                          *_refs(gens.get(generator_of(pipeline, config)) or {})])]


def fit_kind(name: str, spec: Mapping[str, Any] | None) -> tuple[str, dict[str, Any]]:
    """Which ``seal fit`` command a ``fit.NAME`` entry runs and with which options: its ``model:`` option (taken
    out of the options), else the name itself. ``model`` lets a preset fit one kind twice with different options,
    e.g. ``ego_skills: {model: skills, preset: ego}`` beside ``skills``."""
    options = dict(spec or {})
    kind = options.pop("model", name)
    if not isinstance(kind, str):
        raise ValueError(f"fit.{name}.model must be the name of a fitted model kind, got {kind!r}")
    return kind, options


def fit_dependencies(spec: Mapping[str, Any] | None) -> list[str]:
    """The fitted models a ``fit.NAME`` entry's options reference (``"${fit.OTHER}"``): fitted before it; none for
    a model given as ``path``."""
    spec = spec or {}
    return [] if spec.get("path") else list(dict.fromkeys(_refs(dict(spec))))


def fits_needed(config: Mapping[str, Any]) -> list[str]:
    """Models referenced (``"${fit.NAME}"``) by the kwargs of the generators in use and by the train section,
    plus the models those fits' options reference in turn (e.g. ``objective: {prior: "${fit.prior}"}``); ordered
    so that every model comes after the ones its fit uses."""
    gens, fit = config.get("generators") or {}, config.get("fit") or {}
    wanted = [r for name in generators_in_use(config) for r in _refs(gens.get(name) or {})]
    wanted += _refs(config.get("train") or {})  # e.g. the ReSkill ego's hyperparams.reskill.skills
    order: list[str] = []

    def visit(name: str, chain: tuple[str, ...]) -> None:
        if name in order:
            return
        if name in chain:
            raise ValueError(f"fit: circular references {' -> '.join((*chain, name))}")
        if name not in fit:
            raise ValueError(f"the preset references ${{fit.{name}}} but has no fit.{name} entry")
        for dep in fit_dependencies(fit[name]):
            visit(dep, (*chain, name))
        order.append(name)

    for name in dict.fromkeys(wanted):
        visit(name, ())
    return order


def substitute(value: Any, models: Mapping[str, str], runs: Mapping[str, str] | None = None) -> Any:
    """Replace ``"${fit.NAME}"`` strings (at any depth) by the fitted model paths and, with ``runs`` (run name ->
    folder), ``"${runs.NAME}"`` strings by the training run folders."""
    if isinstance(value, dict):
        return {k: substitute(v, models, runs) for k, v in value.items()}
    if isinstance(value, list):
        return [substitute(v, models, runs) for v in value]
    if not isinstance(value, str):
        return value
    if runs is not None and (r := RUN_REF.match(value)):
        return runs[r.group(1)]
    m = REF.match(value)
    return models[m.group(1)] + m.group(2) if m else value


def planned_runs(config: Mapping[str, Any]) -> dict[str, tuple[str, int, str | None]]:
    """The training runs of a plan: run folder name -> ``(pipeline, seed, algo)``. Without ``algos`` one run per
    pipeline x seed, ``<pipeline>-s<seed>``, with the train section's algorithm (``algo`` None); with ``algos`` one
    per pipeline x algorithm x seed, ``<pipeline>-<algo>-s<seed>``."""
    algos = config.get("algos") or [None]
    return {(f"{p}-{a}-s{seed}" if a else f"{p}-s{seed}"): (p, int(seed), a)
            for p in config["pipelines"] for a in algos for seed in config["seeds"]}


def with_algo(config: Mapping[str, Any], algo: str | None) -> dict[str, Any]:
    """``config`` with ``train.algo`` set to ``algo`` (unchanged for None): the config one run of a multi-algorithm
    plan is built from."""
    if algo is None:
        return dict(config)
    return {**config, "train": {**dict(config.get("train") or {}), "algo": algo}}


def with_models(config: Mapping[str, Any], models: Mapping[str, str]) -> dict[str, Any]:
    """``config`` with the ``"${fit.NAME}"`` references of its train section replaced by the fitted models' paths
    (``train: {hyperparams: {reskill: {skills: "${fit.skills}"}}}``: the ReSkill ego's skills)."""
    return {**config, "train": substitute(dict(config.get("train") or {}), models)}


def eval_egos(config: Mapping[str, Any], trained: Sequence[str]) -> list[str]:
    """The egos the eval step evaluates, in the store's order: the ``trained`` run folders, the preset's
    ``eval.egos`` (reference egos such as ``heuristic``, or models of other experiments) and, unless
    ``eval.replay_ego`` is false, the Replay ego; each once."""
    ev = config.get("eval") or {}
    egos = [*trained, *(str(e) for e in ev.get("egos") or []), *(["replay"] if ev.get("replay_ego", True) else [])]
    return list(dict.fromkeys(egos))


HELDOUT_DIR = "heldout"
"""OUT/heldout/<name>: the held-out pools a run builds itself (``eval.heldout`` entries with ``generate``)."""


def heldout_pool(entry: Any, out: Path) -> str:
    """The folder of one ``eval.heldout`` entry: a folder given as a path (``~`` expanded, resolved), or
    OUT/heldout/<name> for a pool the run builds (an entry ``{name, generate, score, split}``)."""
    if isinstance(entry, Mapping):
        return str(Path(out).resolve() / HELDOUT_DIR / str(entry.get("name")))
    return str(Path(str(entry)).expanduser().resolve())


def heldout_pools(config: Mapping[str, Any], out: Path) -> list[str]:
    """The preset's ``eval.heldout`` dataset folders (`heldout_pool`), each once."""
    return list(dict.fromkeys(heldout_pool(e, out) for e in (config.get("eval") or {}).get("heldout") or []))


def eval_settings(config: Mapping[str, Any], dataset: str, out: Path) -> list[Any]:
    """The eval step's `seal.experiments.evaluation.evaluate.Setting`\\ s: ``eval.settings`` on the run's own pool
    ``dataset``, then the same settings but ``real:DIR`` on each ``eval.heldout`` pool (its eval / hard splits; the
    store keeps the pools apart and the report labels them ``normal@<pool>``)."""
    from seal.experiments.evaluation.evaluate import REAL_PREFIX, parse_settings

    spec = (config.get("eval") or {}).get("settings") or ["normal", "hard"]
    settings = parse_settings(spec, dataset)
    for pool in heldout_pools(config, out):
        settings += [s for s in parse_settings(spec, pool) if not s.name.startswith(REAL_PREFIX)]
    return settings
