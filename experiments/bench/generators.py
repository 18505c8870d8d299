"""``seal bench generators``: generation latency per scenario (batch of one, CPU), the number the real-time budget
is about (RAPID: < 30 ms per generation; CAT: < 1 s).

Each generator is called twice per scenario on a queue of K roll-outs (K copies of the logged ego future, the
queue a scenario starts with), after one untimed warm-up call on the first scenario (lazy imports). The first call
on a scenario is "cold" (per-road caches, e.g. the prior's map featurisation, are empty), the second "warm" (the
closed loop generates K = 5 times per scenario, so most calls are warm). Reported per generator: mean / p50 / p95
/ max milliseconds of `AdversaryGenerator.generate` over cold calls (the headline) and the warm mean / p95
(candidate prediction included), and, where the generator reports them, the candidate-source and selection
shares of the cold calls (SEAL: also its objective's ranking time). The reference measured in the same run is
``replay`` (no work beyond building its behaviour).
"""

from __future__ import annotations

import os
import time
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from seal.adversaries.base import AdversaryGenerator
from seal.adversaries.history import RolloutHistory
from seal.core.scenario import Scenario

BUDGET_MS = 30.0


def _stats(ms: np.ndarray) -> dict[str, float]:
    return {
        "mean": round(float(ms.mean()), 3),
        "p50": round(float(np.percentile(ms, 50)), 3),
        "p95": round(float(np.percentile(ms, 95)), 3),
        "max": round(float(ms.max()), 3),
    }


def bench_generators(
    scenarios: Sequence[Scenario], generators: Mapping[str, AdversaryGenerator], seed: int = 0,
    budget_ms: float = BUDGET_MS,
) -> dict[str, Any]:
    """Latency table: ``{name: {mean, p50, p95, max, [candidate_ms_mean, select_ms_mean], within_budget}}``."""
    history = RolloutHistory()
    queues = [history.queue(s) for s in scenarios]  # built before timing
    result: dict[str, Any] = {"scenarios": len(scenarios), "budget_ms": budget_ms,
                              "load_avg": round(os.getloadavg()[0], 2)}
    for name, generator in generators.items():
        rng = np.random.default_rng(seed)
        generator.generate(scenarios[0], queues[0], rng)  # warm-up
        total, cpu, warm, cand, select, rank = [], [], [], [], [], []
        for scenario, queue in zip(scenarios, queues, strict=True):
            start, cpu_start = time.perf_counter(), time.process_time()
            generation = generator.generate(scenario, queue, rng)
            total.append(time.perf_counter() - start)
            cpu.append(time.process_time() - cpu_start)
            start = time.perf_counter()
            generator.generate(scenario, queue, rng)
            warm.append(time.perf_counter() - start)
            if "candidate_time_s" in generation.extra:
                cand.append(generation.extra["candidate_time_s"])
                select.append(generation.extra["select_time_s"])
            if "rank_time_s" in generation.extra:
                rank.append(generation.extra["rank_time_s"])
        ms = 1e3 * np.asarray(total)
        row: dict[str, Any] = {f"ms_{k}": v for k, v in _stats(ms).items()}
        warm_stats = _stats(1e3 * np.asarray(warm))
        row["warm_ms_mean"], row["warm_ms_p95"] = warm_stats["mean"], warm_stats["p95"]
        # CPU time of the cold calls: what the generator costs without the other processes' share of a loaded
        # machine (wall time = CPU time on an idle one; the load average is in the result).
        cpu_stats = _stats(1e3 * np.asarray(cpu))
        row["cpu_ms_mean"], row["cpu_ms_p95"] = cpu_stats["mean"], cpu_stats["p95"]
        if cand:
            row["candidate_ms_mean"] = round(1e3 * float(np.mean(cand)), 3)
            row["select_ms_mean"] = round(1e3 * float(np.mean(select)), 3)
        if rank:  # SEAL: the objective's share of the selection (ranking all candidates)
            row["rank_ms_mean"] = round(1e3 * float(np.mean(rank)), 3)
            row["rank_ms_p95"] = round(1e3 * float(np.percentile(rank, 95)), 3)
        row["p95_within_budget"] = bool(row["ms_p95"] < budget_ms)
        result[name] = row
    if "replay" in generators:
        ref = result["replay"]["ms_mean"]
        for name in generators:
            result[name]["x_replay"] = round(result[name]["ms_mean"] / max(ref, 1e-6), 1)
    return result


def format_bench(result: dict[str, Any]) -> str:
    """Aligned text table of `bench_generators`."""
    names = [k for k, v in result.items() if isinstance(v, dict)]
    cols = ("ms_mean", "ms_p50", "ms_p95", "ms_max", "cpu_ms_mean", "cpu_ms_p95", "warm_ms_mean", "warm_ms_p95",
            "candidate_ms_mean",
            "select_ms_mean", "rank_ms_mean", "rank_ms_p95", "x_replay", "p95_within_budget")
    lines = [
        f"generation latency per scenario (batch of one, CPU), {result['scenarios']} scenarios, "
        f"budget {result['budget_ms']:.0f} ms, load average {result.get('load_avg', '-')}",
        "(ms_*: first call per scenario, wall; cpu_ms_*: its CPU time; warm_*: second call; candidate / select: "
        "shares of the first call; rank: SEAL's objective within select)",
        f"{'generator':<12}" + "".join(f"{c:>18}" for c in cols),
    ]
    for name in names:
        lines.append(f"{name:<12}" + "".join(f"{str(result[name].get(c, '-')):>18}" for c in cols))
    return "\n".join(lines)
