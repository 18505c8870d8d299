"""``seal run PRESET.yaml``: the whole experiment, from data to report, skipping steps already done.

Read top to bottom, the steps are:

1. data     ``seal data generate`` / ``score`` / ``split`` into OUT/data (or use ``data.path`` as is)
2. fit      ``seal fit prior | goose | skills | objective`` into OUT/models, only the models that the generators
            in use reference (``"${fit.NAME}"`` in ``generators``), or the file given as ``fit.NAME.path``
3. train    one job per pipeline x seed (`seal.experiments.training.train.train_run`) into OUT/runs/<pipeline>-s<seed>
4. eval     one job per trained ego, plus the Replay ego (`seal.experiments.evaluation.evaluate.evaluate_job`) into
            OUT/results.sqlite
5. report   `seal.experiments.report.write.write_report` into OUT/report

Each step leaves a marker ``OUT/steps/<step>.json`` holding a hash of its parameters; a step whose marker
matches is skipped, a step whose parameters changed runs again (its command resumes or overwrites as that
command does). Train jobs count as done when their run folder has ``done.json``; evaluation is incremental
through the results store. Train and eval jobs go through a backend (`seal.experiments.backends`): local
processes
or Ray tasks, all writing to the same run folders and store.

The preset's sections (all but ``train`` belong to this module; ``train`` is passed to the trainer):

* ``data``: ``path`` (an existing scored, split dataset) or ``generate`` / ``score`` / ``split`` options
  (each key becomes the command's ``--key``, e.g. ``split: {n_train: 80}`` -> ``--n-train 80``).
* ``fit``: per model (``prior``, ``goose``, ``skills``, ``objective``) either ``{path: FILE}`` or command
  options (``{preset: quick, max_minutes: 1}``; ``"${fit.prior}"`` in them = another fitted model, fitted first).
* ``generators``: generator name -> constructor kwargs for training and evaluation; a value ``"${fit.prior}"``
  becomes the fitted model's path.
* ``pipelines``: training pipelines (``noadv`` = no adversary; ``goose``, ``cat``, ``seal``, ... = that
  generator); ``seeds``: list of seeds.
* ``eval``: ``settings`` (list, as ``seal eval runs --settings``), ``k``, ``limit``, ``seed``, ``prior``,
  ``candidates``, ``env``, ``replay_ego`` (default true).
* ``report``: ``plots`` (default true), ``videos`` (per generator, default 0), ``video_format``.
* ``backend``: ``name`` (local | ray), ``workers``, ``address`` (Ray), ``train_workers`` (local: concurrent train
  jobs, when each trainer already runs several env processes); the command line overrides name and workers.
"""

from __future__ import annotations

import hashlib
import json
import re
import subprocess
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.experiments.backends import Backend, Job, JobResult, make_backend

SECTIONS = ("data", "fit", "generators", "pipelines", "seeds", "eval", "report", "backend", "train", "preset")
NO_ADVERSARY = "noadv"
FIT_OUTPUTS = {"prior": "prior.pt", "goose": "goose.zip", "skills": "skills", "objective": "objective"}
"""Model name -> file or folder written under OUT/models by ``seal fit NAME DATASET --out ...``."""
FIT_ARGS = {"prior": ["--split", "all-but-eval"]}
"""Extra fixed arguments per fit command (the prior must not see the eval split)."""
REF = re.compile(r"^\$\{fit\.(\w+)\}(.*)$")
"""``"${fit.NAME}"`` or ``"${fit.NAME}/file inside it"`` in generator kwargs: a fitted model's path."""

CommandRunner = Callable[[Sequence[str]], None]


# ---------------------------------------------------------------------------------------------- config
def load_run_config(path: str | Path) -> dict[str, Any]:
    """The preset YAML, checked: known sections, ``pipelines`` and ``seeds`` present."""
    path = Path(path)
    config = yaml.safe_load(path.read_text()) or {}
    if not isinstance(config, dict):
        raise ValueError(f"{path}: expected a mapping of sections ({', '.join(SECTIONS)})")
    unknown = sorted(set(config) - set(SECTIONS))
    if unknown:
        raise ValueError(f"{path}: unknown section(s) {unknown}; known: {list(SECTIONS)}")
    for key in ("pipelines", "seeds"):
        if not isinstance(config.get(key), list) or not config[key]:
            raise ValueError(f"{path}: '{key}' must be a non-empty list")
    config.setdefault("preset", path.stem)
    return config


