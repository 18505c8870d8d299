"""``seal run PRESET.yaml``: the whole experiment, from data to report, skipping steps already done.

Read top to bottom, the steps are:

1. data     generate / score / split (as ``seal data generate | score | split``) into OUT/data (or use
            ``data.path`` as is), then the held-out pools the preset builds (``eval.heldout`` entries with
            ``generate``) into OUT/heldout/<name>
2. fit      the prior / goose / skills / objective (as ``seal fit NAME``) into OUT/models, only the models that the
            generators in use reference (``"${fit.NAME}"`` in ``generators``), or the file given as ``fit.NAME.path``
3. train    one job per pipeline x seed (`seal.experiments.training.train.train_run`) into OUT/runs/<pipeline>-s<seed>
            (x algorithm with ``algos``: OUT/runs/<pipeline>-<algo>-s<seed>)
4. eval     one job per trained ego, plus the Replay ego (`seal.experiments.evaluation.evaluate.evaluate_job`),
            into OUT/results.sqlite; the progress bar counts the episodes in the store as the jobs write them
            (`seal.experiments.evaluation.store_progress`)
5. report   `seal.experiments.report.write.write_report` into OUT/report

Each step leaves a marker ``OUT/steps/<step>.json`` holding a hash of its parameters; a step whose marker
matches is skipped, a step whose parameters changed runs again (it resumes or overwrites as the matching command
does). Train jobs count as done when their run folder has ``done.json``; evaluation is incremental through the
results store. Every step is a Python call (`seal.experiments.pipeline.tasks.run_task`, `train_job`,
`seal.experiments.evaluation.evaluate.evaluate_job`) run through a backend (`seal.experiments.backends`): data and
fit steps one at a time in a fresh worker process (as the ``seal`` commands ran before), train and eval jobs in
local processes or Ray tasks, all writing to the same run folders and store.

The preset's sections (all but ``train`` belong to this module; ``train`` is passed to the trainer):

* ``data``: ``path`` (an existing scored, split dataset) or ``generate`` / ``score`` / ``split`` options
  (the command's options without dashes, e.g. ``split: {n_train: 80}`` = ``--n-train 80``;
  `seal.experiments.pipeline.tasks`).
* ``fit``: per model (``prior``, ``goose``, ``skills``, ``objective``, ``behavior``, ``probes``) either
  ``{path: FILE}`` or command options (``{preset: quick, max_minutes: 1}``; ``"${fit.prior}"`` in them = another
  fitted model, fitted first). Any other name with ``model: KIND`` is a second fit of that kind under its own
  name (``ego_skills: {model: skills, preset: ego}`` -> OUT/models/ego_skills). ``"${runs.NAME}"`` in a fit's
  options is this plan's training run NAME (e.g. ``objective: {egos: [heuristic, "${runs.noadv-td3-s0}"]}``): that
  fit waits for the runs that do not need it, and the runs that need its model train after it (steps 2-3 then
  alternate: fits, runs without the late models, the late fits, the other runs).
* ``generators``: generator name -> constructor kwargs for training and evaluation; a value ``"${fit.prior}"``
  becomes the fitted model's path.
* ``train``: `seal.experiments.training.config.EgoTrainConfig` keys; ``"${fit.NAME}"`` in it = a fitted model
  (``hyperparams: {reskill: {skills: "${fit.skills}"}}`` for the ReSkill ego).
* ``pipelines``: training pipelines (``noadv`` = no adversary; ``goose``, ``cat``, ``seal``, ... = that
  generator; or a name of ``variants``); ``seeds``: list of seeds; ``algos`` (optional): ego algorithms to train
  each pipeline x seed with (``[reskill, td3]``: the main and a secondary row of the report, which labels and
  compares them apart, `seal.experiments.report.grouping`); ``algo_train`` (optional): algorithm -> ``train``
  settings for that algorithm's runs only (``{td3: {deadline_obs: false}}``), applied after ``train``.
* ``variants``: pipeline name -> ``{generator: NAME, kwargs: {...}, train: {...}}``: a training pipeline that uses
  generator NAME with its ``generators`` kwargs updated by ``kwargs``, and the ``train`` section updated by
  ``train`` (nested keys, e.g. ``{curriculum: {warmup: 0.0}}``): the training-pipeline ablations of thesis
  Fig. 6.5 (``experiments/configs/quick_ablations.yaml``); ``generator: noadv`` is a variant without adversary
  (``{noadv-dl: {generator: noadv, train: {deadline_obs: true}}}``: the time-aware No-Adv ego).
* ``eval``: ``settings`` (list, as ``seal eval runs --settings``), ``k``, ``limit``, ``seed``, ``prior``,
  ``candidates``, ``env``, ``replay_ego`` (default true), ``egos`` (reference egos evaluated beside the
  trained ones: ``[heuristic]``, or run folders / SB3 models / ``seal.egos`` entry points of other experiments),
  ``heldout`` (pools whose eval / hard splits the egos also play, every setting but ``real:``: pools generated
  with another seed and split with ``seal data split --n-train 0``, scenarios from traffic runs that neither the
  training nor the fits saw; the report labels them ``normal@<pool>``): each a dataset folder, or
  ``{name, generate, score, split}`` (options as in ``data``) for a pool the run builds into OUT/heldout/<name>.
* ``report``: ``plots`` (default true), ``videos`` (per generator, default 0), ``video_format``, ``reps`` /
  ``poi_reps`` (bootstrap resamples of the intervals / probabilities of improvement, as ``seal compare``).
* ``backend``: ``name`` (local | ray), ``workers``, ``address`` (Ray), ``train_workers`` (local: concurrent train
  jobs, when each trainer already runs several env processes), ``fit_workers`` (fits run side by side when none
  uses another's model, default 1: one after the other); the command line overrides name and workers.
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field, fields
from functools import partial
from pathlib import Path
from typing import Any

import yaml

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.config import apply_overrides, check_keys, safe_load_file
from seal.experiments.backends import Backend, InlineBackend, Job, JobResult, LocalBackend, make_backend
from seal.experiments.pipeline.drift import describe_drift, fit_drift
from seal.experiments.pipeline.location import relocate
from seal.experiments.pipeline.plan import check_plan
from seal.experiments.pipeline.references import (
    dotted,
    eval_egos,
    eval_settings,
    fits_needed,
    generator_of,
    generators_in_use,
    heldout_pools,
    late_fits,
    late_runs,
    planned_runs,
    run_refs,
    substitute,
    variant_of,
    with_algo,
    with_models,
)
from seal.experiments.pipeline.reuse import apply_reuse, describe, reuse_plan
from seal.experiments.pipeline.steps import FIT_OUTPUTS, Steps, data_steps, fit_steps, heldout_steps, run_steps
from seal.experiments.pipeline.tasks import run_task

logger = logging.getLogger(__name__)



@dataclass(frozen=True)
class RunPreset:
    """The sections of a ``seal run`` preset (``experiments/configs/quick|standard|paper|decisive.yaml``); each
    step's own config type checks its section when the step runs."""

    data: dict[str, Any] = field(default_factory=dict)
    """How to build, score and split the pool (options of ``seal data generate / score / split``), or ``path:``."""
    fit: dict[str, Any] = field(default_factory=dict)
    """Model name -> fit options (``seal fit NAME``), or ``path:`` of an existing model."""
    generators: dict[str, Any] = field(default_factory=dict)
    """Generator name -> constructor kwargs (``"${fit.NAME}"`` = a fitted model's path)."""
    pipelines: list[str] = field(default_factory=list)
    """Training pipelines (``noadv`` and the registry's training generators)."""
    seeds: list[int] = field(default_factory=list)
    """Training seeds per pipeline."""
    eval: dict[str, Any] = field(default_factory=dict)
    """`seal.experiments.evaluation.evaluate.EvalRunsConfig` keys plus ``settings``."""
    report: dict[str, Any] = field(default_factory=dict)
    """Report options (plots, videos, video_format)."""
    backend: dict[str, Any] = field(default_factory=dict)
    """Backend options (name, workers, address)."""
    train: dict[str, Any] = field(default_factory=dict)
    """`seal.experiments.training.config.EgoTrainConfig` keys."""
    variants: dict[str, Any] = field(default_factory=dict)
    """Pipeline name -> ``{generator, kwargs, train}``: a variant of a generator's training pipeline."""
    algos: list[str] = field(default_factory=list)
    """Ego algorithms (``train.algo`` values) each pipeline x seed is trained with, run folders
    ``<pipeline>-<algo>-s<seed>``; empty: the train section's ``algo`` only, run folders ``<pipeline>-s<seed>``."""
    algo_train: dict[str, Any] = field(default_factory=dict)
    """Ego algorithm -> ``train`` settings for that algorithm's runs only, on top of ``train`` (nested keys)."""
    preset: str = ""
    """The preset's name (default: the file name)."""
    reuse: str = ""
    """Another run folder whose data and fitted models this run takes where they were made with exactly this
    preset's options (`seal.experiments.pipeline.reuse`); the rest is made here."""


