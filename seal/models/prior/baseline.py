"""Constant-velocity candidates: the baseline the prior is measured against, and its fallback for agents with too
little history for the network."""

from __future__ import annotations

import numpy as np

from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, N_FUTURE, VX, VY, Scenario, X, Y
from seal.models.prior.candidates import Candidates

#: Fan of the fallback candidates: speed factors x constant yaw rates (rad/s); the first pair is plain CV.
FAN_SPEED_FACTORS = (1.0, 0.5, 1.25, 0.0)
FAN_YAW_RATES_RPS = (0.0, -0.05, 0.05, -0.15, 0.15, -0.3, 0.3, -0.5)


def constant_velocity_candidates(
    scenario: Scenario, agent_index: int, n_candidates: int = 1, fallback: str | None = None
) -> Candidates:
    """Candidates from the agent's velocity ``(vx, vy)`` at `CURRENT_STEP`, held for the 8 s future.

    With ``n_candidates == 1`` this is the plain constant-velocity (CV) prediction. With more, candidate 0 is
    still CV and the others fan out over constant speed factors and constant yaw rates (`FAN_SPEED_FACTORS` x
    `FAN_YAW_RATES_RPS`, up to 32), with probabilities decaying away from CV, so a generator that expects a set
    of candidates still gets one.

    Args:
        scenario: the scenario.
        agent_index: row of the agent in ``scenario.tracks``; it must be valid at the current step.
        n_candidates: 1 to 32.
        fallback: recorded in `Candidates.fallback` (why CV was used instead of the network).
    """
    if not 0 <= agent_index < scenario.n_agents:
        raise ValueError(f"scenario {scenario.scenario_id!r}: agent index {agent_index} out of range")
    if not scenario.valid[agent_index, CURRENT_STEP]:
        raise ValueError(
            f"scenario {scenario.scenario_id!r}: agent {int(scenario.agent_ids[agent_index])} is not valid at the "
            f"current step {CURRENT_STEP}; no velocity to extrapolate"
        )
    grid = [(f, w) for f in FAN_SPEED_FACTORS for w in FAN_YAW_RATES_RPS]
    if not 1 <= n_candidates <= len(grid):
        raise ValueError(f"n_candidates must be in [1, {len(grid)}], got {n_candidates}")
    row = scenario.tracks[agent_index, CURRENT_STEP].astype(np.float64)
    start = row[[X, Y]]
    speed = float(np.hypot(row[VX], row[VY]))
    course = float(np.arctan2(row[VY], row[VX])) if speed > 1e-6 else float(row[HEADING])
    factor, yaw = (np.array(v, dtype=np.float64)[:n_candidates, None] for v in zip(*grid, strict=True))
    t = np.arange(1, N_FUTURE + 1) * DT_S  # [T]
    theta = course + yaw * t  # [K, T]
    step = speed * factor * DT_S
    xy = start + np.cumsum(np.stack([np.cos(theta), np.sin(theta)], axis=-1) * step[..., None], axis=1)
    # Plain CV must be exact: straight line from the velocity vector.
    xy[0] = start + np.stack([row[VX] * t, row[VY] * t], axis=-1)
    rank = np.arange(n_candidates, dtype=np.float64)
    probs = np.exp(-0.25 * rank)
    return Candidates.from_positions(
        xy, probs / probs.sum(), start, float(row[HEADING]), agent_index, fallback=fallback
    )