def cli_options(options: Mapping[str, Any] | None) -> list[str]:
    """``{n_train: 80, no_eval: true, layouts: [a, b]}`` -> ``--n-train 80 --no-eval --layouts a b``."""
    argv: list[str] = []
    for key, value in (options or {}).items():
        flag = "--" + str(key).replace("_", "-")
        if value is True:
            argv.append(flag)
        elif value is False or value is None:
            continue
        elif isinstance(value, list | tuple):
            argv += [flag, *map(str, value)]
        else:
            argv += [flag, str(value)]
    return argv


def generator_of(pipeline: str) -> str | None:
    """The adversary generator a training pipeline uses (None for ``noadv``)."""
    return None if pipeline == NO_ADVERSARY else pipeline


def generators_in_use(config: Mapping[str, Any]) -> list[str]:
    """Generators of the training pipelines and of the eval settings, in order of first use."""
    from seal.adversaries.base import available_generators

    names = [generator_of(p) for p in config["pipelines"]]
    names += [s for s in (config.get("eval") or {}).get("settings", []) if s in available_generators()]
    return [n for n in dict.fromkeys(names) if n]


def _refs(value: Any) -> list[str]:
    """Names of the fitted models referenced (``"${fit.NAME}"``) anywhere in ``value``."""
    if isinstance(value, dict):
        return [r for v in value.values() for r in _refs(v)]
    if isinstance(value, list):
        return [r for v in value for r in _refs(v)]
    m = REF.match(value) if isinstance(value, str) else None
    return [m.group(1)] if m else []


def fits_needed(config: Mapping[str, Any]) -> list[str]:
    """Models referenced (``"${fit.NAME}"``) by the kwargs of the generators in use, plus the models those fits'
    options reference in turn (e.g. ``objective: {prior: "${fit.prior}"}``); ordered so that every model comes
    after the ones its fit uses."""
    gens, fit = config.get("generators") or {}, config.get("fit") or {}
    wanted = [r for name in generators_in_use(config) for r in _refs(gens.get(name) or {})]
    order: list[str] = []

    def visit(name: str, chain: tuple[str, ...]) -> None:
        if name in order:
            return
        if name in chain:
            raise ValueError(f"fit: circular references {' -> '.join((*chain, name))}")
        if name not in fit:
            raise ValueError(f"the preset references ${{fit.{name}}} but has no fit.{name} entry")
        spec = fit[name] or {}
        for dep in ([] if spec.get("path") else _refs(spec)):
            visit(dep, (*chain, name))
        order.append(name)

    for name in dict.fromkeys(wanted):
        visit(name, ())
    return order


def substitute(value: Any, models: Mapping[str, str]) -> Any:
    """Replace ``"${fit.NAME}"`` strings (at any depth) by the fitted model paths."""
    if isinstance(value, dict):
        return {k: substitute(v, models) for k, v in value.items()}
    if isinstance(value, list):
        return [substitute(v, models) for v in value]
    m = REF.match(value) if isinstance(value, str) else None
    return models[m.group(1)] + m.group(2) if m else value


# ---------------------------------------------------------------------------------------------- steps
class Steps:
    """Done-markers under OUT/steps: a step is done when its marker holds the same parameter hash."""

    def __init__(self, out: Path, log: Callable[[str], None] = print) -> None:
        self.dir = out / "steps"
        self.log = log
        self.ran: list[str] = []
        self.skipped: list[str] = []

    @staticmethod
    def digest(params: Any) -> str:
        return hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()[:16]

    def done(self, name: str, params: Any) -> bool:
        path = self.dir / f"{name}.json"
        if not path.is_file():
            return False
        return json.loads(path.read_text()).get("params") == self.digest(params)

    def run(self, name: str, params: Any, action: Callable[[], Any]) -> bool:
        """Run ``action`` unless ``name`` is done with these ``params``; returns True if it ran. The marker is
        written when ``action`` returns anything but False (False: partly failed, run it again next time)."""
        if self.done(name, params):
            self.log(f"[seal run] {name}: done, skipped")
            self.skipped.append(name)
            return False
        self.log(f"[seal run] {name}: running")
        start = time.perf_counter()
        if action() is False:
            return True
        atomic_write_json(self.dir / f"{name}.json", {
            "params": self.digest(params), "seconds": round(time.perf_counter() - start, 2), "finished": time.time(),
        })
        self.ran.append(name)
        return True