SECTIONS = tuple(f.name for f in fields(RunPreset))

# ---------------------------------------------------------------------------------------------- config
def load_run_config(path: str | Path, sets: Sequence[str] = ()) -> dict[str, Any]:
    """The preset YAML with ``sets`` (``section.key=value``, e.g. ``eval.limit=5``) applied, checked: known
    sections, ``pipelines`` and ``seeds`` present."""
    path = Path(path)
    config = safe_load_file(path) or {}
    if not isinstance(config, dict):
        raise ValueError(f"{path}: expected a mapping of sections ({', '.join(SECTIONS)})")
    check_keys(RunPreset, config, str(path))
    if sets:
        config = apply_overrides(config, sets)
        check_keys(RunPreset, config, "--set")
    for key in ("pipelines", "seeds"):
        if not isinstance(config.get(key), list) or not config[key]:
            raise ValueError(f"{path}: '{key}' must be a non-empty list")
    if not isinstance(config.get("algos") or [], list):
        raise ValueError(f"{path}: 'algos' must be a list of ego algorithms, got {config['algos']!r}")
    for key in ("data", "fit", "generators", "eval", "report", "backend", "train"):
        if config.get(key) is not None and not isinstance(config[key], dict):
            raise ValueError(f"{path}: '{key}' must be a mapping of options, got {config[key]!r}")
    algo_train = config.get("algo_train") or {}
    if not isinstance(algo_train, dict) or not all(isinstance(v, dict) for v in algo_train.values()):
        raise ValueError(f"{path}: 'algo_train' must be a mapping of ego algorithm -> train settings, got "
                         f"{algo_train!r}")
    from seal.experiments.training.config import ALGOS

    unknown = sorted(set(algo_train) - set(ALGOS))  # one the plan does not train is ignored (--set algos=[...])
    if unknown:
        raise ValueError(f"{path}: 'algo_train' names unknown ego algorithm(s) {unknown}; known: {list(ALGOS)}")
    if not isinstance(config.get("variants") or {}, dict):
        raise ValueError(f"{path}: 'variants' must be a mapping of pipeline name -> {{generator, kwargs, train}}")
    for name in config.get("variants") or {}:
        variant_of(config, name)  # a malformed variant fails here, before any step runs
    config.setdefault("preset", path.stem)
    if config.get("reuse"):
        config = apply_reuse(config, reuse_plan(config, Path(str(config["reuse"])).expanduser().resolve()))
    return config


