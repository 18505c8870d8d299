"""Closed loop of ``seal eval background``: how often background traffic hits the ego from behind, per kind.

For each ego (``heuristic`` or a `seal train` run folder) and each background kind, the normal episode of every
held-out scenario (`seal.experiments.evaluation.protocol.normal_episode`: the same seed as ``seal eval runs``,
the logged adversary) is played with ``ScenarioEnv(config={"background": kind})``. Reported per (ego, kind):
episodes, crash rate, rear-end hits by background traffic (`Rollout.rear_end_by_background`) per episode and
their share of the ego's crashes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from seal.core.scenario import Scenario
from seal.envs.background import BackgroundController
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation import protocol
from seal.experiments.training.egos import make_ego


def background_env(scenarios: Sequence[Scenario], kind: str, rapid: BackgroundController | None) -> ScenarioEnv:
    """The evaluation env of a background kind (``rapid``: the controller given; other kinds: built in)."""
    return ScenarioEnv(list(scenarios), config={"background": kind},
                       background_model=rapid if kind == "rapid" else None)


def closed_loop_metrics(scenarios: Sequence[Scenario], egos: Sequence[str], kinds: Sequence[str],
                        rapid: BackgroundController | None, seed: int, progress: Any = None
                        ) -> dict[str, dict[str, dict[str, float]]]:
    """``{ego: {kind: metrics}}`` (module docstring)."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for spec in egos:
        ego = make_ego(spec)
        out[spec] = {}
        for kind in kinds:
            env = background_env(scenarios, kind, rapid)
            crashes = rear = 0
            for i, scenario in enumerate(scenarios):
                rollout = protocol.normal_episode(env, scenario, i, ego, seed)
                crashes += rollout.crashed
                rear += rollout.rear_end_by_background()
                if progress is not None:
                    progress.update(1)
            n = len(scenarios)
            out[spec][kind] = {
                "episodes": n, "crash_rate": crashes / n, "rear_end_rate": rear / n,
                "rear_end_share_of_crashes": rear / crashes if crashes else math.nan,
            }
    return out


def rear_end_change(table: Mapping[str, Mapping[str, Mapping[str, float]]]) -> dict[str, dict[str, float]]:
    """Per ego and reactive kind: rear-end rate minus the ``replay`` one (negative = fewer rear-end hits)."""
    out: dict[str, dict[str, float]] = {}
    for ego, kinds in table.items():
        if "replay" not in kinds:
            continue
        base = kinds["replay"]["rear_end_rate"]
        out[ego] = {k: v["rear_end_rate"] - base for k, v in kinds.items() if k != "replay"}
    return out
