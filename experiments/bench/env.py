"""``seal bench env``: ScenarioEnv steps/s against highway-env's ``highway-v0``, measured in the same run.

ScenarioEnv runs with the full observation, replayed traffic and the replayed adversary, in one process, over
the scenarios of a dataset (or, without one, scenarios generated in memory from highway-env traffic on all
layouts). The ego is driven by the heuristic driver (realistic episode lengths) or uniform random actions.
The reference is ``highway-v0`` with 10 vehicles, ``LidarObservation``, 10 Hz policy and simulation
frequency and random meta-actions. For both, only the time spent inside ``env.step`` and ``env.reset`` counts
(policies excluded), and resets are included in the step rate. Rates are reported per wall-clock second (the
headline) and per CPU second of this process (robust to other load on the machine).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.scenario import Scenario

TARGET_STEPS_PER_S = 6000.0
"""Issue 23: ScenarioEnv steps per wall second in one process (compiled observation, collisions, projection)."""
TARGET_RATIO = 14.0
"""Issue 23: ScenarioEnv steps/s over highway-v0 steps/s, measured in the same run."""
HIGHWAY_CONFIG: dict[str, Any] = {
    "vehicles_count": 10,
    "observation": {"type": "LidarObservation"},
    "policy_frequency": 10,
    "simulation_frequency": 10,
}


def bench_scenarios(dataset: str | Path | None, seed: int = 0, n_runs: int = 8) -> tuple[list[Scenario], str]:
    """Scenarios to benchmark on and a description of where they come from.

    Without a dataset: ``n_runs`` highway-env traffic runs (spread over the layouts) simulated in this process
    by `seal.envs.generate`.
    """
    if dataset is not None:
        from seal.core.dataset import load_scenarios

        return load_scenarios(dataset), f"dataset {dataset}"
    from seal.envs.generate import RunTask, simulate_run
    from seal.envs.layouts import LAYOUTS

    scenarios: list[Scenario] = []
    for run in range(n_runs):
        task = RunTask(run=run, layout=LAYOUTS[run % len(LAYOUTS)], seed=seed, kind_shares=(0.7, 0.15, 0.15))
        scenarios.extend(simulate_run(task))
    return scenarios, f"in-memory highway-env traffic ({n_runs} runs, {', '.join(LAYOUTS)})"


def bench_scenario_env(
    scenarios: list[Scenario], n_steps: int, seed: int = 0, policy: str = "heuristic"
) -> dict[str, Any]:
    """Steps/s of `ScenarioEnv` over ``n_steps`` steps (episodes restart on random scenarios)."""
    from seal.envs.heuristic import HeuristicDriver
    from seal.envs.scenario_env import ScenarioEnv

    env = ScenarioEnv(scenarios)
    driver = HeuristicDriver()
    rng = np.random.default_rng(seed)
    # Warm the per-road caches (geometry, grid cells) outside the timed loop, as a long training run would.
    for s in scenarios:
        env.reset(options={"scenario_id": s.scenario_id})
    t0, c0 = time.perf_counter(), time.process_time()
    obs, _ = env.reset(seed=seed)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    episodes = 1
    outcomes: dict[str, int] = {}  # outcome -> episodes
    for _ in range(n_steps):
        action = driver.predict(obs)[0] if policy == "heuristic" else rng.uniform(-1.0, 1.0, 2)
        t0, c0 = time.perf_counter(), time.process_time()
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            outcomes[info["outcome"]] = outcomes.get(info["outcome"], 0) + 1
            obs, _ = env.reset()
            episodes += 1
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
    return {"steps_per_s": n_steps / wall, "steps_per_cpu_s": n_steps / cpu, "episodes": episodes,
            "outcomes": outcomes}


def bench_highway_v0(n_steps: int, seed: int = 0) -> dict[str, Any]:
    """Steps/s of highway-env's ``highway-v0`` (`HIGHWAY_CONFIG`, random actions)."""
    import gymnasium
    import highway_env  # noqa: F401  (registers highway-v0)

    env = gymnasium.make("highway-v0", config=HIGHWAY_CONFIG)
    env.action_space.seed(seed)
    t0, c0 = time.perf_counter(), time.process_time()
    env.reset(seed=seed)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    episodes = 1
    for _ in range(n_steps):
        action = env.action_space.sample()
        t0, c0 = time.perf_counter(), time.process_time()
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
            episodes += 1
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
    env.close()
    return {"steps_per_s": n_steps / wall, "steps_per_cpu_s": n_steps / cpu, "episodes": episodes}


def run_env_bench(
    dataset: str | Path | None, n_steps: int = 3000, seed: int = 0, policy: str = "heuristic"
) -> dict[str, Any]:
    """Benchmark ScenarioEnv against highway-v0 in one run; returns rates, their ratio and the targets.

    Args:
        dataset: dataset directory, or None for scenarios generated in memory (`bench_scenarios`).
        n_steps: env steps per measurement.
        seed: seed for scenario choice, actions and highway-v0.
        policy: ego actions, ``"heuristic"`` or ``"random"``.
    """
    if policy not in ("heuristic", "random"):
        raise ValueError(f"policy must be 'heuristic' or 'random', got {policy!r}")
    scenarios, source = bench_scenarios(dataset, seed)
    ours = bench_scenario_env(scenarios, n_steps, seed, policy)
    ref = bench_highway_v0(n_steps, seed)
    ratio = ours["steps_per_s"] / ref["steps_per_s"]
    return {
        "scenario_env_steps_per_s": round(ours["steps_per_s"], 1),
        "highway_v0_steps_per_s": round(ref["steps_per_s"], 1),
        "ratio": round(ratio, 2),
        # Per CPU second of this process: less sensitive to other load on the machine.
        "scenario_env_steps_per_cpu_s": round(ours["steps_per_cpu_s"], 1),
        "highway_v0_steps_per_cpu_s": round(ref["steps_per_cpu_s"], 1),
        "ratio_cpu": round(ours["steps_per_cpu_s"] / ref["steps_per_cpu_s"], 2),
        "meets_target": bool(ours["steps_per_s"] >= TARGET_STEPS_PER_S and ratio >= TARGET_RATIO),
        "target": f">= {TARGET_STEPS_PER_S:.0f} steps/s and ratio >= {TARGET_RATIO}",
        "n_steps": n_steps,
        "policy": policy,
        "scenarios": len(scenarios),
        "scenario_source": source,
        "scenario_env_episodes": ours["episodes"],
        "scenario_env_outcomes": ours["outcomes"],
        "highway_v0_episodes": ref["episodes"],
        "highway_v0_config": HIGHWAY_CONFIG,
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run_env_bench(None), indent=2))
