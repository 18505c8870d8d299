"""The data and model-fit steps of ``seal run`` as Python calls: one picklable job function, `run_task`, that a
backend runs in a worker process (`seal.experiments.backends`), with the same defaults as the matching ``seal``
commands (``seal data generate | score | split``, ``seal fit prior | goose | skills | objective | behavior |
probes``).

A job is a dict: ``task`` (``generate``, ``score``, ``split``, ``fit``), ``dataset`` (the dataset folder),
``model`` and ``out`` (fits: which model and the file or folder to write) and ``options`` (the preset's options of
that step, named as the command's options without dashes: ``{n_train: 80}`` is ``--n-train 80``; ``set: [KEY=VALUE,
...]`` is the fit command's ``--set``). Unknown options raise an error naming them and the known ones.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from seal.experiments.backends import Job

logger = logging.getLogger(__name__)

ALL_BUT_EVAL = "all-but-eval"
FIT_DEFAULTS: dict[str, dict[str, Any]] = {"prior": {"split": ALL_BUT_EVAL}}
"""Options fixed per fit unless the preset gives them (the prior must not see the eval / hard splits)."""

OPTIONS: dict[str, tuple[str, ...]] = {
    "generate": ("n", "seed", "layouts", "workers", "inattentive_share", "aggressive_share", "overwrite",
                 "no_progress"),
    "score": ("workers", "no_progress"),
    "split": ("hard_quantile", "n_train", "n_eval", "n_hard", "seed", "hard_by", "score"),
    "prior": ("split", "config", "epochs", "max_minutes", "no_time_budget", "threads", "seed", "limit", "resume",
              "no_progress"),
    "goose": ("preset", "config", "set", "algo", "steps", "split", "limit", "eval_split", "eval_limit", "no_eval",
              "run_dir", "seed", "no_progress"),
    "skills": ("preset", "config", "set", "split", "limit", "demos", "workers", "seed", "no_progress"),
    "objective": ("preset", "config", "set", "prior", "candidates", "eval_split", "eval_limit", "workers", "seed",
                  "split", "limit", "skills", "behavior", "egos", "no_progress"),
    "behavior": ("preset", "config", "set", "split", "limit", "eval_split", "eval_limit", "max_samples",
                 "crash_datasets", "seed", "threads", "no_progress"),
    "probes": ("prior", "config", "split", "limit", "max_targets", "seed", "no_progress"),
}
"""Known options per task / fitted model (the options of the matching ``seal`` command)."""


def _options(kind: str, options: Mapping[str, Any] | None) -> dict[str, Any]:
    """``options`` checked against `OPTIONS` [kind]."""
    given = dict(options or {})
    unknown = sorted(set(given) - set(OPTIONS[kind]))
    if unknown:
        raise ValueError(f"{kind}: unknown option(s) {unknown}; known: {list(OPTIONS[kind])}")
    return given


def run_task(job: Job) -> Any:
    """Run one data or fit step (module docstring); returns the step's summary."""
    task = str(job["task"])
    if task == "fit":
        model = str(job["model"])
        if model not in FITS:
            raise ValueError(f"fit: unknown model {model!r}; known: {sorted(FITS)}")
        options = _options(model, {**FIT_DEFAULTS.get(model, {}), **dict(job.get("options") or {})})
        return FITS[model](str(job["dataset"]), str(job["out"]), options)
    if task not in DATA_TASKS:
        raise ValueError(f"unknown task {task!r}; known: {[*DATA_TASKS, 'fit']}")
    return DATA_TASKS[task](str(job["dataset"]), _options(task, job.get("options")))


