"""Where independent jobs (one training run per pipeline x seed, one ego evaluation) execute.

A backend maps a picklable top-level function over a list of job dicts and returns one `JobResult` per job, in
job order; a failing job is reported in its result (with the error text) instead of stopping the others.

* `InlineBackend`: in this process, one after another (debugging, tests, ``--workers 0``).
* `LocalBackend`: a process pool on this machine (``spawn`` start method, so workers start clean of this
  process's threads and torch state).
* `RayBackend`: Ray tasks on a running cluster: ``ray start --head`` on the head node, then the address from
  the config, ``RAY_ADDRESS`` or ``"auto"``; or a private local instance with ``local_cpus``. Workers must see
  the same files as the driver (run folders, datasets, the results store), e.g. a shared filesystem.
"""

from __future__ import annotations

import logging
import os
import sys
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

Job = Mapping[str, Any]
JobFn = Callable[[Job], Any]
BACKENDS = ("local", "ray", "inline")


@dataclass
class JobResult:
    """What one job returned (``value``) or why it failed (``error``, the traceback's last lines)."""

    job: Job
    value: Any = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None


class Backend(Protocol):
    name: str

    def map(
        self, fn: JobFn, jobs: Sequence[Job], desc: str = "jobs", unit: str = "job",
        sizes: Sequence[int] | None = None, progress: bool = True,
    ) -> list[JobResult]:
        """Run ``fn(job)`` for every job; results in job order. The progress bar (``progress``) advances by
        ``sizes[i]`` when job ``i`` finishes (default 1 each), so its rate reads in ``unit`` per second."""
        ...


def _bar(jobs: Sequence[Job], desc: str, unit: str, sizes: Sequence[int] | None, progress: bool) -> Any:
    """The tqdm bar of a `Backend.map` (on stderr; ``disable`` when not ``progress``)."""
    from tqdm import tqdm

    total = len(jobs) if sizes is None else int(sum(sizes))
    return tqdm(total=total, desc=desc, unit=unit, disable=not progress, smoothing=0.1)


def _step(sizes: Sequence[int] | None, i: int) -> int:
    return 1 if sizes is None else int(sizes[i])


def _call(fn: JobFn, job: Job) -> JobResult:
    """``fn(job)`` as a `JobResult` (a failure too)."""
    try:
        return JobResult(job, fn(job))
    except Exception as exc:  # a job's failure is its result; the other jobs go on
        tail = "".join(traceback.format_exception(exc)[-3:]).strip()
        return JobResult(job, error=f"{type(exc).__name__}: {exc}\n{tail}")


def _worker_call(fn: JobFn, job: Job) -> JobResult:
    """A worker process's entry: the ``seal.*`` loggers get the CLI's stderr handler (INFO, plain message) when
    they have none, so the job's log lines show as in the driver; then `_call`."""
    root = logging.getLogger("seal")
    if not root.handlers:  # a fresh worker (a reused one is set up already)
        handler = logging.StreamHandler(sys.stderr)
        handler.setFormatter(logging.Formatter("%(message)s"))
        root.addHandler(handler)
        root.setLevel(logging.INFO)
        root.propagate = False
    return _call(fn, job)


class InlineBackend:
    """Jobs in this process, in order."""

    name = "inline"

    def map(
        self, fn: JobFn, jobs: Sequence[Job], desc: str = "jobs", unit: str = "job",
        sizes: Sequence[int] | None = None, progress: bool = False,
    ) -> list[JobResult]:
        results = []
        with _bar(jobs, desc, unit, sizes, progress) as bar:
            for i, job in enumerate(jobs):
                results.append(_call(fn, job))
                bar.update(_step(sizes, i))
        return results


class LocalBackend:
    """A pool of ``workers`` spawned processes (default: the CPU count).

    By default each `map` spawns its pool and closes it at the end. `start` spawns the workers at once instead
    (each importing the ``warm`` modules as it starts) and keeps them for every later `map` until `shutdown` (as
    `RayBackend`): their start-up (a fresh interpreter, seal's imports and compiled kernels, about a second of CPU
    each) then overlaps what this process does before its first `map` (its own imports, planning the jobs) instead
    of following it.
    """

    name = "local"

    def __init__(self, workers: int | None = None, warm: Sequence[str] = ()) -> None:
        self.workers = max(1, int(workers or os.cpu_count() or 1))
        self.warm = tuple(warm)
        self._pool: Any = None

    def _new_pool(self, n_workers: int) -> Any:
        import multiprocessing as mp
        from concurrent.futures import ProcessPoolExecutor

        from seal.core.workers import initializer

        # Job workers die with this process (no orphans after a kill); then they import the warm modules.
        init, init_args = initializer(_import_modules, self.warm)
        return ProcessPoolExecutor(n_workers, mp_context=mp.get_context("spawn"), initializer=init,
                                   initargs=init_args)

    def start(self) -> LocalBackend:
        """Spawn all ``workers`` now (without waiting for them) and keep the pool for later `map` calls; returns
        self. Idempotent."""
        if self._pool is None:
            self._pool = self._new_pool(self.workers)
            # The executor spawns a worker per submitted job while none is idle: one no-op job per worker starts
            # them all now rather than at the first `map`.
            for _ in range(self.workers):
                self._pool.submit(_noop)
        return self

    def shutdown(self) -> None:
        """Shut a `start`-ed pool down (waits for its workers to exit); a no-op otherwise."""
        if self._pool is not None:
            pool, self._pool = self._pool, None
            pool.shutdown(wait=True)

    def map(
        self, fn: JobFn, jobs: Sequence[Job], desc: str = "jobs", unit: str = "job",
        sizes: Sequence[int] | None = None, progress: bool = True,
    ) -> list[JobResult]:
        if not jobs:
            return []
        if self._pool is not None:
            return self._map(self._pool, fn, jobs, desc, unit, sizes, progress)
        with self._new_pool(min(self.workers, len(jobs))) as pool:
            return self._map(pool, fn, jobs, desc, unit, sizes, progress)

    @staticmethod
    def _map(
        pool: Any, fn: JobFn, jobs: Sequence[Job], desc: str, unit: str, sizes: Sequence[int] | None,
        progress: bool,
    ) -> list[JobResult]:
        from concurrent.futures import as_completed

        results: list[JobResult | None] = [None] * len(jobs)
        futures = {pool.submit(_worker_call, fn, job): i for i, job in enumerate(jobs)}
        with _bar(jobs, desc, unit, sizes, progress) as bar:
            for fut in as_completed(futures):
                i = futures[fut]
                try:
                    results[i] = fut.result()
                except Exception as exc:  # the worker process died (e.g. out of memory)
                    results[i] = JobResult(jobs[i], error=f"worker process failed: {type(exc).__name__}: {exc}")
                bar.update(_step(sizes, i))
        return [r for r in results if r is not None]


