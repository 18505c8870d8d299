"""Build a base-scenario dataset from highway-env traffic (``seal data generate``).

Runs are numbered 0, 1, 2, ...; run ``r`` draws everything (layout parameters, traffic, drivers, windows,
ego/adversary roles) from its own generator seeded with ``SeedSequence(seed, spawn_key=(r,))``. Runs are
processed in chunks of `runs_per_chunk` runs; one chunk is one shard of the dataset, written atomically by
`seal.core.dataset.DatasetBuilder`, so an interrupted build resumes at the first missing chunk. The layout of each
run of a chunk is chosen before the chunk starts, from the scenario counts of the chunks before it: each run
goes to the layout with the fewest (projected) scenarios, so layouts stay balanced even when one yields fewer
scenarios per run. Chunks are built until at least ``n`` scenarios exist, then the dataset is trimmed to
exactly ``n``. The result depends on the content arguments only, never on ``workers``.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import os
import platform
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import highway_env
import numpy as np
from tqdm import tqdm

import seal
from seal.core.dataset import Dataset, DatasetBuilder
from seal.core.scenario import Scenario
from seal.core.workers import initializer
from seal.envs.layouts import LAYOUTS, sample_params
from seal.envs.network_topology import describe_network
from seal.envs.traffic_run import Simulation
from seal.envs.windows import find_windows, window_tracks

GENERATOR_VERSION = 2
"""Bump when the generated content changes for the same arguments (it is part of the build parameters)."""
RUNS_PER_CHUNK = 16
"""Runs per chunk (= shard) for large builds; small builds use smaller chunks (`runs_per_chunk`)."""
RUN_STEPS = 300
"""Steps of 0.1 s simulated per run (30 s)."""
WARMUP_STEPS = 20
"""Windows start after the first 2 s, once the initial placement has settled."""
SCENARIOS_PER_RUN = 5
"""At most this many scenarios per run, so the pool spreads over many roads and traffic situations."""
SOURCE = "highway-env"


class GenerationInterrupted(RuntimeError):
    """Raised by the test hook ``_stop_after_chunks`` to simulate an interrupted build."""


@dataclass(frozen=True)
class RunTask:
    run: int
    layout: str
    seed: int
    kind_shares: tuple[float, float, float]


def runs_per_chunk(n: int) -> int:
    """Chunk size for a build of ``n`` scenarios: about a quarter of the expected runs, 2 to `RUNS_PER_CHUNK`.

    Small builds do not simulate a whole large chunk; it depends on ``n`` only, so builds stay reproducible.
    """
    return int(min(RUNS_PER_CHUNK, max(2, math.ceil(n / (4 * SCENARIOS_PER_RUN)))))


def run_rng(seed: int, run: int) -> np.random.Generator:
    """The generator of run ``run`` of a build with ``seed``."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(run,)))


def simulate_run(task: RunTask) -> list[Scenario]:
    """Simulate one run and cut its scenarios (ids ``{layout}-{run:05d}-{k:02d}``)."""
    rng = run_rng(task.seed, task.run)
    params = sample_params(task.layout, rng)
    sim = Simulation(task.layout, params, rng, task.kind_shares)
    log = sim.run(RUN_STEPS)
    windows = find_windows(log, rng, SCENARIOS_PER_RUN, min_t0=WARMUP_STEPS)
    if not windows:
        return []
    road = describe_network(sim.network, task.layout, params)
    out = []
    for k, w in enumerate(windows):
        tracks, ids = window_tracks(log, w)
        out.append(
            Scenario(
                scenario_id=f"{task.layout}-{task.run:05d}-{k:02d}",
                tracks=tracks,
                agent_ids=ids,
                agent_types=("vehicle",) * len(ids),
                ego_id=int(ids[0]),
                adv_id=int(ids[1]),
                road=road,
                source=SOURCE,
                metadata={
                    "layout": task.layout,
                    "run": task.run,
                    "group": f"{SOURCE}:seed{task.seed}:run{task.run:05d}",
                    "t0_step": w.t0,
                    "pair_min_gap_m": round(w.min_gap_m, 3),
                    "pair_collision": w.pair_collision,
                    "any_collision": w.any_collision,
                    "ego_driver": log.kinds[w.ego],
                    "adv_driver": log.kinds[w.adv],
                    "seed": task.seed,
                },
            )
        )
    return out