def run_seal_command(argv: Sequence[str]) -> None:
    """``python -m seal ARGV`` in a child process (its own progress bars; a failure raises)."""
    result = subprocess.run([sys.executable, "-m", "seal", *map(str, argv)], check=False)
    if result.returncode != 0:
        raise RuntimeError(f"`seal {' '.join(map(str, argv))}` failed with exit status {result.returncode}")


# ---------------------------------------------------------------------------------------------- jobs
def train_job(job: Job) -> dict[str, Any]:
    """One training run (a picklable backend job): ``seal.experiments.training.train.train_run(job["config"],
    job["out"],
    resume=True)``."""
    import torch

    torch.set_num_threads(1)
    from seal.experiments.training.state import run_status
    from seal.experiments.training.train import train_run

    out = Path(job["out"])
    # An interrupted run (config.yaml, no done.json) continues from its last checkpoint.
    path = train_run(dict(job["config"]), out, resume=run_status(out) == "unfinished", progress=False)
    return {"run": str(path)}


def train_config(config: Mapping[str, Any], preset_path: Path, pipeline: str, seed: int, dataset: str,
                 generators: Mapping[str, Any]) -> dict[str, Any]:
    """The resolved trainer config of one run: the preset's ``train`` section via
    ``seal.experiments.training.train.load_train_config`` plus the run's pipeline, seed, dataset and generator (the
    ``generators`` kwargs, fitted model paths filled in, replace the train section's ``pipelines.<pipeline>``)."""
    from seal.experiments.training.train import load_train_config

    gen = generator_of(pipeline)
    overrides = {"pipeline": pipeline, "seed": int(seed), "dataset": dataset}
    if gen:
        overrides[f"pipelines.{pipeline}"] = {"name": gen, "kwargs": dict(generators.get(gen) or {})}
    return load_train_config(preset_path, overrides)


def _failures(kind: str, results: Sequence[JobResult], log: Callable[[str], None]) -> list[str]:
    errors = []
    for r in results:
        if not r.ok:
            errors.append(f"{kind} {r.job.get('name', '?')}: {r.error}")
            log(f"[seal run] FAILED {errors[-1]}")
    return errors


# ---------------------------------------------------------------------------------------------- pipeline
def run_pipeline(
    config_path: str | Path, out: str | Path, backend: Backend | None = None, workers: int | None = None,
    command: CommandRunner = run_seal_command, train_fn: Callable[[Job], Any] = train_job,
    eval_fn: Callable[[Job], Any] | None = None, train_config_fn: Callable[..., dict[str, Any]] = train_config,
    progress: bool = True, log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Run the experiment of ``config_path`` into ``out`` (module docstring). ``command`` runs ``seal``
    subcommands, ``train_fn`` / ``eval_fn`` are the per-job functions and ``train_config_fn`` builds a run's
    trainer config (injectable for tests). Returns a summary; raises after the report if any job failed."""
    from seal.experiments.evaluation.evaluate import evaluate_job, parse_settings, resolve_eval_config

    config_path, out = Path(config_path).resolve(), Path(out).resolve()
    config = load_run_config(config_path)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(config, sort_keys=False).encode())
    steps = Steps(out, log)
    eval_fn = eval_fn or evaluate_job
    if backend is None:
        bcfg = config.get("backend") or {}
        backend = make_backend(bcfg.get("name", "local"), workers if workers is not None else bcfg.get("workers"),
                               address=bcfg.get("address"))
    started = time.perf_counter()

    # 1. data ------------------------------------------------------------------------------------------
    data = config.get("data") or {}
    data_params = {k: data.get(k) for k in ("path", "generate", "score", "split")}  # fits redo when these change
    if data.get("path"):
        dataset = str(Path(data["path"]).expanduser().resolve())
    else:
        dataset = str(out / "data")
        gen_opts = dict(data.get("generate") or {})
        steps.run("data", gen_opts, lambda: command(["data", "generate", "--out", dataset, *cli_options(gen_opts)]))
        score_opts = dict(data.get("score") or {})
        steps.run("score", [gen_opts, score_opts],
                  lambda: command(["data", "score", dataset, *cli_options(score_opts)]))
        split_opts = dict(data.get("split") or {})
        steps.run("split", [gen_opts, split_opts],
                  lambda: command(["data", "split", dataset, *cli_options(split_opts)]))

    # 2. fit the models the generators in use need -------------------------------------------------------
    models: dict[str, str] = {}
    for name in fits_needed(config):
        spec = dict((config.get("fit") or {})[name] or {})
        if spec.get("path"):
            models[name] = str(Path(spec["path"]).expanduser().resolve())
            continue
        (out / "models").mkdir(exist_ok=True)
        models[name] = str(out / "models" / FIT_OUTPUTS.get(name, name))
        options = cli_options(substitute(spec, models))  # e.g. the objective's candidates: "${fit.prior}"
        argv = ["fit", name, dataset, "--out", models[name], *FIT_ARGS.get(name, []), *options]
        steps.run(f"fit-{name}", [data_params, argv], lambda argv=argv: command(argv))
    generators = {name: substitute(dict((config.get("generators") or {}).get(name) or {}), models)
                  for name in generators_in_use(config)}

    # 3. train: pipelines x seeds ----------------------------------------------------------------------
    jobs = []
    runs = {out / "runs" / f"{p}-s{seed}": (p, int(seed)) for p in config["pipelines"] for seed in config["seeds"]}
    for run_dir, (pipeline, seed) in runs.items():
        if (run_dir / "done.json").is_file():
            log(f"[seal run] train {run_dir.name}: done, skipped")
            continue
        cfg = train_config_fn(config, config_path, pipeline, seed, dataset, generators)
        jobs.append({"name": run_dir.name, "config": cfg, "out": str(run_dir)})
    # Trainers may run several env processes each: backend.train_workers caps concurrent local train jobs.
    train_workers = (config.get("backend") or {}).get("train_workers")
    train_backend = make_backend("local", int(train_workers)) if train_workers and backend.name == "local" else backend
    if jobs:
        log(f"[seal run] train: {len(jobs)} job(s) on the {train_backend.name} backend")
    errors = _failures("train", train_backend.map(train_fn, jobs, desc="train"), log)
    trained = [str(d) for d in runs if (d / "done.json").is_file()]  # this preset's runs that finished

    # 4. eval: every trained ego plus the Replay ego, into the store -----------------------------------
    ev = dict(config.get("eval") or {})
    store = str(out / "results.sqlite")
    eval_config = resolve_eval_config(**{k: ev.get(k) for k in ("k", "limit", "seed", "prior", "candidates", "env")})
    eval_config["generators"] = generators
    settings = parse_settings(ev.get("settings") or ["normal", "hard"], dataset)
    egos = trained + (["replay"] if ev.get("replay_ego", True) else [])
    eval_jobs = [
        {"name": Path(e).name, "store": store, "run": e, "settings": [vars(s) for s in settings],
         "config": eval_config, "progress": False}
        for e in egos
    ]
    eval_params = [egos, [vars(s) for s in settings], eval_config]

    def evaluate() -> bool:
        failed = _failures("eval", backend.map(eval_fn, eval_jobs, desc="eval"), log)
        errors.extend(failed)  # reported at the end; the report covers what was evaluated
        return not failed

    steps.run("eval", eval_params, evaluate)

    # 5. report ------------------------------------------------------------------------------------------
    rep = dict(config.get("report") or {})
    report_dir = out / "report"
    if Path(store).is_file():
        from seal.experiments.evaluation.results_store import ResultsStore
        from seal.experiments.report.write import write_report

        with ResultsStore(store) as s:
            n_episodes = s.count()
        if n_episodes:
            steps.run("report", [rep, n_episodes], lambda: write_report(
                store, report_dir, plots=rep.get("plots", True), videos=int(rep.get("videos", 0)),
                video_format=rep.get("video_format", "mp4"), progress=progress,
            ))
    summary = {
        "out": str(out), "dataset": dataset, "models": models, "runs": trained, "store": store,
        "report": str(report_dir / "report.md"), "steps_ran": steps.ran, "steps_skipped": steps.skipped,
        "train_jobs": len(jobs), "seconds": round(time.perf_counter() - started, 1), "errors": errors,
    }
    atomic_write_json(out / "summary.json", summary)
    if errors:
        raise RuntimeError(f"{len(errors)} job(s) failed (see {out / 'summary.json'}):\n" + "\n".join(errors))
    return summary