# ---------------------------------------------------------------------------------------------- jobs
def train_job(job: Job) -> dict[str, Any]:
    """One training run (a picklable backend job, the worker's entry point): ``train_run(job["config"], job["out"])``,
    resuming an interrupted run; torch threads as the run's ``torch_threads``."""
    import torch

    from seal.experiments.training.state import run_status
    from seal.experiments.training.train import run_torch_threads, train_run

    out = Path(job["out"])
    # An interrupted run (config.yaml, no done.json) continues from its last checkpoint.
    resume = run_status(out) == "unfinished"
    torch.set_num_threads(run_torch_threads(job["config"], out, resume))
    path = train_run(dict(job["config"]), out, resume=resume, progress=False)
    return {"run": str(path)}


def train_config(config: Mapping[str, Any], preset_path: Path, pipeline: str, seed: int, dataset: str,
                 generators: Mapping[str, Any]) -> dict[str, Any]:
    """The resolved trainer config of one run: the preset's ``train`` section via
    ``seal.experiments.training.train.load_train_config`` plus the run's pipeline, seed, dataset and generator (the
    ``generators`` kwargs, fitted model paths filled in, replace the train section's ``pipelines.<pipeline>``)."""
    from seal.experiments.training.train import load_train_config

    gen = generator_of(pipeline, config)
    variant = variant_of(config, pipeline)
    # The run config's train section (the preset's, with any --set train.* applied), then the algorithm's, then the
    # variant's.
    train = dict(config.get("train") or {})
    per_algo = (config.get("algo_train") or {}).get(train.get("algo")) or {}
    overrides: dict[str, Any] = {**dotted("", train), **dotted("", per_algo), **dotted("", variant.get("train") or {}),
                                 "pipeline": pipeline, "seed": int(seed), "dataset": dataset}
    if gen:
        kwargs = {**dict(generators.get(gen) or {}), **dict(variant.get("kwargs") or {})}
        overrides[f"pipelines.{pipeline}"] = {"name": gen, "kwargs": kwargs}
    elif variant:  # a variant of noadv: trains without an adversary under its own name (overrides skip None)
        return load_train_config(preset_path, overrides, sets=[f"pipelines.{pipeline}=null"])
    return load_train_config(preset_path, overrides)