# ------------------------------------------------------------------------------------------ arguments
def _check_args(
    n: Any, seed: Any, layouts: Any, workers: Any, inattentive_share: Any, aggressive_share: Any
) -> tuple[str, ...]:
    """Validate the arguments; errors name the CLI option. Returns the layouts in canonical order."""
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"--n: must be a positive integer, got {n!r}")
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ValueError(f"--seed: must be a non-negative integer, got {seed!r}")
    if isinstance(layouts, str):
        layouts = [x for x in layouts.replace(",", " ").split() if x]
    layouts = list(layouts)
    if not layouts:
        raise ValueError(f"--layouts: give at least one layout; choose from {', '.join(LAYOUTS)}")
    for layout in layouts:
        if layout not in LAYOUTS:
            raise ValueError(f"--layouts: unknown layout {layout!r}; choose from {', '.join(LAYOUTS)}")
    if len(set(layouts)) != len(layouts):
        raise ValueError(f"--layouts: duplicate layouts in {layouts}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"--workers: must be a positive integer, got {workers!r}")
    for name, share in (("--inattentive-share", inattentive_share), ("--aggressive-share", aggressive_share)):
        if isinstance(share, bool) or not isinstance(share, int | float) or not 0.0 <= share <= 1.0:
            raise ValueError(f"{name}: must be a number in [0, 1], got {share!r}")
    if inattentive_share + aggressive_share > 1.0:
        total = inattentive_share + aggressive_share
        raise ValueError(f"--inattentive-share + --aggressive-share must be at most 1, got {total}")
    return tuple(x for x in LAYOUTS if x in layouts)


# ------------------------------------------------------------------------------------------ balancing
def assign_layouts(
    layouts: Sequence[str], counts: dict[str, int], runs: dict[str, int], n_runs: int
) -> list[str]:
    """Layouts for the ``n_runs`` runs of the next chunk: each goes to the layout with the fewest projected
    scenarios (``counts`` so far plus the runs already assigned times the layout's mean yield)."""
    total_s, total_r = sum(counts.values()), sum(runs.values())
    default = total_s / total_r if total_r else float(SCENARIOS_PER_RUN)
    mean = {x: counts[x] / runs[x] if runs[x] else default for x in layouts}
    projected = {x: float(counts[x]) for x in layouts}
    out = []
    for _ in range(n_runs):
        layout = min(layouts, key=lambda x: (projected[x], layouts.index(x)))
        out.append(layout)
        projected[layout] += max(mean[layout], 0.5)  # a layout that yields nothing still takes turns
    return out


def _map_runs(tasks: list[RunTask], pool: Any) -> Iterator[list[Scenario]]:
    """Results in task order; the pool gets the slow layouts first so both cores stay busy to the end.

    With a pool the runs are handed to the workers at once (not when the results are first asked for), so a
    chunk can be started before the parent writes the previous shard (`_build_chunks`).
    """
    if pool is None:
        return map(simulate_run, tasks)
    cost = {"merge": 0, "highway": 1, "roundabout": 2, "intersection": 3}
    order = sorted(range(len(tasks)), key=lambda k: (cost.get(tasks[k].layout, 9), k))
    running = pool.imap(simulate_run, [tasks[k] for k in order])
    return _in_task_order(order, running)


def _in_task_order(order: list[int], results: Iterator[list[Scenario]]) -> Iterator[list[Scenario]]:
    """``results`` (of the tasks in ``order``) in task order."""
    out: dict[int, list[Scenario]] = {}
    for k, res in zip(order, results, strict=True):
        out[k] = res
    for k in range(len(order)):
        yield out[k]


def _make_pool(workers: int) -> Any:
    """A process pool. Fork where available: workers start at once with everything imported, and scripts
    calling `generate_dataset` without a ``__main__`` guard still work (workers use numpy/highway-env).
    """
    methods = mp.get_all_start_methods()
    init, init_args = initializer()  # workers die with this process (no orphans after a kill)
    return mp.get_context("fork" if "fork" in methods else None).Pool(workers, init, init_args)


def _versions() -> dict[str, str]:
    return {
        "seal": seal.__version__,
        "highway_env": getattr(highway_env, "__version__", "unknown"),
        "numpy": np.__version__,
        "python": platform.python_version(),
        "generator": str(GENERATOR_VERSION),
    }


# ------------------------------------------------------------------------------------------ entry point
def generate_dataset(
    out: str | Path,
    n: int,
    seed: int,
    layouts: Sequence[str] = LAYOUTS,
    workers: int | None = None,
    inattentive_share: float = 0.15,
    aggressive_share: float = 0.15,
    overwrite: bool = False,
    progress: bool = True,
    *,
    _stop_after_chunks: int | None = None,
) -> Dataset:
    """Generate ``n`` base scenarios from highway-env traffic into the dataset directory ``out``.

    Args:
        out: dataset directory (created; an unfinished build there with the same arguments is resumed).
        n: number of scenarios.
        seed: build seed; the same arguments give the same dataset for any ``workers``.
        layouts: subset of `seal.envs.layouts.LAYOUTS`; scenarios are spread evenly over them.
        workers: processes (None: ``os.cpu_count()``; 1: in this process).
        inattentive_share: share of drivers with distraction episodes.
        aggressive_share: share of aggressive drivers.
        overwrite: replace a finished dataset or an unfinished build with other arguments.
        progress: show a tqdm bar over the scenarios built.
        _stop_after_chunks: test hook: raise `GenerationInterrupted` after building that many chunks.
    """
    layouts = _check_args(n, seed, layouts, workers, inattentive_share, aggressive_share)
    n, seed = int(n), int(seed)
    # P(normal, inattentive, aggressive), in `DRIVER_KINDS` order.
    shares = (1.0 - inattentive_share - aggressive_share, float(inattentive_share), float(aggressive_share))
    params = {
        "generator": SOURCE,
        "version": GENERATOR_VERSION,
        "n": n,
        "seed": seed,
        "layouts": list(layouts),
        "inattentive_share": float(inattentive_share),
        "aggressive_share": float(aggressive_share),
    }
    builder = DatasetBuilder(out, params, overwrite=overwrite)
    if builder.shards:
        # Tell the user: a command that "starts" at 60 % is otherwise a surprise.
        print(f"resuming the unfinished build in {out}: {len(builder.shards)} shard(s) with "
              f"{builder.n_done_scenarios} scenarios already done", file=sys.stderr)
    workers = (os.cpu_count() or 1) if workers is None else workers
    n_chunks = _build_chunks(builder, n, seed, layouts, shares, workers, progress, _stop_after_chunks)
    provenance = {
        "generator": "seal.envs.generate.generate_dataset",
        "source": SOURCE,
        "seed": seed,
        "layouts": list(layouts),
        "inattentive_share": float(inattentive_share),
        "aggressive_share": float(aggressive_share),
        "runs": n_chunks * runs_per_chunk(n),
        "run_steps": RUN_STEPS,
        "scenarios_per_run_max": SCENARIOS_PER_RUN,
        "versions": _versions(),
    }
    return builder.finalize(n, provenance)


def _build_chunks(
    builder: DatasetBuilder, n: int, seed: int, layouts: tuple[str, ...], shares: tuple[float, float, float],
    workers: int, progress: bool, stop_after_chunks: int | None,
) -> int:
    """Build (or, where ``builder`` already holds them, count) shards until ``n`` scenarios exist; returns the
    number of chunks. Layouts of each chunk's runs follow the yields so far (`assign_layouts`)."""
    chunk_runs = runs_per_chunk(n)
    counts = dict.fromkeys(layouts, 0)
    runs = dict.fromkeys(layouts, 0)
    total = chunk = built = 0
    pool = None
    bar = None
    ok = False
    started: tuple[list[RunTask], Iterator[list[Scenario]]] | None = None  # the next chunk, already running
    try:
        while total < n:
            if builder.is_done(chunk):
                info = builder.shards[chunk]["info"]
                for x in layouts:
                    counts[x] += int(info["scenarios_per_layout"].get(x, 0))
                    runs[x] += int(info["runs_per_layout"].get(x, 0))
                total += int(builder.shards[chunk]["n_scenarios"])
                chunk += 1
                continue
            if stop_after_chunks is not None and built >= stop_after_chunks:
                raise GenerationInterrupted(f"stopped after {built} chunks (test hook)")
            if pool is None and workers > 1:
                pool = _make_pool(workers)
            if bar is None:
                bar = tqdm(
                    total=n, initial=min(total, n), unit="scenario", desc="generate", disable=not progress
                )
            tasks, results = started or _start_chunk(chunk, chunk_runs, seed, layouts, shares, counts, runs, pool)
            started = None
            scenarios, info = _collect_chunk(tasks, results, bar, n, layouts)
            for x in layouts:
                counts[x] += info["scenarios_per_layout"][x]
                runs[x] += info["runs_per_layout"][x]
            total += len(scenarios)
            if pool is not None and total < n and not builder.is_done(chunk + 1) and (
                stop_after_chunks is None or built + 1 < stop_after_chunks
            ):
                # The next chunk's layouts follow from the counts so far: start its runs now, so the workers
                # simulate while this process compresses and writes the shard.
                started = _start_chunk(chunk + 1, chunk_runs, seed, layouts, shares, counts, runs, pool)
            builder.write_shard(chunk, scenarios, info)
            chunk += 1
            built += 1
            if chunk >= 50 and total == 0:
                raise RuntimeError(f"{chunk * chunk_runs} runs produced no scenario; giving up")
        ok = True
    finally:
        if pool is not None:
            if ok:
                pool.close()
            else:
                pool.terminate()
            pool.join()
        if bar is not None:
            bar.close()
    return chunk


def _start_chunk(
    chunk: int, chunk_runs: int, seed: int, layouts: tuple[str, ...], shares: tuple[float, float, float],
    counts: dict[str, int], runs: dict[str, int], pool: Any,
) -> tuple[list[RunTask], Iterator[list[Scenario]]]:
    """The runs of chunk ``chunk`` (layouts by `assign_layouts` from the counts so far) and their results, which
    the pool starts computing at once."""
    plan = assign_layouts(layouts, counts, runs, chunk_runs)
    tasks = [RunTask(chunk * chunk_runs + k, layout, seed, shares) for k, layout in enumerate(plan)]
    return tasks, _map_runs(tasks, pool)


def _collect_chunk(
    tasks: list[RunTask], results: Iterator[list[Scenario]], bar: Any, n: int, layouts: tuple[str, ...]
) -> tuple[list[Scenario], dict[str, Any]]:
    """The scenarios of one chunk's runs, in run order, and the shard's info (runs, runs and scenarios per
    layout)."""
    scenarios: list[Scenario] = []
    chunk_counts = dict.fromkeys(layouts, 0)
    for task, result in zip(tasks, results, strict=True):
        scenarios.extend(result)
        chunk_counts[task.layout] += len(result)
        bar.update(max(0, min(len(result), n - bar.n)))
    info = {
        "runs": [t.run for t in tasks],
        "runs_per_layout": {x: sum(t.layout == x for t in tasks) for x in layouts},
        "scenarios_per_layout": chunk_counts,
    }
    return scenarios, info
