"""Turn a candidate future (positions only) into a full ``[91, 8]`` track the env can replay.

History (steps ``0..CURRENT_STEP``) is the agent's log; the future (step ``CURRENT_STEP + 1 + j`` = candidate row
``j``) takes the candidate positions, with velocity from central finite differences (the logged current position
closes the gap at the join, so there is no velocity jump from the estimator) and heading along that velocity;
where the agent is (almost) still the heading is held. Length and width are the agent's at `CURRENT_STEP`.
A candidate shorter than the 80 future steps is extended at its last velocity (the agent must not vanish
mid-episode); a longer one is cut.
"""

from __future__ import annotations

import numpy as np

from seal.core.scenario import (
    CURRENT_STEP,
    DT_S,
    HEADING,
    LENGTH,
    N_FUTURE,
    N_STEPS,
    VALID,
    VX,
    VY,
    WIDTH,
    Scenario,
    X,
    Y,
)

STILL_MPS = 0.2
"""Below this finite-difference speed (m/s) the heading is held instead of following the (noisy) velocity."""


def candidate_track(scenario: Scenario, agent_index: int, future_xy: np.ndarray) -> np.ndarray:
    """``[N_STEPS, 8]`` float64 track: the agent's logged history followed by ``future_xy``.

    Args:
        scenario: the base scenario.
        agent_index: row of the agent in ``scenario.tracks``.
        future_xy: ``[T, 2]`` positions (m, world frame); row ``j`` is scenario step ``CURRENT_STEP + 1 + j``.
    """
    future_xy = np.asarray(future_xy, dtype=np.float64)
    if future_xy.ndim != 2 or future_xy.shape[1] != 2 or future_xy.shape[0] < 1:
        raise ValueError(f"candidate_track: future_xy must have shape [T>=1, 2], got {future_xy.shape}")
    log = scenario.tracks[agent_index].astype(np.float64)
    if log[CURRENT_STEP, VALID] < 0.5:
        raise ValueError(
            f"candidate_track: agent {int(scenario.agent_ids[agent_index])} of scenario {scenario.scenario_id!r} "
            f"is not valid at the current step {CURRENT_STEP}"
        )
    fut = future_xy[:N_FUTURE]
    if fut.shape[0] < N_FUTURE:
        prev = fut[-2] if fut.shape[0] >= 2 else log[CURRENT_STEP, [X, Y]]
        steps = np.arange(1, N_FUTURE - fut.shape[0] + 1)[:, None]
        fut = np.concatenate([fut, fut[-1] + steps * (fut[-1] - prev)])

    # Positions from the current step on: [81, 2]; central differences inside, one-sided at the end.
    pos = np.concatenate([log[CURRENT_STEP : CURRENT_STEP + 1, [X, Y]], fut])
    vel = np.empty_like(pos)
    vel[1:-1] = (pos[2:] - pos[:-2]) / (2 * DT_S)
    vel[-1] = (pos[-1] - pos[-2]) / DT_S
    vel = vel[1:]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    heading = np.arctan2(vel[:, 1], vel[:, 0])
    held = float(log[CURRENT_STEP, HEADING])
    for j in range(N_FUTURE):
        if speed[j] < STILL_MPS:
            heading[j] = held
        held = heading[j]

    track = np.zeros((N_STEPS, 8), dtype=np.float64)
    track[: CURRENT_STEP + 1] = log[: CURRENT_STEP + 1]
    future = track[CURRENT_STEP + 1 :]
    future[:, X], future[:, Y] = fut[:, 0], fut[:, 1]
    # Continuous with the logged current heading (no 2 pi jump at the join).
    future[:, HEADING] = np.unwrap(np.concatenate([[log[CURRENT_STEP, HEADING]], heading]))[1:]
    future[:, VX], future[:, VY] = speed * np.cos(heading), speed * np.sin(heading)
    future[:, LENGTH], future[:, WIDTH] = log[CURRENT_STEP, LENGTH], log[CURRENT_STEP, WIDTH]
    future[:, VALID] = 1.0
    return track