def _failures(kind: str, results: Sequence[JobResult]) -> list[str]:
    errors = []
    for r in results:
        if not r.ok:
            errors.append(f"{kind} {r.job.get('name', '?')}: {r.error}")
            logger.error(f"[seal run] FAILED {errors[-1]}")
    return errors


# ---------------------------------------------------------------------------------------------- pipeline
@dataclass
class _Run:
    """What the steps of one `run_pipeline` call share."""

    config_path: Path
    out: Path
    config: dict[str, Any]
    backend: Backend
    step_backend: Backend
    task_fn: Callable[[Job], Any]
    train_fn: Callable[[Job], Any]
    eval_fn: Callable[[Job], Any]
    train_config_fn: Callable[..., dict[str, Any]]
    progress: bool
    steps: Steps
    errors: list[str] = field(default_factory=list)

    def task(self, job: dict[str, Any]) -> None:
        """One data / fit step through the step backend; a failure stops the pipeline."""
        (result,) = self.step_backend.map(self.task_fn, [job], desc=str(job["name"]), progress=self.progress)
        if not result.ok:
            # The error's first line says what went wrong (a SplitError's advice, ...); the traceback tail under it
            # is for debugging, printed with SEAL_DEBUG=1 as the other commands do.
            error = str(result.error)
            shown = error if os.environ.get("SEAL_DEBUG") else error.split("\n", 1)[0]
            raise RuntimeError(f"step {job['name']} failed: {shown}")


