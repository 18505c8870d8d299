"""`seal bench prior`: latency of `TrajectoryPrior.predict` (32 candidates per scenario) on CPU.

Timed is the whole ``predict`` call: featurisation from `Scenario` objects, the network, the transform to the
world frame and building `Candidates`. "Warm" calls reuse the prior's per-road lane-chunk cache (a generator asks
about the same scenario several times); "cold" calls clear it first. Medians over repetitions after warm-up, in
wall-clock milliseconds (the headline) and in CPU milliseconds of this process (robust to other load on a shared
machine).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Sequence
from typing import Any

import torch

from seal.core.scenario import Scenario
from seal.models.prior.prior import TrajectoryPrior

TARGET_SINGLE_MS = 10.0


def _median_ms(fn: Any, repeats: int) -> tuple[float, float]:
    """Median wall-clock and CPU (this process) milliseconds of ``fn()``."""
    wall, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return 1000.0 * statistics.median(wall), 1000.0 * statistics.median(cpu)


def bench_prior(
    prior: TrajectoryPrior, scenarios: Sequence[Scenario], repeats: int = 50, batch: int = 64,
    warmup: int = 5,
) -> dict[str, Any]:
    """Median latency (ms) of ``predict`` for one scenario (warm and cold cache) and for ``batch`` scenarios."""
    if not scenarios:
        raise ValueError("bench_prior needs at least one scenario")
    pool = list(scenarios)
    big = [pool[i % len(pool)] for i in range(batch)]
    state = {"i": 0}

    def one() -> None:
        state["i"] = (state["i"] + 1) % len(pool)
        prior.predict([pool[state["i"]]])

    def one_cold() -> None:
        prior._cache = type(prior._cache)(prior._cache.chunk_length_m, prior._cache.n_points)
        one()

    for _ in range(warmup):
        one()
        prior.predict(big)
    single_warm, single_warm_cpu = _median_ms(one, repeats)
    single_cold, _ = _median_ms(one_cold, repeats)
    batched, batched_cpu = _median_ms(lambda: prior.predict(big), max(3, repeats // 5))
    return {
        "candidates": prior.n_candidates,
        "threads": torch.get_num_threads(),  # set by the caller (entry point)
        "single_scenario_ms": round(single_warm, 2),
        "single_scenario_cpu_ms": round(single_warm_cpu, 2),
        "single_scenario_cold_cache_ms": round(single_cold, 2),
        f"batch_{batch}_ms": round(batched, 2),
        f"batch_{batch}_cpu_ms": round(batched_cpu, 2),
        f"batch_{batch}_per_scenario_ms": round(batched / batch, 3),
        "target_single_ms": TARGET_SINGLE_MS,
        "meets_target": single_warm < TARGET_SINGLE_MS,
        "repeats": repeats,
    }
