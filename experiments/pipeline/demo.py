"""The README's main job on the embedded default.

1. build a small base-scenario dataset from highway-env traffic (all layouts),
2. roll a few scenarios out in ScenarioEnv (heuristic reactive ego, replayed adversary and traffic),
3. write the per-scenario outcomes (CSV), a summary table (Markdown) and a short top-down video per layout.

Every step is skipped when its output already exists, so an interrupted demo resumes where it stopped.
"""

from __future__ import annotations

import csv
import io
import logging
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from tqdm import tqdm

from seal.core.atomic import atomic_write_bytes
from seal.core.dataset import MANIFEST, Dataset
from seal.core.scenario import Scenario
from seal.envs.episode_video import render_episode
from seal.envs.generate import generate_dataset
from seal.envs.heuristic import HeuristicDriver
from seal.envs.scenario_env import ScenarioEnv
from seal.scoring.proximity import pair_proximity

OUTCOME_FIELDS = (
    "scenario_id", "layout", "outcome", "route_completion", "steps", "return", "logged_pair_min_gap_m",
)

logger = logging.getLogger(__name__)


def pick_spread(scenarios: list[Scenario], n: int) -> list[Scenario]:
    """Up to ``n`` scenarios, taken round-robin over layouts so every layout is shown."""
    by_layout: dict[str, list[Scenario]] = defaultdict(list)
    for s in scenarios:
        by_layout[s.layout].append(s)
    queues = [by_layout[name] for name in sorted(by_layout)]
    picked: list[Scenario] = []
    while len(picked) < n and any(queues):
        for q in queues:
            if q and len(picked) < n:
                picked.append(q.pop(0))
    return picked


def roll_out(env: ScenarioEnv, scenario: Scenario, seed: int) -> dict[str, Any]:
    """One episode with the heuristic ego; returns the outcome row."""
    driver = HeuristicDriver()
    obs, info = env.reset(seed=seed, options={"scenario_id": scenario.scenario_id})
    total, steps, done = 0.0, 0, False
    while not done:
        action, _ = driver.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        done = terminated or truncated
    outcome = (
        "success" if info["is_success"] else "crash" if info["crashed"] else
        "out_of_road" if info["out_of_road"] else "time_limit"
    )
    return {
        "scenario_id": scenario.scenario_id,
        "layout": scenario.layout,
        "outcome": outcome,
        "route_completion": round(float(info["route_completion"]), 3),
        "steps": steps,
        "return": round(total, 2),
        "logged_pair_min_gap_m": round(pair_proximity(scenario).min_gap_m, 2),
    }


def summary_table(rows: list[dict[str, Any]]) -> str:
    """Markdown: outcome rates per layout and overall."""
    groups: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        groups[r["layout"]].append(r)
    groups["all"] = rows
    lines = [
        "| layout | episodes | success | crash | out of road | time limit | mean route completion |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name, rs in groups.items():
        n = len(rs)
        rate = {k: sum(r["outcome"] == k for r in rs) / n for k in ("success", "crash", "out_of_road", "time_limit")}
        completion = float(np.mean([r["route_completion"] for r in rs]))
        lines.append(
            f"| {name} | {n} | {rate['success']:.0%} | {rate['crash']:.0%} | {rate['out_of_road']:.0%} "
            f"| {rate['time_limit']:.0%} | {completion:.2f} |"
        )
    return "\n".join(lines) + "\n"


def run_demo(out: Path, n_scenarios: int = 40, n_rollouts: int = 12, seed: int = 0, overwrite: bool = False) -> dict:
    """Run the demo into ``out``; returns the summary rows."""
    out.mkdir(parents=True, exist_ok=True)
    config = {"n_scenarios": n_scenarios, "n_rollouts": n_rollouts, "seed": seed, "ego": "heuristic",
              "adversary": "replay"}
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(config, sort_keys=True).encode())

    data_dir = out / "data"
    if (data_dir / MANIFEST).exists() and not overwrite:
        logger.info(f"[1/3] dataset {data_dir} exists, reusing it")
        ds = Dataset.open(data_dir)
    else:
        logger.info(f"[1/3] generating {n_scenarios} base scenarios into {data_dir}")
        ds = generate_dataset(data_dir, n=n_scenarios, seed=seed, overwrite=overwrite)
    scenarios = ds.load()

    logger.info(f"[2/3] rolling out {min(n_rollouts, len(scenarios))} scenarios (heuristic ego vs replayed adversary)")
    picked = pick_spread(scenarios, n_rollouts)
    env = ScenarioEnv(picked)
    rows = [roll_out(env, s, seed + i) for i, s in enumerate(tqdm(picked, desc="roll-outs", unit="episode"))]
    env.close()

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=OUTCOME_FIELDS)
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(out / "rollouts.csv", buf.getvalue().encode())
    table = summary_table(rows)
    per_scenario = "\n".join(
        f"| {r['scenario_id']} | {r['outcome']} | {r['route_completion']:.2f} | {r['logged_pair_min_gap_m']:.1f} |"
        for r in rows
    )
    markdown = (
        f"# seal demo\n\nDataset: `{data_dir}` ({len(scenarios)} scenarios). Ego: heuristic reactive driver; "
        "adversary and traffic: replayed logs.\n\n## Outcomes\n\n" + table +
        "\n## Episodes\n\n| scenario | outcome | route completion | logged pair min gap (m) |\n|---|---|---:|---:|\n"
        + per_scenario + "\n"
    )
    atomic_write_bytes(out / "summary.md", markdown.encode())

    logger.info("[3/3] rendering one video per layout")
    videos = out / "videos"
    videos.mkdir(exist_ok=True)
    seen: set[str] = set()
    for s in tqdm(picked, desc="videos", unit="video"):
        if s.layout in seen:
            continue
        seen.add(s.layout)
        render_episode(s, videos / f"{s.scenario_id}.mp4")
    return {"rows": rows, "table": table,
            "wrote": f"wrote {out / 'summary.md'}, {out / 'rollouts.csv'} and {len(seen)} videos in {videos}"}