def check_run(config_path: str | Path, out: str | Path, sets: Sequence[str] = (),
              train_config_fn: Callable[..., dict[str, Any]] = train_config) -> dict[str, Any]:
    """``seal run --check``: load ``config_path`` and check its whole plan (`check_plan`) without writing anything;
    returns what it would run: the training runs, the models to fit and the evaluation settings."""
    from seal.experiments.evaluation.evaluate import DEFAULTS

    config_path, out = Path(config_path).resolve(), Path(out).resolve()
    config = load_run_config(config_path, sets)
    check_plan(config, config_path, out, train_config_fn, FIT_OUTPUTS)
    ev = config.get("eval") or {}
    return {"preset": config["preset"], "out": str(out), "runs": list(planned_runs(config)),
            "fits": fits_needed(config), "generators": generators_in_use(config),
            "reuse": describe(config, fits_needed(config)) if config.get("reuse") else None,
            "eval_settings": list(ev.get("settings") or ["normal", "hard"]), "eval_k": ev.get("k", DEFAULTS["k"]),
            "eval_heldout": heldout_pools(config, out)}


def run_pipeline(
    config_path: str | Path, out: str | Path, backend: Backend | None = None, workers: int | None = None,
    task_fn: Callable[[Job], Any] = run_task, train_fn: Callable[[Job], Any] = train_job,
    eval_fn: Callable[[Job], Any] | None = None, train_config_fn: Callable[..., dict[str, Any]] = train_config,
    step_backend: Backend | None = None, progress: bool = True, sets: Sequence[str] = (),
) -> dict[str, Any]:
    """Run the experiment of ``config_path`` into ``out`` (module docstring). ``task_fn`` runs the data / fit steps
    (on ``step_backend``, default: one fresh worker process per step, in this process with an inline
    ``backend``), ``train_fn`` / ``eval_fn`` are the per-job functions and ``train_config_fn`` builds a run's
    trainer config (injectable for tests); ``sets`` are ``--set`` overrides of the preset (`load_run_config`).
    Returns a summary; raises after the report if any job failed."""
    from seal.experiments.evaluation.evaluate import evaluate_job

    config_path, out = Path(config_path).resolve(), Path(out).resolve()
    config = load_run_config(config_path, sets)
    check_plan(config, config_path, out, train_config_fn, FIT_OUTPUTS)  # every step's config, before any file
    if config.get("reuse"):
        logger.info(f"[seal run] {describe(config, fits_needed(config))}")
    out.mkdir(parents=True, exist_ok=True)
    moved = relocate(out)  # a moved or copied run folder: its store and run configs point here before any step
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(config, sort_keys=False).encode())
    if backend is None:
        bcfg = config.get("backend") or {}
        backend = make_backend(bcfg.get("name", "local"), workers if workers is not None else bcfg.get("workers"),
                               address=bcfg.get("address"))
    if step_backend is None:
        step_backend = InlineBackend() if isinstance(backend, InlineBackend) else LocalBackend(1)
    run = _Run(config_path, out, config, backend, step_backend, task_fn, train_fn, eval_fn or evaluate_job,
               train_config_fn, progress, Steps(out, [m.old for m in moved]))
    started = time.perf_counter()
    dataset, data_params = _data_steps(run)
    late = late_fits(config)  # fits that label against trained egos ("${runs.NAME}"): after the runs they name
    models = _fit_steps(run, dataset, data_params, skip=late)
    run.config = with_models(config, models)  # the train section's "${fit.NAME}" (the ReSkill ego's skills)
    generators = {name: substitute(dict((config.get("generators") or {}).get(name) or {}), models)
                  for name in generators_in_use(config)}
    waiting = late_runs(config)
    n_jobs, trained = _train_step(run, dataset, generators, skip=waiting)
    if late and _late_fits_can_run(run, late):
        _fit_steps(run, dataset, data_params, only=late)
        n_late, trained = _train_step(run, dataset, generators, only=waiting)
        n_jobs += n_late
    store = _eval_step(run, dataset, generators, trained)
    report = _report_step(run, store)
    summary = {
        "out": str(out), "dataset": dataset, "models": models, "runs": trained, "store": store,
        "report": str(report / "report.md"), "steps_ran": run.steps.ran, "steps_skipped": run.steps.skipped,
        "train_jobs": n_jobs, "seconds": round(time.perf_counter() - started, 1), "errors": run.errors,
    }
    atomic_write_json(out / "summary.json", summary)
    if run.errors:
        raise RuntimeError(f"{len(run.errors)} job(s) failed (see {out / 'summary.json'}):\n" + "\n".join(run.errors))
    return summary


