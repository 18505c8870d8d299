"""How close agents come to each other in a logged scenario: body gaps (m) and collisions.

Gaps are between the agents' oriented boxes (0 = overlap = collision), not between centres, so "within 2 m"
means bodies within 2 m of each other whatever the vehicles' sizes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from seal.core.geometry import box_gap, boxes_overlap, track_corners
from seal.core.scenario import CURRENT_STEP, LENGTH, VALID, WIDTH, Scenario, X, Y


def pair_gaps(scenario: Scenario, agent_a: int, agent_b: int) -> np.ndarray:
    """``[T]`` body gap in metres between two agents (by id); NaN where either is invalid."""
    ta, tb = scenario.track(agent_a), scenario.track(agent_b)
    both = (ta[:, VALID] > 0.5) & (tb[:, VALID] > 0.5)
    gaps = box_gap(track_corners(ta), track_corners(tb))
    return np.where(both, gaps, np.nan)


@dataclass(frozen=True)
class PairProximity:
    """Closest approach of the (ego, adv) pair over the future steps (index >= CURRENT_STEP)."""

    min_gap_m: float
    min_gap_step: int
    collision: bool


def pair_proximity(scenario: Scenario) -> PairProximity:
    """Closest approach of the scenario's (ego, adv) pair from the current step on."""
    gaps = pair_gaps(scenario, scenario.ego_id, scenario.adv_id)[CURRENT_STEP:]
    if np.all(np.isnan(gaps)):
        return PairProximity(float("inf"), -1, False)
    k = int(np.nanargmin(gaps))
    return PairProximity(float(gaps[k]), CURRENT_STEP + k, bool(gaps[k] <= 0.0))


def any_collision(scenario: Scenario, within_m: float = 30.0) -> bool:
    """True if any two agents' boxes overlap at any step (pairs farther than ``within_m`` are skipped)."""
    tr = scenario.tracks
    valid = tr[:, :, VALID] > 0.5
    pos = tr[:, :, [X, Y]]
    # Candidate (a, b, t) triples: both valid and centres close enough that boxes could touch.
    dist = np.linalg.norm(pos[:, None] - pos[None, :], axis=-1)  # [A, A, T]
    reach = 0.5 * np.hypot(tr[:, :, LENGTH], tr[:, :, WIDTH])  # circumscribed radius [A, T]
    close = valid[:, None] & valid[None, :] & (dist <= np.minimum(reach[:, None] + reach[None, :], within_m))
    close &= np.triu(np.ones(close.shape[:2], dtype=bool), k=1)[:, :, None]
    a, b, t = np.nonzero(close)
    if a.size == 0:
        return False
    corners = track_corners(tr)
    return bool(boxes_overlap(corners[a, t], corners[b, t]).any())


def pool_proximity(scenarios: Sequence[Scenario]) -> dict[str, float]:
    """Shares of a pool whose (ego, adv) pair comes within 2 m / 5 m, collides, or has any collision."""
    if not scenarios:
        return {}
    prox = [pair_proximity(s) for s in scenarios]
    gaps = np.array([p.min_gap_m for p in prox])
    return {
        "pair_within_2m": float(np.mean(gaps <= 2.0)),
        "pair_within_5m": float(np.mean(gaps <= 5.0)),
        "pair_collision": float(np.mean([p.collision for p in prox])),
        "any_collision": float(np.mean([any_collision(s) for s in scenarios])),
        "pair_min_gap_m_median": float(np.median(gaps)),
    }
