"""``seal eval runs`` at scale: egos x scenarios as chunk jobs on a backend (this process, local worker processes,
Ray tasks), the same rows as one process.

The parent plans every ego (`seal.experiments.evaluation.evaluate.plan_ego`: records the ego and the settings,
lists the scenarios still missing), cuts each ego's list into chunks of a few scenarios and maps `evaluate_chunk`
over them. A chunk plays its scenarios exactly as one process would (each scenario's episodes depend only on the
scenario, its index in the split, the ego, the generator and the seed: `seal.experiments.evaluation.protocol`)
and writes one transaction per scenario into the shared results store (SQLite in WAL mode), so an interrupted
evaluation resumes. Small chunks balance the load between workers; the progress bar counts scored episodes.

Each worker process keeps what its chunks share for the session (one token per `evaluate_parallel` call):
`seal.experiments.evaluation.worker_cache`.
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.core.errors import SealError
from seal.core.plugins import load_plugins, plugin_specs
from seal.core.workers import torch_threads
from seal.experiments.backends import Backend, InlineBackend, LocalBackend
from seal.experiments.evaluation.evaluate import (
    EgoSpec,
    Setting,
    WorkItem,
    check_generator_config,
    default_dataset,
    parse_settings,
    plan_ego,
    play_items,
    read_run,
    resolve_eval_config,
    written_key,
)
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.evaluation.worker_cache import use_session

logger = logging.getLogger(__name__)


def evaluate_chunk(job: Mapping[str, Any]) -> dict[str, Any]:
    """One chunk job (keys: ``store``, ``run``, ``algo``, ``settings`` (`Setting` fields), ``config``, ``items``
    (`WorkItem` lists), ``session``, ``plugins`` (the parent's ``--plugin`` modules)): plays the items and writes
    their rows; returns ``{"run", "written", "rows"}``."""
    # One core per worker (the workers are the parallelism); torch is not imported for it: chunks whose egos and
    # generators need no torch never load it (`torch_threads`).
    torch_threads(1)
    load_plugins(job.get("plugins") or [])  # a Ray worker does not inherit this process's SEAL_PLUGINS
    use_session(str(job["session"]))
    ego = read_run(job["run"], job.get("algo"))
    settings = [Setting(**s) for s in job["settings"]]
    items = [(str(d), sp, int(i), list(m)) for d, sp, i, m in job["items"]]
    with ResultsStore(job["store"]) as store:
        written = play_items(store, ego, settings, job["config"], items)
    return {"run": ego.run, "written": written, "rows": sum(written.values())}


def chunk_jobs(
    store_path: str, egos: Sequence[EgoSpec], settings: Sequence[Setting], config: Mapping[str, Any],
    n_workers: int = 1, chunk_size: int | None = None,
) -> list[dict[str, Any]]:
    """Plan every ego (records egos and settings in the store) and cut its missing scenarios into chunk jobs of at
    most ``chunk_size`` scenarios, egos in order; by default about eight chunks per worker for the largest ego
    plan, 1 to 20 scenarios each (small enough to balance the workers, large enough that job overhead stays
    small), and the last ``n_workers`` chunks cut in halves (`_halve_tail`)."""
    session = uuid.uuid4().hex
    split_ids: dict[tuple[str, str | None, int | None], list[str]] = {}  # each split read once for all egos
    with ResultsStore(store_path) as store:
        plans = [(ego, plan_ego(store, ego, settings, config, split_ids)) for ego in egos]
    auto = chunk_size is None
    if chunk_size is None:
        largest = max((len(items) for _, items in plans), default=1)
        chunk_size = max(1, min(20, -(-largest // (8 * max(1, n_workers)))))
    chunks = [(ego, items[start : start + chunk_size]) for ego, items in plans
              for start in range(0, len(items), chunk_size)]
    if auto and n_workers > 1:
        chunks = _halve_tail(chunks, n_workers)
    return [{
        "store": store_path, "run": ego.ego if ego.path else ego.run, "algo": ego.algo,
        "settings": [vars(s) for s in settings], "config": dict(config),
        "items": [list(it) for it in chunk], "session": session, "plugins": plugin_specs(),
    } for ego, chunk in chunks]


def _halve_tail(chunks: list[tuple[EgoSpec, list[WorkItem]]], n_workers: int) -> list[tuple[EgoSpec, list[WorkItem]]]:
    """The last ``n_workers`` chunks (of more than one scenario) each cut in two halves, in order.

    Workers take chunks in order, so the final round decides how long the others wait idle for the last one; half
    as long a final round halves that wait, at the cost of ``n_workers`` more (cheap) jobs."""
    head, tail = chunks[:-n_workers], chunks[-n_workers:]
    out = list(head)
    for ego, items in tail:
        half = (len(items) + 1) // 2
        out.extend([(ego, items[:half]), (ego, items[half:])] if len(items) > 1 else [(ego, items)])
    return out


def evaluate_parallel(
    store_path: str, egos: Sequence[EgoSpec], settings: Sequence[Setting], config: Mapping[str, Any],
    workers: int = 1, backend: Backend | None = None, progress: bool = True, chunk_size: int | None = None,
) -> list[dict[str, Any]]:
    """Evaluate ``egos`` on ``settings`` as chunk jobs on ``backend`` (default: this process for ``workers`` <= 1,
    else a local pool of ``workers`` processes); returns one ``{"run", "written"}`` per ego, in ego order. The
    progress bar counts scored episodes (rows), so its rate is episodes/s."""
    if backend is None:
        backend = InlineBackend() if workers <= 1 else LocalBackend(workers)
    n_workers = int(getattr(backend, "workers", None) or workers or 1)
    jobs = chunk_jobs(str(store_path), egos, settings, config, n_workers, chunk_size)
    sizes = [sum(len(m) for *_, m in job["items"]) for job in jobs]
    results = backend.map(evaluate_chunk, jobs, desc="eval", unit="episode", sizes=sizes, progress=progress)
    failed = [r for r in results if not r.ok]
    if failed:
        # One line for the user (the CLI prints SealError without a traceback): how many jobs failed, for which
        # egos, and the first failure's own message; every failure's traceback tail goes to the log.
        for r in failed:
            logger.error("evaluation job of %s failed: %s", r.job["run"], r.error)
        runs = list(dict.fromkeys(str(r.job["run"]) for r in failed))
        first = str(failed[0].error).splitlines()[0]
        raise SealError(f"{len(failed)} of {len(results)} evaluation jobs failed ({len(runs)} egos: "
                        f"{', '.join(runs[:3])}{', ...' if len(runs) > 3 else ''}); first error: {first}. Rows of "
                        "the jobs that finished are in the store; re-running adds only what is missing")
    out: dict[str, dict[str, int]] = {e.run: {written_key(s, settings): 0 for s in settings} for e in egos}
    for r in results:
        for name, n in r.value["written"].items():
            out[r.value["run"]][name] += n
    return [{"run": e.run, "written": out[e.run]} for e in egos]


def evaluate_runs(
    runs: Sequence[str], settings_spec: str | Sequence[str], store_path: str | Path, dataset: str | Path | None = None,
    config: Mapping[str, Any] | None = None, replay_ego: bool = True, workers: int = 1, progress: bool = True,
    backend: Backend | None = None, chunk_size: int | None = None, algo: str | None = None,
) -> list[dict[str, Any]]:
    """Evaluate every run (plus the Replay ego unless ``replay_ego`` is False) on the settings; returns one
    ``{"run", "written"}`` per ego. Egos x scenarios run as chunk jobs (`evaluate_parallel`): in this process
    (``workers`` <= 1), in ``workers`` local processes, or on a given `seal.experiments.backends` backend (Ray).
    ``algo``: the SB3 algorithm of model files that do not record it."""
    egos = [read_run(r, algo) for r in runs]
    if replay_ego and not any(e.run == "replay" for e in egos):
        egos.append(read_run("replay"))
    if not egos:
        raise ValueError("nothing to evaluate: give run folders (or keep the Replay ego)")
    dataset = dataset or default_dataset(egos)
    settings = parse_settings(settings_spec, dataset)
    config = dict(config) if config is not None else resolve_eval_config(run_configs=[e.config for e in egos])
    for s in settings:
        if s.generator:
            check_generator_config(s.generator, config)
    return evaluate_parallel(str(store_path), egos, settings, config, workers=workers, backend=backend,
                             progress=progress, chunk_size=chunk_size)