def _data_steps(run: _Run) -> tuple[str, dict[str, Any]]:
    """1. data: generate, score and split OUT/data (or take ``data.path``), then the held-out pools to build;
    returns the dataset folder and the data parameters (the fits run again when they change)."""
    dataset, data_params, steps = data_steps(run.config, run.out)
    # The held-out pools the preset builds come next, not just before the evaluation: a pool that cannot be split as
    # asked (too few Hard scenes) then fails in minutes, not after hours of training.
    for step in [*steps, *heldout_steps(run.config, run.out)]:
        run.steps.run(step.name, step.params, partial(run.task, step.job))
    return dataset, data_params


def _fit_steps(run: _Run, dataset: str, data_params: Mapping[str, Any], skip: Collection[str] = (),
               only: Collection[str] | None = None) -> dict[str, str]:
    """2. fit the models the generators in use need, dependencies first (those named in ``skip`` not, with ``only``
    those named there alone); returns model name -> path (of every model, fitted now or not)."""
    models, steps = fit_steps(run.config, run.out, dataset, data_params)
    steps = [s for s in steps if s.name[len("fit-"):] not in skip and (only is None or s.name[len("fit-"):] in only)]
    if steps:
        (run.out / "models").mkdir(exist_ok=True)
    # Fits are single processes, most of them one thread: backend.fit_workers runs independent ones side by side.
    fit_workers = int((run.config.get("backend") or {}).get("fit_workers") or 1)
    for step in steps:
        if run.steps.done(step.name, step.params) and (drift := fit_drift(step)):
            logger.warning(f"[seal run] {step.name}: done with settings the code now resolves otherwise, kept as "
                           f"fitted (a fresh folder or a --set of the fit refits it): {describe_drift(drift)}")
    run_steps(steps, lambda step: run.steps.run(step.name, step.params, partial(run.task, step.job)), fit_workers)
    return models


def _late_fits_can_run(run: _Run, late: Sequence[str]) -> bool:
    """Whether every training run the ``late`` fits label against has finished; else the failure is recorded and
    those fits and the runs that need them wait for the next ``seal run``."""
    fit = run.config.get("fit") or {}
    missing = sorted({r for name in late for r in run_refs(dict(fit[name] or {}))
                      if not (run.out / "runs" / r / "done.json").is_file()})
    if missing:
        run.errors.append(f"fit {', '.join(late)}: training run(s) {', '.join(missing)} did not finish, so the fit and "
                          "the runs that use its model wait (run `seal run` again)")
    return not missing


def _train_step(run: _Run, dataset: str, generators: Mapping[str, Any], skip: Collection[str] = (),
                only: Collection[str] | None = None) -> tuple[int, list[str]]:
    """3. train one ego per pipeline x seed (finished run folders skipped; runs named in ``skip`` not, with
    ``only`` those alone); returns the number of train jobs and this preset's finished run folders."""
    jobs = []
    runs = {run.out / "runs" / name: spec for name, spec in planned_runs(run.config).items()}
    for run_dir, (pipeline, seed, algo) in runs.items():
        if run_dir.name in skip or (only is not None and run_dir.name not in only):
            continue
        if (run_dir / "done.json").is_file():
            logger.info(f"[seal run] train {run_dir.name}: done, skipped")
            continue
        cfg = run.train_config_fn(with_algo(run.config, algo), run.config_path, pipeline, seed, dataset, generators)
        jobs.append({"name": run_dir.name, "config": cfg, "out": str(run_dir)})
    # Trainers may run several env processes each: backend.train_workers caps concurrent local train jobs.
    train_workers = (run.config.get("backend") or {}).get("train_workers")
    backend = (make_backend("local", int(train_workers)) if train_workers and run.backend.name == "local"
               else run.backend)
    if jobs:
        logger.info(f"[seal run] train: {len(jobs)} job(s) on the {backend.name} backend")
    run.errors += _failures("train", backend.map(run.train_fn, jobs, desc="train", progress=run.progress))
    return len(jobs), [str(d) for d in runs if (d / "done.json").is_file()]


