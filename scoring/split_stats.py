"""Close calls of a split's interacting pairs, logged (GT) and counterfactual (AC), reported by `seal data split`.

* GT: the logged boxes of the ego and the adversary come within 2 m (body gap) or overlap, from the current step on.
* AC: the same, or either agent's future-extrapolated (FE) box against the other's logged box does: the pair is a
  close call in the logged future or in the asymmetric counterfactual, as the AC score takes the larger of the GT
  and the AS score.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from seal.core.geometry import box_corners, box_gap
from seal.core.scenario import CURRENT_STEP, Scenario
from seal.scoring.extrapolation import future_extrapolate
from seal.scoring.proximity import pair_gaps
from seal.scoring.scores import road_index
from seal.scoring.tracks import AgentTracks, from_tracks

CLOSE_CALL_M = 2.0
"""Body gap (m) at or below which a pair's approach is a close call."""


def _corners(tr: AgentTracks, row: int) -> np.ndarray:
    """``[T, 4, 2]`` box corners (m) of agent ``row``."""
    n_steps = tr.pos.shape[1]
    return box_corners(
        tr.pos[row, :, 0], tr.pos[row, :, 1], tr.heading[row],
        np.full(n_steps, tr.length[row]), np.full(n_steps, tr.width[row]),
    )


def counterfactual_gaps(scenario: Scenario) -> np.ndarray:
    """``[2, T - CURRENT_STEP]`` body gaps (m) of (ego FE vs adversary GT) and (adversary FE vs ego GT) from the
    current step on; NaN where either is invalid."""
    index = road_index(scenario.road)
    rows = [scenario.ego_index, scenario.adv_index]
    gt = from_tracks(scenario.tracks[rows], index)
    fe = future_extrapolate(gt, index)
    out = []
    for a, b in ((0, 1), (1, 0)):
        both = fe.valid[a] & gt.valid[b]
        out.append(np.where(both, box_gap(_corners(fe, a), _corners(gt, b)), np.nan)[CURRENT_STEP:])
    return np.stack(out)


def _min_gap(gaps: np.ndarray) -> float:
    return float(np.nanmin(gaps)) if np.isfinite(gaps).any() else float("inf")


def split_close_calls(scenarios: Sequence[Scenario]) -> dict[str, float]:
    """Shares of ``scenarios`` whose pair has a GT / AC close call (<= `CLOSE_CALL_M`) or collision (gap 0)."""
    if not scenarios:
        return {}
    gt_gap = np.array([_min_gap(pair_gaps(s, s.ego_id, s.adv_id)[CURRENT_STEP:]) for s in scenarios])
    cf_gap = np.array([_min_gap(counterfactual_gaps(s)) for s in scenarios])
    ac_gap = np.minimum(gt_gap, cf_gap)
    return {
        "gt_close_call": float(np.mean(gt_gap <= CLOSE_CALL_M)),
        "gt_collision": float(np.mean(gt_gap <= 0.0)),
        "ac_close_call": float(np.mean(ac_gap <= CLOSE_CALL_M)),
        "ac_collision": float(np.mean(ac_gap <= 0.0)),
    }