def _noop() -> None:
    """The job that makes `LocalBackend.start` spawn a worker."""


def _import_modules(modules: Sequence[str]) -> None:
    """A worker's warm-up (`LocalBackend` ``warm``): import ``modules``."""
    import importlib

    for name in modules:
        importlib.import_module(name)


class RayBackend:
    """Ray tasks: ``ray.init(address=...)`` with ``address`` (config) or ``RAY_ADDRESS`` or ``"auto"`` (a running
    cluster), or, with ``local_cpus``, a private local instance of that many CPUs. ``cpus_per_job`` CPUs are
    reserved per task."""

    name = "ray"

    def __init__(
        self, address: str | None = None, local_cpus: int | None = None, cpus_per_job: float = 1.0,
        runtime_env: Mapping[str, Any] | None = None,
    ) -> None:
        try:
            import ray
        except ImportError:
            raise RuntimeError(
                "--backend ray needs Ray: pip install -e '.[ray]' (or use --backend local)"
            ) from None
        self._ray = ray
        self.cpus_per_job = float(cpus_per_job)
        if not ray.is_initialized():
            # The driver's sys.path (the repository) must reach the workers: ship it as PYTHONPATH.
            env = {"env_vars": {"PYTHONPATH": os.pathsep.join(p for p in _import_roots() if p)}}
            env.update(runtime_env or {})
            if local_cpus is not None:
                ray.init(num_cpus=int(local_cpus), include_dashboard=False, runtime_env=env, log_to_driver=False)
            else:
                target = address or os.environ.get("RAY_ADDRESS") or "auto"
                try:
                    ray.init(address=target, runtime_env=env)
                except (ConnectionError, RuntimeError) as exc:
                    raise RuntimeError(
                        f"--backend ray: no Ray cluster at {target!r} ({exc}); start one with `ray start --head` "
                        "(or set RAY_ADDRESS / the preset's backend.address), or use --backend local"
                    ) from None

    def map(
        self, fn: JobFn, jobs: Sequence[Job], desc: str = "jobs", unit: str = "job",
        sizes: Sequence[int] | None = None, progress: bool = True,
    ) -> list[JobResult]:
        if not jobs:
            return []
        task = self._ray.remote(num_cpus=self.cpus_per_job)(_worker_call)
        refs = [task.remote(fn, dict(job)) for job in jobs]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[JobResult | None] = [None] * len(jobs)
        pending = list(refs)
        with _bar(jobs, desc, unit, sizes, progress) as bar:
            while pending:
                ready, pending = self._ray.wait(pending, num_returns=1)
                i = index[ready[0]]
                try:
                    results[i] = self._ray.get(ready[0])
                except Exception as exc:  # the task or its worker died
                    results[i] = JobResult(jobs[i], error=f"ray task failed: {type(exc).__name__}: {exc}")
                bar.update(_step(sizes, i))
        return [r for r in results if r is not None]

    def shutdown(self) -> None:
        self._ray.shutdown()


def _import_roots() -> list[str]:
    """The directory this package is imported from (the repository or site-packages)."""
    import seal

    return [os.path.dirname(os.path.dirname(os.path.abspath(seal.__file__)))]


def make_backend(
    name: str, workers: int | None = None, address: str | None = None, ray_local_cpus: int | None = None
) -> Backend:
    """``local`` (``workers`` processes), ``ray`` (cluster at ``address`` / ``RAY_ADDRESS`` / auto, or a local
    instance of ``ray_local_cpus``) or ``inline``."""
    if name == "local":
        return InlineBackend() if workers == 0 else LocalBackend(workers)
    if name == "ray":
        return RayBackend(address=address, local_cpus=ray_local_cpus)
    if name == "inline":
        return InlineBackend()
    raise ValueError(f"--backend must be one of {BACKENDS}, got {name!r}")
