"""``goose``: GOOSE (Ransiek et al., ITSC 2024; thesis 6.4.2) with a trained goal-conditioned agent.

The generator keeps, per scenario, the adversary's NURBS curve (`GooseCurve`, fitted to the logged path in the
adversary's initial frame) and how many times it has updated it. Each call observes the most recent roll-out in
``history`` and, unless that roll-out already reached the desired goal or the curve has had ``max_updates`` (K)
updates, lets the agent edit the curve once (one curve update per observed roll-out). The adversary then
replays the curve re-timed with its logged speed profile (`GooseCurve.track`).

Why a replayed track and not `seal.envs.behaviors.TrackingBehavior`: GOOSE's adversary follows its curve exactly
(as CAT's replays its chosen path), and the goal's kinematic bounds (|acc| <= 8 m/s^2, |yaw rate| <= 0.7 rad/s)
are what keeps the curve feasible. A tracking controller would clip an infeasible curve through the bicycle
model's limits, hiding the violation from the goal, and add tracking errors the agent never sees.

A roll-out continues the kept curve only if its adversary moved exactly along the track this generator returned
last for that scenario; any other roll-out (e.g. the normal episode before the first pass, or an evaluation of
a new ego reusing this instance) restarts the scenario from the fitted curve with no updates used.

Use: ``make_generator("goose", model="agent.zip")`` with an agent file from ``seal fit goose``; in a
``seal eval generators --config`` YAML: ``generators: {goose: {model: agent.zip}}``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from seal.adversaries.base import AdversaryGenerator, Generation, register
from seal.adversaries.goose.agent import GooseAgent, load_goose_agent
from seal.adversaries.goose.curve import GooseCurve
from seal.adversaries.goose.goals import achieved_goal, goal_reached
from seal.adversaries.goose.obs import build_observation
from seal.core.scenario import CURRENT_STEP, N_STEPS, VALID, Scenario
from seal.envs.behaviors import ReplayBehavior
from seal.envs.rollout import Rollout

MATCH_TOL_M = 0.05
"""A roll-out's adversary within this of the returned track at every executed step was driven by it."""


@dataclass(frozen=True)
class _Kept:
    curve: GooseCurve
    track: np.ndarray
    updates: int


def driven_by(rollout: Rollout, track: np.ndarray, tol_m: float = MATCH_TOL_M) -> bool:
    """True if the roll-out's adversary followed ``track [N_STEPS, 8]`` at every executed step (same presence,
    positions within ``tol_m``)."""
    last = min(rollout.last_step, N_STEPS - 1)
    if last <= CURRENT_STEP:
        return False
    rows = slice(CURRENT_STEP + 1, last + 1)
    done, want = rollout.adv_track[rows].astype(np.float64), np.asarray(track, dtype=np.float64)[rows]
    present, expected = done[:, VALID] > 0.5, want[:, VALID] > 0.5
    if not np.array_equal(present, expected):
        return False
    return bool(np.all(np.hypot(*(done[present, :2] - want[present, :2]).T) <= tol_m))


@register("goose")
class GooseGenerator(AdversaryGenerator):
    """GOOSE generator (see the module docstring).

    Args:
        model: a GOOSE agent file (`seal fit goose ... --out FILE`) or a loaded `GooseAgent`.
        deterministic: use the agent's deterministic action (True) or sample it (SAC only; seeded from ``rng``).
        max_updates: curve updates per scenario (default: the agent's ``spec.max_updates``, K = 5).
    """

    def __init__(
        self, model: str | Path | GooseAgent | None = None, deterministic: bool = True, max_updates: int | None = None
    ) -> None:
        if model is None:
            raise ValueError("generator 'goose' needs model=PATH, a GOOSE agent file (train one with `seal fit goose`)")
        self.agent = model if isinstance(model, GooseAgent) else load_goose_agent(model)
        self.spec = self.agent.spec
        self.deterministic = deterministic
        self.max_updates = self.spec.max_updates if max_updates is None else int(max_updates)
        if self.max_updates < 0:
            raise ValueError(f"max_updates must be >= 0, got {max_updates}")
        self._kept: dict[str, _Kept] = {}

    def forget(self, scenario_id: str | None = None) -> None:
        """Drop the kept curve of one scenario (all when None)."""
        if scenario_id is None:
            self._kept.clear()
        else:
            self._kept.pop(scenario_id, None)

    def updates_used(self, scenario_id: str) -> int:
        kept = self._kept.get(scenario_id)
        return 0 if kept is None else kept.updates

    def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        sid = scenario.scenario_id
        last = history[-1] if history else None
        if last is not None and last.scenario_id != sid:
            raise ValueError(f"goose: history roll-out is of scenario {last.scenario_id!r}, not {sid!r}")
        kept = self._kept.get(sid)
        if kept is None or last is None or not driven_by(last, kept.track):
            curve = GooseCurve.from_scenario(scenario, self.spec.timing)
            kept = _Kept(curve, curve.track(), 0)
        extra: dict = {"fit_error_m": round(kept.curve.fit_error_m, 4)}
        if last is None:
            reason = "no_history"
        else:
            achieved = achieved_goal(last)
            extra["observed_goal"] = [round(float(v), 4) for v in achieved]
            if goal_reached(achieved, self.spec.goal_array):
                reason = "goal_met"
            elif kept.updates >= self.max_updates:
                reason = "max_updates"
            else:
                obs = build_observation(self.spec, kept.curve, last, kept.updates, achieved)
                if self.deterministic:
                    action = self.agent.act(obs, deterministic=True)
                else:
                    with torch.random.fork_rng():
                        torch.manual_seed(int(rng.integers(2**31)))
                        action = self.agent.act(obs, deterministic=False)
                curve = kept.curve.edited(action, self.spec)
                kept = _Kept(curve, curve.track(), kept.updates + 1)
                reason = "update"
                extra["action"] = [round(float(v), 4) for v in action]
        self._kept[sid] = kept
        extra.update(
            reason=reason, updates=kept.updates, ctrl_m=np.round(kept.curve.ctrl, 3).tolist(),
            weights=np.round(kept.curve.weights, 4).tolist(), length_ratio=round(kept.curve.length_ratio(), 4),
        )
        return Generation(behavior=ReplayBehavior(kept.track), extra=extra)