def _eval_step(run: _Run, dataset: str, generators: Mapping[str, Any], trained: Sequence[str]) -> str:
    """4. evaluate every trained ego, the preset's reference egos (``eval.egos``) and the Replay ego into
    OUT/results.sqlite; returns the store path."""
    from seal.experiments.evaluation.evaluate import resolve_eval_config

    ev = dict(run.config.get("eval") or {})
    store = str(run.out / "results.sqlite")
    eval_config = resolve_eval_config(k=ev.get("k"), limit=ev.get("limit"), seed=ev.get("seed"), prior=ev.get("prior"),
                                      candidates=ev.get("candidates"), env=ev.get("env"))
    eval_config["generators"] = generators
    settings = eval_settings(run.config, dataset, run.out)
    egos = eval_egos(run.config, trained)
    jobs = [{"name": Path(e).name, "store": store, "run": e, "settings": [vars(s) for s in settings],
             "config": eval_config, "progress": False} for e in egos]

    def evaluate() -> bool:
        from seal.experiments.evaluation.store_progress import StoreProgress, expected_rows

        # The jobs (one per ego) write rows as they go: the bar counts those, not finished egos (minutes apart).
        total = expected_rows(egos, settings, eval_config.get("limit"))
        with StoreProgress(store, egos, [s.name for s in settings], total, desc=f"eval ({len(egos)} egos)",
                           disable=not run.progress):
            results = run.backend.map(run.eval_fn, jobs, desc="eval", progress=False)
        failed = _failures("eval", results)
        run.errors.extend(failed)  # reported at the end; the report covers what was evaluated
        return not failed

    run.steps.run("eval", [egos, [vars(s) for s in settings], eval_config], evaluate)
    return store


def _prior_threads() -> None:
    """Report videos re-simulate prior-based generators in this process: torch threads as the evaluation workers
    had them (`seal.adversaries.candidate_sources.PRIOR_THREADS`), so the videos show the scored episodes."""
    import torch

    from seal.adversaries.candidate_sources import PRIOR_THREADS

    torch.set_num_threads(PRIOR_THREADS)


def _report_step(run: _Run, store: str) -> Path:
    """5. the report of what the store holds into OUT/report; returns that folder."""
    rep = dict(run.config.get("report") or {})
    report_dir = run.out / "report"
    if not Path(store).is_file():
        return report_dir
    from seal.experiments.evaluation.results_store import ResultsStore
    from seal.experiments.report.stats import N_BOOT, N_BOOT_POI
    from seal.experiments.report.write import write_report

    with ResultsStore(store) as s:
        n_episodes = s.count()
    if n_episodes:
        if int(rep.get("videos", 0)) > 0:
            _prior_threads()
        run.steps.run("report", [rep, n_episodes], lambda: write_report(
            store, report_dir, plots=rep.get("plots", True), videos=int(rep.get("videos", 0)),
            video_format=rep.get("video_format", "mp4"), progress=run.progress,
            n_boot=int(rep.get("reps") or N_BOOT), n_boot_poi=int(rep.get("poi_reps") or N_BOOT_POI),
        ))
    return report_dir