# ---------------------------------------------------------------------------------------------- data
def generate(dataset: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal data generate --out DATASET``."""
    from seal.envs.generate import generate_dataset
    from seal.envs.layouts import LAYOUTS

    layouts = o.get("layouts") or list(LAYOUTS)
    if isinstance(layouts, str):
        layouts = [name.strip() for name in layouts.split(",") if name.strip()]
    ds = generate_dataset(
        dataset, n=int(o["n"]), seed=int(o.get("seed", 0)), layouts=list(layouts), workers=o.get("workers"),
        inattentive_share=float(o.get("inattentive_share", 0.15)),
        aggressive_share=float(o.get("aggressive_share", 0.15)),
        overwrite=bool(o.get("overwrite", False)), progress=not o.get("no_progress", False),
    )
    logger.info(f"wrote {len(ds)} scenarios to {ds.root}")
    return {"scenarios": len(ds)}


def score(dataset: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal data score DATASET``."""
    from seal.scoring.store import score_dataset

    return score_dataset(dataset, workers=o.get("workers"), progress=not o.get("no_progress", False))


def split(dataset: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal data split DATASET``."""
    from seal.scoring.splits import make_splits

    return make_splits(dataset, **o)


DATA_TASKS: dict[str, Callable[[str, dict[str, Any]], Any]] = {"generate": generate, "score": score, "split": split}


# ---------------------------------------------------------------------------------------------- fits
def _torch_threads(threads: int) -> None:
    """A fit task is the entry point of its worker process: torch threads as `seal fit ...` sets them."""
    import torch

    torch.set_num_threads(int(threads))


def fit_prior(dataset: str, out: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal fit prior DATASET --out OUT``: the model file and ``OUT.json`` (resolved config, training summary)."""
    from dataclasses import replace

    import yaml

    from seal.core.atomic import atomic_write_json
    from seal.core.dataset import load_split
    from seal.models.prior.network import PriorConfig
    from seal.models.prior.train import PriorTrainConfig, fit_prior, resumable_state

    doc = (yaml.safe_load(Path(o["config"]).read_text()) or {}) if o.get("config") else {}
    if not isinstance(doc, dict) or set(doc) - {"model", "train"}:
        raise ValueError(f"fit prior config {o['config']} must be a mapping with sections 'model' and/or 'train'")
    model_cfg = PriorConfig.from_dict(dict(doc.get("model") or {}))
    train_cfg = PriorTrainConfig.from_dict(dict(doc.get("train") or {}))
    overrides = {k: o.get(k) for k in ("epochs", "max_minutes", "threads", "seed")}
    train_cfg = replace(train_cfg, **{k: v for k, v in overrides.items() if v is not None})
    if o.get("no_time_budget"):
        train_cfg = replace(train_cfg, max_minutes=None)
    split_name = str(o.get("split", "train"))
    scenarios = load_split(dataset, split_name, o.get("limit"), "prior", allow_empty=True)
    info = {"dataset": str(Path(dataset).resolve()), "split": split_name, "scenarios": len(scenarios),
            "config_file": o.get("config")}
    logger.info(f"fit prior: {info['scenarios']} scenarios from {dataset} (split {split_name})")
    _torch_threads(train_cfg.threads)
    # Without a `resume` option a fit interrupted with the same settings (a session that ended mid-fit) goes on from
    # its last epoch: the same model as an uninterrupted fit; a state of other settings is started over.
    resume = o.get("resume")
    if resume is None:
        resume = resumable_state(out, model_cfg, train_cfg)
    prior = fit_prior(scenarios, out, model_cfg, train_cfg, data_info=info, resume=bool(resume),
                      progress=not o.get("no_progress", False))
    summary = {k: v for k, v in prior.training.items() if not k.endswith("_scenario_ids")}
    atomic_write_json(Path(str(out) + ".json"), {"model_config": prior.config.to_dict(), "training": summary})
    return summary


def fit_overrides(o: Mapping[str, Any]) -> tuple[str, ...]:
    """A fit's ``set`` option: ``KEY=VALUE`` overrides of its config, as ``seal fit ... --set`` takes them (e.g.
    ``vae_train.max_minutes=null``)."""
    sets = o.get("set") or ()
    if isinstance(sets, str) or not all(isinstance(item, str) for item in sets):
        raise ValueError(f"option 'set' must be a list of KEY=VALUE strings, got {sets!r}")
    return tuple(sets)


def goose_config(o: Mapping[str, Any]) -> Any:
    """The `GooseFitConfig` of a goose fit's options."""
    from dataclasses import replace

    from seal.experiments.fitting.goose import resolve_config

    config = resolve_config(
        preset=o.get("preset", "standard"), config_file=o.get("config"), algo=o.get("algo"),
        total_steps=o.get("steps"), seed=o.get("seed"), split=o.get("split"), limit=o.get("limit"),
        eval_split=o.get("eval_split"), eval_limit=o.get("eval_limit"), sets=fit_overrides(o),
    )
    return replace(config, eval_split=None) if o.get("no_eval") else config


def skills_config(o: Mapping[str, Any]) -> Any:
    """The `SkillsFitConfig` of a skills fit's options."""
    from seal.experiments.fitting.skills import resolve_config

    return resolve_config(preset=o.get("preset", "standard"), config_file=o.get("config"), split=o.get("split"),
                          limit=o.get("limit"), seed=o.get("seed"), workers=o.get("workers"), sets=fit_overrides(o))


def objective_config(o: Mapping[str, Any]) -> Any:
    """The `ObjectiveFitConfig` of an objective fit's options."""
    from seal.experiments.fitting.objective import resolve_config

    return resolve_config(
        preset=o.get("preset", "standard"), config_file=o.get("config"), prior=o.get("prior"),
        candidates=o.get("candidates"), eval_split=o.get("eval_split"), eval_limit=o.get("eval_limit"),
        workers=o.get("workers"), seed=o.get("seed"), split=o.get("split"), limit=o.get("limit"),
        skills=o.get("skills"), behavior=o.get("behavior"), egos=o.get("egos"), sets=fit_overrides(o),
    )


def behavior_config(o: Mapping[str, Any]) -> Any:
    """The `BehaviorFitConfig` of a behaviour fit's options."""
    from seal.experiments.fitting.behavior import resolve_config

    return resolve_config(
        preset=o.get("preset", "standard"), config_file=o.get("config"), split=o.get("split"), limit=o.get("limit"),
        eval_split=o.get("eval_split"), eval_limit=o.get("eval_limit"), max_samples=o.get("max_samples"),
        crash_datasets=o.get("crash_datasets"), seeds=None if o.get("seed") is None else [o["seed"]],
        threads=o.get("threads"), sets=fit_overrides(o),
    )


FIT_CONFIGS: dict[str, Callable[[Mapping[str, Any]], Any]] = {
    "goose": goose_config, "skills": skills_config, "objective": objective_config, "behavior": behavior_config,
}
"""The fits whose config a ``set`` option overrides, and how each resolves its options to its config."""


def fit_goose(dataset: str, out: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal fit goose DATASET --out OUT``."""
    from seal.experiments.fitting.goose import FIT_THREADS, fit_goose

    config = goose_config(o)
    _torch_threads(FIT_THREADS)
    return fit_goose(dataset, out, config, run_dir=o.get("run_dir"), progress=not o.get("no_progress", False))


def fit_skills(dataset: str, out: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal fit skills DATASET --out OUT``."""
    from seal.experiments.fitting.skills import fit_skills

    config = skills_config(o)
    _torch_threads(config.threads)
    return fit_skills(dataset, out, config, demos_path=o.get("demos"), progress=not o.get("no_progress", False))


def fit_objective(dataset: str, out: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal fit objective DATASET --out OUT``."""
    from seal.experiments.fitting.objective import fit_objective

    config = objective_config(o)
    _torch_threads(config.threads)
    return fit_objective(dataset, out, config, progress=not o.get("no_progress", False))


def fit_behavior(dataset: str, out: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal fit behavior DATASET --out OUT`` (RCG's behaviour embedding; ``crash_datasets``: a list of folders)."""
    from seal.experiments.fitting.behavior import fit_behavior

    config = behavior_config(o)
    _torch_threads(config.threads)
    return fit_behavior(dataset, out, config, progress=not o.get("no_progress", False))


def fit_probes(dataset: str, out: str, o: dict[str, Any]) -> dict[str, Any]:
    """``seal fit probes PRIOR DATASET --out OUT``: the steering folder of the ``steered`` generator (``prior``:
    the prior file, e.g. ``"${fit.prior}"``)."""
    from seal.core.config import load_config
    from seal.core.dataset import load_split
    from seal.experiments.steering.fit import ProbeFitConfig, fit_probes
    from seal.models.prior.prior import TrajectoryPrior

    if not o.get("prior"):
        raise ValueError("fit probes: option 'prior' is required (the prior file, e.g. \"${fit.prior}\")")
    cfg = load_config(ProbeFitConfig, file=o.get("config"),
                      values={k: o.get(k) for k in ("split", "limit", "max_targets", "seed")})
    _torch_threads(1)  # as `seal fit probes`: batch inference of a small transformer is fastest on one thread
    prior = TrajectoryPrior.load(str(o["prior"]))
    scenarios = load_split(dataset, cfg.split, cfg.limit)
    info = {"prior": str(Path(str(o["prior"])).resolve()), "dataset": str(Path(dataset).resolve()),
            "split": cfg.split, "scenarios": len(scenarios)}
    report = fit_probes(prior, scenarios, out, cfg, info=info, progress=not o.get("no_progress", False))
    return {"best_site": report.get("best_site"), "vectors": len(report.get("vectors") or [])}


FITS: dict[str, Callable[[str, str, dict[str, Any]], Any]] = {
    "prior": fit_prior, "goose": fit_goose, "skills": fit_skills, "objective": fit_objective,
    "behavior": fit_behavior, "probes": fit_probes,
}
