"""``seal run PRESET --out OUT --status``: where a run of a preset stands, read from its folder; writes nothing.

A preset like ``decisive`` runs for many hours and is carried across sessions (`seal.experiments.pipeline.run`
resumes it). Before going on, a user wants to know what is done, what is half done and what is left, without
reading logs: this module reads the same markers the run itself skips on.

* data and fit steps: ``done`` (their marker under OUT/steps holds the parameters the preset gives now; with the
  seconds the step took), ``stale`` (a marker of other parameters: the step runs again), ``started`` (no marker
  but its output is there: running now, or stopped part way) or ``pending``;
* training: per planned run folder ``done`` (``done.json``, with its wall time), ``in progress`` (the step of its
  newest checkpoint, out of its ``total_timesteps``) or ``not started``; the finished runs' mean wall time per
  ego algorithm, and the time the runs left would take at that mean, ``backend.train_workers`` runs at a time on
  the local backend (one otherwise);
* evaluation: the rows in OUT/results.sqlite against the rows a complete evaluation of every planned ego and the
  Replay ego writes (`seal.experiments.evaluation.store_progress.expected_rows`; known once the data exist);
* report: whether its marker is there.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from seal.core.dataset import MANIFEST
from seal.core.paths import rebase
from seal.experiments.pipeline.drift import describe_drift, fit_drift
from seal.experiments.pipeline.location import recorded_roots, relocated
from seal.experiments.pipeline.references import eval_egos, eval_settings, fits_needed, heldout_pools, planned_runs
from seal.experiments.pipeline.reuse import describe
from seal.experiments.pipeline.run import load_run_config
from seal.experiments.pipeline.steps import StepJob, Steps, data_steps, fit_steps, heldout_steps
from seal.experiments.training.state import CHECKPOINTS, CONFIG, DONE, LATEST, read_done


def run_status(config_path: str | Path, out: str | Path, sets: Sequence[str] = ()) -> dict[str, Any]:
    """The state of every step of the preset ``config_path`` in the run folder ``out`` (module docstring)."""
    config = load_run_config(config_path, sets)
    out = Path(out).expanduser().resolve()
    previous = recorded_roots(out) if out.is_dir() else []
    moved_from = [] if not previous or relocated(out) else previous  # not yet pointed here by `seal run`
    markers = Steps(out, previous)
    dataset, data_params, data = data_steps(config, out)
    _, fits = fit_steps(config, out, dataset, data_params)
    runs = _training(out, config)
    return {
        "preset": config["preset"], "out": str(out), "exists": out.is_dir(), "moved_from": moved_from,
        "reuse": describe(config, fits_needed(config)) if config.get("reuse") else None,
        "steps": [_step(markers, step) for step in [*data, *heldout_steps(config, out), *fits]],
        "training": runs,
        "evaluation": _evaluation(out, config, dataset, runs["runs"], moved_from),
        "report": "done" if markers.marker("report") is not None else "pending",
    }


def _step(markers: Steps, step: StepJob) -> dict[str, Any]:
    marker = markers.marker(step.name)
    if marker is None:
        # what the step writes is there without its marker: it is running, or was stopped (it resumes or redoes)
        output = step.job.get("out") or (step.job["dataset"] if step.job.get("task") == "generate" else None)
        started = output is not None and Path(output).exists()
        return {"name": step.name, "state": "started" if started else "pending"}
    if not markers.matches(marker, step.params):
        return {"name": step.name, "state": "stale", "seconds": marker.get("seconds")}
    return {"name": step.name, "state": "done", "seconds": marker.get("seconds"), "drift": fit_drift(step)}


def _training(out: Path, config: Mapping[str, Any]) -> dict[str, Any]:
    """Per planned run folder its state and steps; the finished runs' mean wall time per algorithm."""
    default_algo = (config.get("train") or {}).get("algo", "td3")
    runs: list[dict[str, Any]] = []
    for name, (_, _, algo) in planned_runs(config).items():
        folder = out / "runs" / name
        row: dict[str, Any] = {"name": name, "algo": algo or default_algo, "total": _total_steps(folder, config, algo)}
        if (folder / DONE).is_file():
            done = read_done(folder)
            row.update(state="done", steps=done.get("steps"), wall_s=done.get("wall_s"))
        elif (folder / CHECKPOINTS / LATEST).is_file():
            latest = json.loads((folder / CHECKPOINTS / LATEST).read_text())
            row.update(state="in progress", steps=int(latest.get("step", 0)))
        else:
            row.update(state="not started", steps=0)
        runs.append(row)
    mean_s: dict[str, float] = {}
    for algo in dict.fromkeys(r["algo"] for r in runs):
        walls = [r["wall_s"] for r in runs if r["algo"] == algo and r["state"] == "done" and r.get("wall_s")]
        if walls:
            mean_s[algo] = sum(walls) / len(walls)
    left_s = 0.0
    for r in runs:
        if r["state"] != "done" and r["algo"] in mean_s:
            left_s += mean_s[r["algo"]] * (1.0 - (r["steps"] or 0) / max(int(r["total"] or 1), 1))
    concurrent = _concurrent_runs(config)
    return {"runs": runs, "done": sum(r["state"] == "done" for r in runs), "planned": len(runs),
            "mean_run_s": {k: round(v, 1) for k, v in mean_s.items()}, "concurrent_runs": concurrent,
            "left_s_estimate": round(left_s / concurrent, 1) if mean_s else None}


