"""Check a whole ``seal run`` plan before its first step: every step's options, types and ranges, the names of
pipelines, generators and settings, and the paths that must already exist.

`seal.experiments.pipeline.run.run_pipeline` calls `check_plan` before it creates the output folder, so a typo in
the eval section fails in a second, not after hours of training. Each check builds the same typed config the step
builds later (`seal.core.config` and the steps' own resolvers), with placeholder paths for what earlier steps will
write (the dataset, the fitted models). Errors are `ValueError`s whose message starts with the preset section.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from seal.adversaries.base import NO_ADVERSARY, available_generators
from seal.experiments.pipeline.references import (
    fit_kind,
    fits_needed,
    generators_in_use,
    late_fits,
    late_runs,
    planned_runs,
    run_refs,
    substitute,
    with_algo,
    with_models,
)
from seal.experiments.pipeline.tasks import FIT_CONFIGS, FIT_DEFAULTS, OPTIONS
from seal.experiments.training.config import ALGOS

RUN_EVAL_KEYS = ("settings", "replay_ego", "egos", "heldout")
"""Keys of a preset's ``eval`` section besides `seal.experiments.evaluation.evaluate.EvalRunsConfig`'s."""
REPORT_KEYS = {"plots": bool, "videos": int, "video_format": str, "reps": int, "poi_reps": int}
BACKEND_KEYS = {"name": str, "workers": int, "address": str, "train_workers": int, "fit_workers": int}
DATA_TASKS = ("generate", "score", "split")


def check_plan(
    config: Mapping[str, Any], config_path: Path, out: Path,
    train_config_fn: Callable[..., dict[str, Any]], fit_outputs: Mapping[str, str],
) -> None:
    """Raise ValueError naming the section and key of the first problem in ``config`` (a loaded preset)."""
    dataset = _check_data(config.get("data") or {}, out)
    _check_pipelines(config)
    models = {name: str(out / "models" / fit_outputs.get(name, name)) for name in fits_needed(config)}
    _check_fits(config.get("fit") or {}, models)
    _check_late_fits(config)
    generators = {name: substitute(dict((config.get("generators") or {}).get(name) or {}), models)
                  for name in generators_in_use(config)}
    _check_eval(config.get("eval") or {}, dataset)
    _check_heldout(config, dataset, out)
    resolved = with_models(config, models)
    for pipeline, seed, algo in planned_runs(config).values():
        try:
            train_config_fn(with_algo(resolved, algo), config_path, pipeline, seed, dataset, generators)
        except (ValueError, TypeError) as exc:
            raise ValueError(f"train ({pipeline}, seed {seed}{f', algo {algo}' if algo else ''}): {exc}") from None
    _check_types("report", config.get("report") or {}, REPORT_KEYS)
    _check_types("backend", config.get("backend") or {}, BACKEND_KEYS)
    backend = (config.get("backend") or {}).get("name", "local")
    if backend not in ("local", "ray"):
        raise ValueError(f"backend.name must be local or ray, got {backend!r}")
    fit_workers = (config.get("backend") or {}).get("fit_workers")
    if fit_workers is not None and fit_workers < 1:
        raise ValueError(f"backend.fit_workers must be at least 1, got {fit_workers}")


def _check_data(data: Mapping[str, Any], out: Path) -> str:
    """The dataset the later steps will use (``data.path``, which must be a dataset, or OUT/data)."""
    from seal.core.dataset import Dataset, DatasetError

    if not isinstance(data, Mapping):
        raise ValueError(f"data must be a mapping (path, or generate / score / split), got {data!r}")
    unknown = sorted(set(data) - {"path", "generate", "score", "split"})
    if unknown:
        raise ValueError(f"data: unknown key(s) {unknown}; known: path, generate, score, split")
    if data.get("path"):
        root = Path(str(data["path"])).expanduser()
        try:
            ds = Dataset.open(root)
        except DatasetError as exc:
            raise ValueError(f"data.path: {exc}") from None
        if not ds.splits.get("eval"):
            raise ValueError(f"data.path: {root} has no eval split; run `seal data score` and `seal data split`")
        return str(root.resolve())
    _check_pool_options(data, "data")
    return str(out / "data")


def _check_pool_options(data: Mapping[str, Any], section: str) -> None:
    """The generate / score / split options of a pool the run builds (``data``, or an ``eval.heldout`` entry)."""
    for task in DATA_TASKS:
        options = data.get(task) or {}
        if not isinstance(options, Mapping):
            raise ValueError(f"{section}.{task} must be a mapping of options, got {options!r}")
        unknown = sorted(set(options) - set(OPTIONS[task]))
        if unknown:
            raise ValueError(f"{section}.{task}: unknown option(s) {unknown}; known: {list(OPTIONS[task])}")
    _check_generate(data.get("generate") or {}, section)
    _check_split(data.get("split") or {}, section)


def _check_generate(o: Mapping[str, Any], section: str) -> None:
    from seal.envs.generate import _check_args

    if "n" not in o:
        raise ValueError(f"{section}.generate.n: missing (the number of scenarios)"
                         + (", or give data.path" if section == "data" else ""))
    try:
        _check_args(o["n"], o.get("seed", 0), o.get("layouts") or ["highway"], o.get("workers"),
                    o.get("inattentive_share", 0.15), o.get("aggressive_share", 0.15))
    except ValueError as exc:
        raise ValueError(f"{section}.generate: {exc}") from None


def _check_split(o: Mapping[str, Any], section: str) -> None:
    from seal.scoring.splits import SplitError, _check_options

    for key in ("n_train", "n_eval", "n_hard", "seed"):
        if key in o and (isinstance(o[key], bool) or not isinstance(o[key], int)):
            raise ValueError(f"{section}.split.{key} must be an integer, got {o[key]!r}")
    quantile = o.get("hard_quantile", 0.8)
    if isinstance(quantile, bool) or not isinstance(quantile, int | float):
        raise ValueError(f"{section}.split.hard_quantile must be a number, got {quantile!r}")
    try:
        _check_options(float(quantile), o.get("n_train", 400), o.get("n_eval", 100), o.get("n_hard", 100),
                       o.get("score", "ac"), o.get("hard_by", "pair"))
    except SplitError as exc:
        raise ValueError(f"{section}.split: {exc}") from None


def _check_pipelines(config: Mapping[str, Any]) -> None:
    known = [NO_ADVERSARY, *available_generators(), *(config.get("variants") or {})]
    for pipeline in config["pipelines"]:
        if pipeline not in known:
            raise ValueError(f"pipelines: unknown pipeline {pipeline!r}; known: {', '.join(known)}")
    for seed in config["seeds"]:
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise ValueError(f"seeds: every seed must be a non-negative integer, got {seed!r}")
    algos = config.get("algos") or []
    if not isinstance(algos, list) or len(set(map(str, algos))) != len(algos) or any(a not in ALGOS for a in algos):
        raise ValueError(f"algos: expected a list of distinct ego algorithms out of {', '.join(ALGOS)}, got {algos!r}")
    for name in config.get("generators") or {}:
        if name not in available_generators():
            raise ValueError(f"generators: unknown generator {name!r}; known: {', '.join(available_generators())}")


def _check_fits(fit: Mapping[str, Any], models: Mapping[str, str]) -> None:
    for name in models:
        spec = dict(fit.get(name) or {})
        if spec.get("path"):
            if not Path(str(spec["path"])).expanduser().exists():
                raise ValueError(f"fit.{name}.path: {spec['path']} does not exist")
            continue
        kind, spec = fit_kind(name, spec)
        if kind not in OPTIONS or kind in DATA_TASKS:
            known = sorted(k for k in OPTIONS if k not in DATA_TASKS)
            what = f"fit.{name}.model {kind!r}" if kind != name else f"model {name!r}"
            raise ValueError(f"fit: unknown {what}; known: {', '.join(known)} (or give model: KIND)")
        unknown = sorted(set(spec) - set(OPTIONS[kind]))
        if unknown:
            raise ValueError(f"fit.{name}: unknown option(s) {unknown}; known: {['model', *OPTIONS[kind]]}")
        options = {**FIT_DEFAULTS.get(kind, {}), **spec}
        for key in ("epochs", "steps", "limit", "threads", "workers", "seed", "eval_limit", "candidates"):
            value = options.get(key)
            if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 0):
                raise ValueError(f"fit.{name}.{key} must be a non-negative integer, got {value!r}")
        minutes = options.get("max_minutes")
        if minutes is not None and (isinstance(minutes, bool) or not isinstance(minutes, int | float) or minutes <= 0):
            raise ValueError(f"fit.{name}.max_minutes must be a positive number, got {minutes!r}")
        config_file = options.get("config")
        if config_file is not None and not Path(str(config_file)).expanduser().is_file():
            raise ValueError(f"fit.{name}.config: {config_file} does not exist")
        if options.get("set") is not None:
            _check_fit_sets(name, kind, options)


def _check_late_fits(config: Mapping[str, Any]) -> None:
    """A fit that references training runs (``"${runs.NAME}"``) names runs of this plan that do not themselves need
    its model (they train before it)."""
    runs, late = planned_runs(config), set(late_runs(config))
    fit = config.get("fit") or {}
    for name in late_fits(config):
        for run in run_refs(dict(fit[name] or {})):
            if run not in runs:
                names = list(runs)
                listed = ", ".join(names[:8]) + (f", ... ({len(names)} in all)" if len(names) > 8 else "")
                raise ValueError(f"fit.{name}: ${{runs.{run}}} is not a training run of this plan (its runs: "
                                 f"{listed or 'none'}); name one of them, or drop it from the fit's options")
            if run in late:
                raise ValueError(f"fit.{name}: ${{runs.{run}}} trains with a model that waits for this fit (a circle); "
                                 f"label against a run of a pipeline that does not use fit.{name}, e.g. noadv")


def _check_fit_sets(name: str, kind: str, options: Mapping[str, Any]) -> None:
    """A fit's ``set`` overrides resolved with the rest of its options, as the fit will resolve them (unknown keys,
    wrong types, values out of range); references to other fits (``${fit.prior}``) stand in as they are."""
    try:
        FIT_CONFIGS[kind](options)
    except ValueError as exc:
        raise ValueError(f"fit.{name}: {exc}") from None


def _check_eval(ev: Mapping[str, Any], dataset: str) -> None:
    from seal.core.dataset import DatasetError
    from seal.experiments.evaluation.evaluate import DEFAULTS, parse_settings, resolve_eval_config

    if not isinstance(ev, Mapping):
        raise ValueError(f"eval must be a mapping of options, got {ev!r}")
    unknown = sorted(set(ev) - set(DEFAULTS) - set(RUN_EVAL_KEYS))
    if unknown:
        raise ValueError(f"eval: unknown key(s) {unknown}; known: {sorted({*DEFAULTS, *RUN_EVAL_KEYS})}")
    if not isinstance(ev.get("replay_ego", True), bool):
        raise ValueError(f"eval.replay_ego must be true or false, got {ev['replay_ego']!r}")
    _check_reference_egos(ev.get("egos"))
    try:
        resolve_eval_config(k=ev.get("k"), limit=ev.get("limit"), seed=ev.get("seed"), prior=ev.get("prior"),
                            candidates=ev.get("candidates"), env=ev.get("env"))
        settings = ev.get("settings") or ["normal", "hard"]
        if not isinstance(settings, list | str):
            raise ValueError(f"settings must be a list, got {settings!r}")
        parse_settings(settings, dataset)
    except (ValueError, DatasetError) as exc:
        raise ValueError(f"eval: {exc}") from None


def _check_heldout(config: Mapping[str, Any], dataset: str, out: Path) -> None:
    """``eval.heldout``: dataset folders other than the run's own, each with the splits the settings read, or pools
    the run builds (``{name, generate, score, split}``); none generated from the same traffic runs (same generator
    seed) as the run's pool."""
    from seal.core.dataset import Dataset, DatasetError
    from seal.experiments.pipeline.references import eval_settings, heldout_pool

    pools = (config.get("eval") or {}).get("heldout")
    if pools is None:
        return
    if not isinstance(pools, list) or not all(isinstance(p, str | Mapping) for p in pools):
        raise ValueError(f"eval.heldout must be a list of dataset folders or {{name, generate, score, split}} "
                         f"pools to build, got {pools!r}")
    data = config.get("data") or {}
    own = (Dataset.open(dataset).manifest.get("provenance") or {}) if data.get("path") else \
        {"source": "highway-env", "seed": (data.get("generate") or {}).get("seed", 0)}
    built = [_check_heldout_build(entry, own) for entry in pools if isinstance(entry, Mapping)]
    if len(set(built)) < len(built):
        raise ValueError(f"eval.heldout: two pools to build share a name ({sorted(built)})")
    settings = eval_settings(config, dataset, out)
    for pool in dict.fromkeys(heldout_pool(e, out) for e in pools if isinstance(e, str)):  # the built ones: above
        if pool == str(Path(dataset).resolve()):
            raise ValueError(f"eval.heldout: {pool} is the run's own dataset")
        try:
            ds = Dataset.open(pool)
        except DatasetError as exc:
            raise ValueError(f"eval.heldout: {exc}") from None
        prov = ds.manifest.get("provenance") or {}
        if prov.get("source") == own.get("source") == "highway-env" and prov.get("seed") == own.get("seed"):
            raise ValueError(f"eval.heldout: {pool} was generated with seed {own['seed']}, as the run's pool: the "
                             "same traffic runs, not held out (generate it with another --seed)")
        needed = sorted({str(s.split) for s in settings if s.dataset == pool})
        if missing := [sp for sp in needed if not ds.splits.get(sp)]:
            raise ValueError(f"eval.heldout: {pool} has no {' / '.join(missing)} split; run `seal data split "
                             f"{pool} --n-train 0 ...`")


