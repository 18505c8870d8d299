"""The simulation core shared by `seal.envs.scenario_env.ScenarioEnv` (one driven ego and adversary) and
`seal.envs.multi_agent.MultiAgentSim` (every vehicle driven): placing agents in the per-step box table, the one
collision test, the road checks, and the ego's reward terms and outcome.

The per-step box table ``cur [A, 8]`` holds every agent's row in track layout (`seal.core.scenario.TRACK_FIELDS`):
its logged row at the step for replayed agents, the simulated state for driven ones, zeros (``valid`` = 0) for
absent ones. Collisions are oriented-box overlaps (`seal.core.kernels.box_hits_rows`, compiled, per step;
`seal.core.geometry.pairwise_overlaps` for many driven agents: the same separating-axis test).

Reward (CAT / MetaDrive defaults), as named terms (highway-env's ``_rewards``): ``progress`` (``progress_reward``
= 1 per metre of route progress, negative when going back), ``out_of_road`` (``-out_of_road_penalty`` = -10),
``crash`` (``-crash_penalty`` = -1) and ``arrival`` (``+success_reward`` = +10). On a step where something happens
its term replaces progress, in this priority: out of road, crash, arrival; the step reward is the sum of the terms
(at most one is non-zero).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.core.geometry import corners_xy
from seal.core.kernels import box_hits_rows
from seal.core.outcome import Outcome
from seal.core.scenario import N_STEPS
from seal.envs.kinematics import AgentState
from seal.envs.road_geometry import RoadGeometry

REWARD_TERMS = ("progress", "out_of_road", "crash", "arrival")
"""Names of the reward terms in ``info["reward_terms"]``, in the order they are summed."""


# ------------------------------------------------------------------------------------------------ placement
def state_row(state: AgentState) -> tuple[float, ...]:
    """A driven agent's row of the box table (track layout, valid = 1)."""
    return (state.x, state.y, state.heading, state.vx, state.vy, state.length, state.width, 1.0)


def logged_rows(log: np.ndarray, t: int) -> np.ndarray:
    """A fresh ``[A, 8]`` box table with every agent's logged row at step ``t`` (all absent after the log)."""
    return log[:, t].copy() if t < N_STEPS else np.zeros((log.shape[0], 8))


# ------------------------------------------------------------------------------------------------ collisions
def box_hits(state: AgentState, cur: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Indices in ``idx`` (rows of ``cur``, ascending as given) whose boxes overlap ``state``'s box (one compiled
    call, `seal.core.kernels.box_hits_rows`: the half-diagonal pre-filter, then the separating-axis test)."""
    return box_hits_rows(state.x, state.y, state.heading, state.length, state.width, cur, idx)


# ------------------------------------------------------------------------------------------------ road checks
@dataclass(frozen=True)
class RoadChecks:
    """The road rules of a driven agent on one road.

    Attributes:
        geometry: the road's drivable area and painted lines.
        max_lateral_m: distance from the agent's route beyond which it is out of road (m).
        offroad_tolerance_m: how far a box corner may leave the drivable area (m).
        check_continuous_lines: crossing a ``continuous`` line (other than exempt ones) is out of road.
    """

    geometry: RoadGeometry
    max_lateral_m: float
    offroad_tolerance_m: float
    check_continuous_lines: bool

    def corners_on_road(self, state: AgentState) -> bool:
        """Every box corner lies on the drivable area (within the tolerance)."""
        cx, cy = corners_xy(state.x, state.y, state.heading, state.length, state.width)
        return bool(self.geometry.on_road(cx, cy, self.offroad_tolerance_m))

    def too_far(self, lateral_m: float) -> bool:
        """More than ``max_lateral_m`` from the route."""
        return abs(lateral_m) > self.max_lateral_m

    def crosses_solid(self, state: AgentState, exempt: np.ndarray | None) -> bool:
        """The box crosses a ``continuous`` line not in ``exempt`` (never when line checks are off)."""
        return bool(
            self.check_continuous_lines
            and self.geometry.crosses_continuous(state.x, state.y, state.heading, state.length, state.width, exempt)
        )


# ------------------------------------------------------------------------------------------------ ego episode
@dataclass(frozen=True)
class StepEvents:
    """What happened to the ego on one step.

    Attributes:
        crashed: its box overlaps another agent's.
        crash_id: id of an agent it overlaps (the adversary when among them), -1 if none.
        adv_crashed: the adversary's box overlaps a third agent's.
        out_of_road: it left the road (`RoadChecks`).
        success: it arrived (route completion above the threshold, without crash or leaving the road).
    """

    crashed: bool = False
    crash_id: int = -1
    adv_crashed: bool = False
    out_of_road: bool = False
    success: bool = False


@dataclass(frozen=True)
class RewardConfig:
    """Weights of the reward terms (see the module docstring).

    Attributes:
        progress_reward: per metre of route progress.
        success_reward: on arrival.
        out_of_road_penalty: on leaving the road (subtracted).
        crash_penalty: on each step in contact (subtracted).
    """

    progress_reward: float
    success_reward: float
    out_of_road_penalty: float
    crash_penalty: float


def reward_terms(weights: RewardConfig, progress_m: float, events: StepEvents) -> dict[str, float]:
    """The step's reward terms (`REWARD_TERMS` order): the event's term replaces ``progress`` (module docstring)."""
    terms = dict.fromkeys(REWARD_TERMS, 0.0)
    if events.out_of_road:
        terms["out_of_road"] = -weights.out_of_road_penalty
    elif events.crashed:
        terms["crash"] = -weights.crash_penalty
    elif events.success:
        terms["arrival"] = weights.success_reward
    else:
        terms["progress"] = weights.progress_reward * progress_m
    return terms


def total_reward(terms: dict[str, float]) -> float:
    """The step reward: the sum of the terms (exactly the one non-zero term)."""
    total = 0.0
    for name in REWARD_TERMS:
        total += terms[name]
    return float(total)


def episode_outcome(events: StepEvents) -> Outcome:
    """How an episode ending on a step with ``events`` ended (out of road before crash before success)."""
    if events.out_of_road:
        return Outcome.OUT_OF_ROAD
    if events.crashed:
        return Outcome.CRASH
    if events.success:
        return Outcome.SUCCESS
    return Outcome.TIMEOUT
