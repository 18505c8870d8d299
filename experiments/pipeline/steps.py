"""The data and fit steps of ``seal run`` as (name, parameters, job) triples, and their done-markers.

`seal.experiments.pipeline.run` runs these steps; `seal.experiments.pipeline.status` reads which of them are done.
Both plan them here, so a step's parameter hash is computed once, the same way for running and for reporting.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_json
from seal.core.paths import portable_json, swap_folder
from seal.experiments.pipeline.references import (
    HELDOUT_DIR,
    fit_dependencies,
    fit_kind,
    fits_needed,
    planned_runs,
    substitute,
)

logger = logging.getLogger(__name__)

FIT_OUTPUTS = {"prior": "prior.pt", "goose": "goose.zip", "skills": "skills", "objective": "objective",
               "behavior": "behavior", "probes": "probes"}
"""Model name -> file or folder written under OUT/models by the fit of that model."""


@dataclass(frozen=True)
class StepJob:
    """One data or fit step: its marker name, the parameters its marker hashes, and the job that runs it."""

    name: str
    params: Any
    job: dict[str, Any]
    after: tuple[str, ...] = ()
    """Steps that must finish first (a fit that uses another fit's model)."""


class Steps:
    """Done-markers under OUT/steps: a step is done when its marker holds the same parameter hash.

    The hash does not depend on where OUT is (`seal.core.paths.portable_json`: paths inside OUT hash as
    ``${OUT}/...``), so a moved or copied run folder keeps its steps done. Markers written before that hashed the
    absolute paths: they count as done here when they match with OUT's path or with one of ``previous`` (the paths
    the folder was run from before, `seal.experiments.pipeline.location.recorded_roots`), and `run` rewrites them
    in the portable form."""

    def __init__(self, out: Path, previous: Sequence[str] = ()) -> None:
        self.out = Path(out)
        self.dir = self.out / "steps"
        self.previous = tuple(previous)
        self.ran: list[str] = []
        self.skipped: list[str] = []

    def digest(self, params: Any) -> str:
        """The marker hash of ``params`` (portable: the same wherever OUT is)."""
        return _sha(portable_json(params, str(self.out)))

    def matches(self, marker: Mapping[str, Any], params: Any) -> bool:
        """Whether ``marker`` was written for ``params``: the portable hash, or the absolute-path hash of a marker
        written before it, with OUT here or at one of the previous paths."""
        found = marker.get("params")
        text = json.dumps(params, sort_keys=True, default=str)
        here = str(self.out)
        return found in (_sha(swap_folder(text, here)), _sha(text)) or any(
            found == _sha(swap_folder(text, here, root)) for root in self.previous)

    def marker(self, name: str) -> dict[str, Any] | None:
        """The marker of step ``name`` (``params`` hash, ``seconds``, ``finished``), None without one."""
        path = self.dir / f"{name}.json"
        return json.loads(path.read_text()) if path.is_file() else None

    def done(self, name: str, params: Any) -> bool:
        marker = self.marker(name)
        return marker is not None and self.matches(marker, params)

    def run(self, name: str, params: Any, action: Callable[[], Any]) -> bool:
        """Run ``action`` unless ``name`` is done with these ``params``; returns True if it ran. The marker is
        written when ``action`` returns anything but False (False: partly failed, run it again next time)."""
        marker = self.marker(name)
        if marker is not None and self.matches(marker, params):
            if marker.get("params") != self.digest(params):  # an absolute-path marker: now in the portable form
                atomic_write_json(self.dir / f"{name}.json", {**marker, "params": self.digest(params)})
            logger.info(f"[seal run] {name}: done, skipped")
            self.skipped.append(name)
            return False
        logger.info(f"[seal run] {name}: running")
        start = time.perf_counter()
        if action() is False:
            return True
        atomic_write_json(self.dir / f"{name}.json", {
            "params": self.digest(params), "seconds": round(time.perf_counter() - start, 2), "finished": time.time(),
        })
        self.ran.append(name)
        return True


def _sha(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def data_steps(config: Mapping[str, Any], out: Path) -> tuple[str, dict[str, Any], list[StepJob]]:
    """The dataset folder, the data parameters (the fits run again when they change) and the generate / score /
    split steps into OUT/data (none with ``data.path``: that dataset is used as it is)."""
    data = config.get("data") or {}
    data_params = {k: data.get(k) for k in ("path", "generate", "score", "split")}
    if data.get("path"):
        return str(Path(data["path"]).expanduser().resolve()), data_params, []
    dataset = str(out / "data")
    return dataset, data_params, _pool_steps("", dataset, data)


def heldout_pool_steps(config: Mapping[str, Any], out: Path) -> dict[str, list[StepJob]]:
    """Pool name -> the generate / score / split steps (``heldout-<name>-data`` ...) of each held-out pool the run
    builds itself: the ``eval.heldout`` entries ``{name, generate, score, split}``, into OUT/heldout/<name>."""
    return {str(e["name"]): _pool_steps(f"heldout-{e['name']}-", str(out / HELDOUT_DIR / str(e["name"])), e)
            for e in (config.get("eval") or {}).get("heldout") or [] if isinstance(e, Mapping)}


def heldout_steps(config: Mapping[str, Any], out: Path) -> list[StepJob]:
    """The steps of `heldout_pool_steps`, pool after pool."""
    return [step for steps in heldout_pool_steps(config, out).values() for step in steps]


def _pool_steps(prefix: str, dataset: str, data: Mapping[str, Any]) -> list[StepJob]:
    """Generate, score and split ``dataset`` with the options of ``data`` (steps ``<prefix>data``, ``score``,
    ``split``; a changed generate option makes the score and split run again)."""
    gen_opts = dict(data.get("generate") or {})
    score_opts = dict(data.get("score") or {})
    split_opts = dict(data.get("split") or {})
    names = [f"{prefix}{step}" for step in ("data", "score", "split")]
    return [
        StepJob(names[0], gen_opts, {"name": names[0], "task": "generate", "dataset": dataset, "options": gen_opts}),
        StepJob(names[1], [gen_opts, score_opts],
                {"name": names[1], "task": "score", "dataset": dataset, "options": score_opts}),
        StepJob(names[2], [gen_opts, split_opts],
                {"name": names[2], "task": "split", "dataset": dataset, "options": split_opts}),
    ]


def fit_steps(config: Mapping[str, Any], out: Path, dataset: str, data_params: Mapping[str, Any]
              ) -> tuple[dict[str, str], list[StepJob]]:
    """Model name -> path of every model the generators in use need (dependencies first), and the fit steps of
    those not given as ``fit.NAME.path``."""
    models: dict[str, str] = {}
    steps: list[StepJob] = []
    runs = {name: str(out / "runs" / name) for name in planned_runs(config)}  # a late fit's "${runs.NAME}"
    for name in fits_needed(config):
        spec = dict((config.get("fit") or {})[name] or {})
        if spec.get("path"):
            models[name] = str(Path(spec["path"]).expanduser().resolve())
            continue
        kind, spec = fit_kind(name, spec)
        models[name] = str(out / "models" / FIT_OUTPUTS.get(name, name))
        job = {"name": f"fit-{name}", "task": "fit", "model": kind, "dataset": dataset, "out": models[name],
               "options": substitute(spec, models, runs)}  # e.g. the objective's candidates: "${fit.prior}"
        after = tuple(f"fit-{dep}" for dep in fit_dependencies(spec))
        steps.append(StepJob(f"fit-{name}", [data_params, job], job, after))
    return models, steps


def run_steps(steps: Sequence[StepJob], run_one: Callable[[StepJob], Any], workers: int = 1) -> None:
    """Run ``steps`` (in a dependency order), at most ``workers`` at a time in threads, each once the steps it comes
    ``after`` have finished; with one worker, one after the other in the given order. A step that fails stops new
    starts; its error is raised once the steps already running have ended (their markers are kept)."""
    from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait

    workers = max(1, int(workers))
    names = {s.name for s in steps}
    pending, finished = list(steps), set()
    running: dict[Future[Any], StepJob] = {}
    error: BaseException | None = None
    with ThreadPoolExecutor(workers) as pool:
        while pending or running:
            for step in list(pending):
                if error is not None or len(running) >= workers:
                    break
                if all(dep in finished or dep not in names for dep in step.after):
                    pending.remove(step)
                    running[pool.submit(run_one, step)] = step
            if not running:
                break  # a failure left the rest unstartable
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                step = running.pop(future)
                if future.exception() is None:
                    finished.add(step.name)
                elif error is None:
                    error = future.exception()
    if error is not None:
        raise error
