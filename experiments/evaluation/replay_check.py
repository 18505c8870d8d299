"""Logged-ego replay check: does the logged ego, driven through the bicycle model, reach its destination?

For every scenario of a dataset the ego's logged track is turned into actions (`seal.envs.kinematics.recover_actions`,
closed loop from the current step) and played in `ScenarioEnv` with every other agent (the adversary included)
replaying its log. An import is sound when this succeeds for nearly every scenario: the road built from the
imported map holds the logged ego (no out-of-road), the tracks are consistent (no crash the log does not have)
and the route is reachable within the horizon.

Each failure is explained:

* ``out_of_road``: which test fired at the ego's last state - ``lateral`` (farther than ``max_lateral_m`` from
  the route), ``off_drivable`` (a box corner outside the drivable area grown by the tolerance) or
  ``solid_line`` (a ``continuous`` line through the box that the logged ego never crosses) - and whether the
  *logged* ego box at that step already leaves the drivable area (a map problem, not a replay problem);
* ``crash``: the other agent and whether the two *logged* boxes overlap at that step too (overlapping boxes in
  the recording, e.g. NGSIM measurement noise, not a replay error);
* ``timeout``: the route completion reached.

With ``ego="heuristic"`` the rule-based driver drives instead of the log (same explanations).

Run: ``python -m seal.experiments.evaluation.replay_check DATASET [--out FILE.json] [--limit N]`` (or ``seal data
replay-check``).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import Counter
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from seal.core.atomic import atomic_write_json
from seal.core.geometry import box_corners, boxes_overlap
from seal.core.outcome import Outcome
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, N_STEPS, VALID, WIDTH, Scenario, X, Y
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import recover_actions
from seal.envs.road_geometry import get_road_geometry
from seal.envs.route import Route
from seal.envs.scenario_env import DEFAULT_CONFIG, ScenarioEnv

EGO_DRIVERS = ("logged", "heuristic")
"""Who drives the ego: its logged track turned into actions, or the rule-based `HeuristicDriver` (same failure
explanations; the heuristic shows how a driver that does not know the log copes with the imported road)."""


def _box(row: np.ndarray) -> np.ndarray:
    return box_corners(row[X], row[Y], row[HEADING], row[LENGTH], row[WIDTH])


def _off_road_reason(scenario: Scenario, ego_row: np.ndarray, step: int) -> dict[str, Any]:
    geom = get_road_geometry(scenario.road)
    cfg = DEFAULT_CONFIG
    track = scenario.track(scenario.ego_id)
    route = Route.from_track(track.astype(np.float64), CURRENT_STEP)
    lateral = abs(route.project(float(ego_row[X]), float(ego_row[Y])).lateral)
    corners = _box(ego_row)
    off = not geom.on_road(corners[:, 0], corners[:, 1], cfg["offroad_tolerance_m"])
    v = track[:, VALID] > 0.5
    exempt = geom.continuous_hits_along(track[v][:, [X, Y, HEADING, LENGTH, WIDTH]].astype(np.float64))
    line = geom.crosses_continuous(
        float(ego_row[X]), float(ego_row[Y]), float(ego_row[HEADING]), float(ego_row[LENGTH]),
        float(ego_row[WIDTH]), exempt if exempt.any() else None,
    )
    reason = "lateral" if lateral > cfg["max_lateral_m"] else "off_drivable" if off else "solid_line" if line else "?"
    logged_off = None
    if step < N_STEPS and track[step, VALID] > 0.5:
        lc = _box(track[step])
        logged_off = not geom.on_road(lc[:, 0], lc[:, 1], cfg["offroad_tolerance_m"])
    return {"reason": reason, "lateral_m": round(lateral, 2), "logged_ego_off_drivable": logged_off}


def replay_one(env: ScenarioEnv, scenario: Scenario, ego_driver: str = "logged") -> dict[str, Any]:
    """Drive the ego of ``scenario`` in ``env`` (which must hold it) with its logged actions (``"logged"``) or the
    rule-based `HeuristicDriver` (``"heuristic"``); returns the outcome and its reason."""
    ego = scenario.track(scenario.ego_id)
    actions = recover_actions(ego, CURRENT_STEP)
    driver = HeuristicDriver() if ego_driver == "heuristic" else None
    obs, _ = env.reset(options={"scenario_id": scenario.scenario_id})
    t = CURRENT_STEP
    while True:
        logged = actions[t] if t < len(actions) else np.zeros(2)
        a = driver.act(obs) if driver is not None else logged
        obs, _, terminated, truncated, info = env.step(a)
        t += 1
        if terminated or truncated:
            break
    ro = info["rollout"]
    n = min(ro.last_step + 1, N_STEPS)
    both = (ego[CURRENT_STEP:n, VALID] > 0.5) & (ro.ego_track[CURRENT_STEP:n, VALID] > 0.5)
    err = np.hypot(*(ro.ego_track[CURRENT_STEP:n, :2] - ego[CURRENT_STEP:n, :2])[both].T)
    row: dict[str, Any] = {
        "scenario_id": scenario.scenario_id,
        "outcome": ro.outcome,
        "steps": ro.n_steps,
        "route_completion": round(float(ro.route_completion), 3),
        "max_tracking_error_m": round(float(err.max()), 3) if err.size else None,
    }
    if ro.outcome == Outcome.OUT_OF_ROAD:
        row.update(_off_road_reason(scenario, ro.ego_track[ro.last_step], ro.last_step))
    elif ro.outcome == Outcome.CRASH:
        step, other = ro.ego_crashes[0]
        logged = None
        if step < N_STEPS:
            a, b = ego[step], scenario.track(other)[step]
            if a[VALID] > 0.5 and b[VALID] > 0.5:
                logged = bool(boxes_overlap(_box(a), _box(b)))
        row.update({"crash_step": step, "crash_agent_id": int(other), "logged_boxes_overlap": logged})
    return row


def replay_check(scenarios: Sequence[Scenario], progress: bool = True, ego: str = "logged") -> dict[str, Any]:
    """Drive every scenario's ego (``ego``: one of `EGO_DRIVERS`); summary (rates, failure reasons) plus one row
    per scenario."""
    if ego not in EGO_DRIVERS:
        raise ValueError(f"ego must be one of {', '.join(EGO_DRIVERS)}, got {ego!r}")
    env = ScenarioEnv(list(scenarios))
    start = time.perf_counter()
    bar = tqdm(scenarios, desc="replay", unit="scenario", disable=not progress)
    rows = [replay_one(env, s, ego) for s in bar]
    outcomes = Counter(r["outcome"] for r in rows)
    n = len(rows)
    reasons = Counter(
        f"{r['outcome']}:{r.get('reason', 'logged overlap' if r.get('logged_boxes_overlap') else '')}".rstrip(":")
        for r in rows if r["outcome"] != Outcome.SUCCESS
    )
    return {
        "ego": ego,
        "scenarios": n,
        "success_rate": outcomes[Outcome.SUCCESS] / n if n else math.nan,
        "outcomes": dict(sorted(outcomes.items())),
        "failure_reasons": dict(sorted(reasons.items())),
        "seconds": round(time.perf_counter() - start, 2),
        "rows": rows,
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m seal.experiments.evaluation.replay_check",
        description="Replay the logged ego of every scenario of a dataset through the bicycle model in "
        "ScenarioEnv and report how often it reaches its destination, with the reason for each failure.",
    )
    parser.add_argument("dataset", help="dataset directory")
    parser.add_argument("--out", default=None, help="write the full result (with one row per scenario) as JSON")
    parser.add_argument("--limit", type=int, default=None, help="only the first N scenarios")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--ego", choices=EGO_DRIVERS, default="logged", help="who drives the ego (default logged)")
    args = parser.parse_args(argv)
    return run(args.dataset, args.out, args.limit, not args.no_progress, args.ego)


def run(
    dataset: str | Path, out: str | Path | None, limit: int | None, progress: bool = True, ego: str = "logged"
) -> int:
    """Check ``dataset``, print the summary and the failures, write the full result to ``out`` when given."""
    from seal.core.dataset import Dataset

    scenarios = Dataset.open(dataset).load(limit=limit)
    result = replay_check(scenarios, progress=progress, ego=ego)
    summary = {k: v for k, v in result.items() if k != "rows"}
    print(json.dumps(summary, indent=2))
    for r in result["rows"]:
        if r["outcome"] != Outcome.SUCCESS:
            print(json.dumps(r))
    if out is not None:
        atomic_write_json(out, {"dataset": str(dataset), **result})
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