def _check_heldout_build(entry: Mapping[str, Any], own: Mapping[str, Any]) -> str:
    """One ``eval.heldout`` pool the run builds: a folder name, the generate / score / split options as ``data``'s,
    a generator seed other than the run's pool's; returns its name."""
    unknown = sorted(set(entry) - {"name", *DATA_TASKS})
    if unknown:
        raise ValueError(f"eval.heldout: unknown key(s) {unknown} in a pool to build; known: name, "
                         f"{', '.join(DATA_TASKS)}")
    name = entry.get("name")
    if not isinstance(name, str) or not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]*", name):
        raise ValueError(f"eval.heldout: a pool to build needs a folder name (letters, digits, _ . -), got {name!r}")
    section = f"eval.heldout[{name}]"
    _check_pool_options(entry, section)
    seed = (entry.get("generate") or {}).get("seed", 0)
    if own.get("source") == "highway-env" and seed == own.get("seed"):
        raise ValueError(f"{section}.generate.seed: {seed} is the run's pool's seed (the same traffic runs, not "
                         "held out); give another seed")
    return name


def _check_reference_egos(egos: Any) -> None:
    """``eval.egos``: a list of egos `seal eval runs` accepts (built-in, registered, entry point, model path)."""
    from seal.experiments.evaluation.evaluate import read_run

    if egos is None:
        return
    if not isinstance(egos, list) or not all(isinstance(e, str) and e for e in egos):
        raise ValueError(f"eval.egos must be a list of ego names or model paths, got {egos!r}")
    for ego in egos:
        try:
            read_run(ego)
        except (FileNotFoundError, ValueError) as exc:
            raise ValueError(f"eval.egos: {exc}") from None


def _check_types(section: str, values: Mapping[str, Any], types: Mapping[str, type]) -> None:
    if not isinstance(values, Mapping):
        raise ValueError(f"{section} must be a mapping, got {values!r}")
    for key, value in values.items():
        if key not in types:
            raise ValueError(f"{section}: unknown key {key!r}; known: {', '.join(types)}")
        expected = types[key]
        if value is not None and (not isinstance(value, expected) or (expected is int and isinstance(value, bool))):
            raise ValueError(f"{section}.{key} must be {expected.__name__}, got {value!r}")
