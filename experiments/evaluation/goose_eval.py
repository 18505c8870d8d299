"""Goal success of a GOOSE policy on held-out scenarios, the way the generator uses it: per scenario, observe the
roll-out against the logged adversary, then up to K curve updates, each followed by a roll-out of the heuristic
ego; success = some roll-out reaches the desired goal. A scenario whose logged adversary already reaches it
counts as solved with 0 updates (the generator keeps the curve then) and is reported apart.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from tqdm import tqdm

from seal.adversaries.goose.env import GooseEnv

Actor = Callable[[dict[str, np.ndarray]], np.ndarray]
"""Maps one Dict observation to a 12-d action in [-1, 1]."""


def zero_actor(obs: dict[str, np.ndarray]) -> np.ndarray:
    """Keeps the fitted curve (the NURBS refit of the log, no edit)."""
    return np.zeros(12)


def random_actor(seed: int) -> Actor:
    """Uniform random actions in [-1, 1]^12 from a seeded generator."""
    rng = np.random.default_rng(seed)
    return lambda obs: rng.uniform(-1.0, 1.0, 12)


def run_episode(env: GooseEnv, scenario_id: str, act: Actor) -> dict[str, Any]:
    """One GOOSE episode on ``scenario_id``; returns success, updates used and the final achieved goal."""
    obs, info = env.reset(options={"scenario_id": scenario_id})
    if info["solved_at_start"]:
        return {"scenario_id": scenario_id, "solved_at_start": True, "success": True, "updates": 0,
                "achieved_goal": obs["achieved_goal"].tolist(),
                "outcome": env.last_rollout.outcome if env.last_rollout is not None else None}
    done, updates = False, 0
    while not done:
        obs, _, terminated, truncated, info = env.step(act(obs))
        updates += 1
        done = terminated or truncated
    return {"scenario_id": scenario_id, "solved_at_start": False, "success": bool(info["is_success"]),
            "updates": updates, "achieved_goal": info["achieved_goal"], "outcome": info["outcome"]}


def evaluate(
    env: GooseEnv, scenario_ids: Sequence[str], actors: dict[str, Actor], progress: bool = True
) -> dict[str, dict[str, Any]]:
    """Per actor: success rate over all scenarios and over those not solved at the start, mean updates used,
    median final achieved goal, and the per-scenario rows."""
    out: dict[str, dict[str, Any]] = {}
    for name, act in actors.items():
        rows = [run_episode(env, sid, act) for sid in tqdm(scenario_ids, desc=f"eval {name}", unit="scenario",
                                                            disable=not progress, leave=False)]
        unsolved = [r for r in rows if not r["solved_at_start"]]
        achieved = np.array([r["achieved_goal"] for r in unsolved]) if unsolved else np.zeros((0, 3))
        out[name] = {
            "scenarios": len(rows),
            "solved_at_start": len(rows) - len(unsolved),
            "success_rate": float(np.mean([r["success"] for r in rows])) if rows else float("nan"),
            "success_rate_unsolved": float(np.mean([r["success"] for r in unsolved])) if unsolved else float("nan"),
            "mean_updates_unsolved": float(np.mean([r["updates"] for r in unsolved])) if unsolved else float("nan"),
            "median_final_goal_unsolved": np.median(achieved, axis=0).round(3).tolist() if unsolved else [],
            "crash_with_adv_rate_unsolved": float(np.mean(achieved[:, 0] <= 0.0)) if unsolved else float("nan"),
            "rows": rows,
        }
    return out
