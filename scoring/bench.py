"""Scoring benchmark: load, fit primitives and score a dataset in memory (nothing is written)."""

from __future__ import annotations

import os
import resource
import time
from pathlib import Path
from typing import Any

from seal.core.dataset import Dataset
from seal.scoring.store import default_workers, fit_dataset_primitives, score_scenarios


def run_scoring_bench(dataset_dir: str | Path, workers: int | None = None, limit: int | None = None) -> dict[str, Any]:
    """Time the scoring pipeline on a dataset (the first ``limit`` scenarios if given).

    ``seconds`` is the wall time of the whole job (load, primitive fit, scoring); ``cpu_s`` the CPU time of this
    process and its workers (what a busy machine does not inflate as much), ``load_avg`` the 1-minute load
    average when the run ended (above the core count the wall times are not the machine's speed).
    """
    t0 = time.perf_counter()
    cpu0 = _cpu_seconds()
    scenarios = Dataset.open(dataset_dir).load()
    if limit is not None:
        scenarios = scenarios[:limit]
    t_load = time.perf_counter()
    prim = fit_dataset_primitives(scenarios)
    t_fit = time.perf_counter()
    score_scenarios(scenarios, prim, workers=workers, progress=False)
    t_score = time.perf_counter()
    n = len(scenarios)
    return {
        "scenarios": n,
        "seconds": round(t_score - t0, 3),
        "cpu_s": round(_cpu_seconds() - cpu0, 3),
        "load_avg": round(os.getloadavg()[0], 2),
        "cores": os.cpu_count(),
        "n_scenarios": n,
        "workers": default_workers() if workers is None else int(workers),
        "load_s": round(t_load - t0, 3),
        "fit_s": round(t_fit - t_load, 3),
        "score_s": round(t_score - t_fit, 3),
        "total_s": round(t_score - t0, 3),
        "ms_per_scenario": round(1e3 * (t_score - t_fit) / max(n, 1), 2),
        "total_ms_per_scenario": round(1e3 * (t_score - t0) / max(n, 1), 2),
    }


def _cpu_seconds() -> float:
    """User + system CPU seconds of this process and its finished child processes."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime
