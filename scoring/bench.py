"""Scoring benchmark: load, fit primitives and score a dataset in memory (nothing is written)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from seal.core.dataset import Dataset
from seal.scoring.store import default_workers, fit_dataset_primitives, score_scenarios


def run_scoring_bench(dataset_dir: str | Path, workers: int | None = None, limit: int | None = None) -> dict[str, Any]:
    """Time the scoring pipeline on a dataset (the first ``limit`` scenarios if given); seconds and ms/scenario."""
    t0 = time.perf_counter()
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
        "n_scenarios": n,
        "workers": default_workers() if workers is None else int(workers),
        "load_s": round(t_load - t0, 3),
        "fit_s": round(t_fit - t_load, 3),
        "score_s": round(t_score - t_fit, 3),
        "total_s": round(t_score - t0, 3),
        "ms_per_scenario": round(1e3 * (t_score - t_fit) / max(n, 1), 2),
        "total_ms_per_scenario": round(1e3 * (t_score - t0) / max(n, 1), 2),
    }