def _concurrent_runs(config: Mapping[str, Any]) -> int:
    """Training runs `seal run` plays side by side: ``backend.train_workers`` on the local backend, else one (a
    Ray cluster's concurrency is not known from the preset)."""
    backend = config.get("backend") or {}
    if backend.get("name", "local") != "local" or not backend.get("train_workers"):
        return 1
    return max(int(backend["train_workers"]), 1)


def _total_steps(folder: Path, config: Mapping[str, Any], algo: str | None) -> int | None:
    """A run's ``total_timesteps``: as its own config.yaml records it, else as the preset gives it."""
    if (folder / CONFIG).is_file():
        recorded = yaml.safe_load((folder / CONFIG).read_text()) or {}
        if recorded.get("total_timesteps"):
            return int(recorded["total_timesteps"])
    per_algo = ((config.get("algo_train") or {}).get(algo) or {}) if algo else {}
    total = per_algo.get("total_timesteps", (config.get("train") or {}).get("total_timesteps"))
    return None if total is None else int(total)


def _evaluation(out: Path, config: Mapping[str, Any], dataset: str, runs: Sequence[Mapping[str, Any]],
                moved_from: Sequence[str] = ()) -> dict[str, Any]:
    """Rows in the results store, and the rows a complete evaluation of the planned egos writes (None before the
    data exist); an ego's rows stored under an earlier path of the folder (``moved_from``) count as its own, as
    they will once `seal run` relocates them."""
    from seal.experiments.evaluation.results_store import ResultsStore
    from seal.experiments.evaluation.store_progress import expected_rows

    ev = config.get("eval") or {}
    egos = eval_egos(config, [str(out / "runs" / r["name"]) for r in runs])
    store = out / "results.sqlite"
    stored = 0
    complete_egos = None
    expected = None
    if all(Path(pool, MANIFEST).is_file() for pool in [dataset, *heldout_pools(config, out)]):
        settings = eval_settings(config, dataset, out)
        names = [s.name for s in settings]
        expected = expected_rows(egos, settings, ev.get("limit"))
        per_ego = expected // max(len(egos), 1)
        if store.is_file():
            with ResultsStore(store) as s:
                counts = [s.count(run=[e, *(rebase(e, str(out), old) for old in moved_from)], setting=names)
                          for e in egos]
            stored, complete_egos = sum(counts), sum(c >= per_ego for c in counts)
    elif store.is_file():
        with ResultsStore(store) as s:
            stored = s.count()
    return {"rows": stored, "expected_rows": expected, "egos": len(egos), "complete_egos": complete_egos}


def format_status(status: Mapping[str, Any]) -> str:
    """The status as a few lines of text."""
    lines = [f"seal run status: {status['preset']} in {status['out']}" + ("" if status["exists"] else
                                                                          " (no such folder yet)")]
    if status.get("reuse"):
        lines.append(f"  {status['reuse']}")
    if status.get("moved_from"):
        lines.append(f"  run from {', '.join(status['moved_from'])} before: `seal run` points its store and run "
                     "configs here first; what was done there counts as done")
    w = max([18, *(len(step["name"]) for step in status["steps"])])  # held-out pool steps have long names
    for step in status["steps"]:
        took = f" ({step['seconds'] / 60:.1f} min)" if step.get("seconds") is not None else ""
        lines.append(f"  {step['name']:<{w}} {step['state']}{took}")
        if step.get("drift"):
            lines.append(f"  {'':<{w}}   fitted with settings the code now resolves otherwise (kept; refit with a "
                         f"fresh folder or a --set of the fit): {describe_drift(step['drift'])}")
    tr = status["training"]
    states = [r["state"] for r in tr["runs"]]
    lines.append(f"  {'training':<{w}} {tr['done']} of {tr['planned']} runs done, {states.count('in progress')} in "
                 f"progress, {states.count('not started')} not started")
    for r in tr["runs"]:
        if r["state"] == "in progress":
            total = "?" if r["total"] is None else f"{r['total']:,}"
            lines.append(f"  {'':<{w}}   {r['name']}: {r['steps']:,} of {total} steps")
    if tr["mean_run_s"]:
        means = ", ".join(f"{algo} {s / 60:.1f} min" for algo, s in tr["mean_run_s"].items())
        left = tr["left_s_estimate"]
        at_a_time = "one at a time" if tr["concurrent_runs"] == 1 else f"{tr['concurrent_runs']} at a time"
        lines.append(f"  {'':<{w}}   finished runs take {means} on average; the runs left ~{left / 3600:.1f} h at "
                     f"that pace ({at_a_time}; algorithms without a finished run not counted)")
    ev = status["evaluation"]
    expected = "?" if ev["expected_rows"] is None else f"{ev['expected_rows']:,}"
    egos = "" if ev["complete_egos"] is None else f" ({ev['complete_egos']} of {ev['egos']} egos complete)"
    lines.append(f"  {'evaluation':<{w}} {ev['rows']:,} of {expected} rows{egos}")
    lines.append(f"  {'report':<{w}} {status['report']}")
    return "\n".join(lines)
