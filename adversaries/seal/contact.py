"""Predicted collision / closest-approach step of one candidate adversary future against the past ego roll-outs
(SEAL switches to its skill policy a fixed offset before it, thesis 6.3.2).

Every step of the candidate is tested (not CAT's 0.5 s samples: the switch step should not be off by up to 4
steps): oriented boxes with the adversary's and the ego's length / width and the heading of the smoothed polyline
(`seal.adversaries.cat.select.smoothed_heading`, as CAT), `seal.core.geometry.obb_overlap` on ``[K, T]`` at once.
The
earliest step at which the boxes intersect in any roll-out is the predicted collision step; without any
intersection, the step of the smallest centre distance over the roll-outs is the closest approach.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.adversaries.cat.select import _fill_invalid, smoothed_heading
from seal.core.geometry import obb_overlap
from seal.core.scenario import CURRENT_STEP


@dataclass(frozen=True)
class ContactPrediction:
    """Outcome of `predict_contact`.

    Attributes:
        step: scenario step of the predicted collision (``collided``) or closest approach.
        collided: True when the candidate's box meets an ego box in at least one roll-out.
        rollout: index of the roll-out that gives ``step``.
        min_distance_m: smallest centre distance over all steps and roll-outs (m; inf when no step is comparable).
    """

    step: int
    collided: bool
    rollout: int
    min_distance_m: float


def predict_contact(
    cand_xy: np.ndarray,
    cand_heading: np.ndarray,
    adv_size_m: tuple[float, float],
    ego_xy: np.ndarray,
    ego_heading: np.ndarray,
    ego_valid: np.ndarray,
    ego_size_m: tuple[float, float],
) -> ContactPrediction:
    """Predicted collision / closest-approach step of one candidate (see the module docstring).

    Args:
        cand_xy: ``[T, 2]`` candidate positions (m); row ``j`` is scenario step ``CURRENT_STEP + 1 + j``.
        cand_heading: ``[T]`` candidate headings (rad), used where the candidate stands still.
        adv_size_m: adversary (length, width) in m.
        ego_xy: ``[K, T_e, 2]`` past ego roll-outs indexed by scenario step (row ``t`` = step ``t``).
        ego_heading: ``[K, T_e]`` their headings (rad).
        ego_valid: ``[K, T_e]`` bool.
        ego_size_m: ego (length, width) in m.
    """
    cand_xy = np.asarray(cand_xy, dtype=np.float64)
    ego_xy = np.asarray(ego_xy, dtype=np.float64)
    ego_valid = np.asarray(ego_valid, dtype=bool)
    if cand_xy.ndim != 2 or cand_xy.shape[1] != 2 or cand_xy.shape[0] == 0:
        raise ValueError(f"predict_contact: cand_xy must be [T>=1, 2], got {cand_xy.shape}")
    if ego_xy.ndim != 3 or ego_valid.shape != ego_xy.shape[:2] or ego_xy.shape[0] == 0:
        raise ValueError(f"predict_contact: ego_xy must be [K>=1, T, 2] with ego_valid [K, T], got {ego_xy.shape} "
                         f"and {ego_valid.shape}")
    n_fut = cand_xy.shape[0]
    n_ego = ego_valid.shape[1]
    rows = np.arange(n_fut)
    steps = CURRENT_STEP + 1 + rows
    ego_rows = np.minimum(steps, n_ego - 1)
    ok = ego_valid[:, ego_rows] & (steps < n_ego)[None]  # [K, T]
    c_h = smoothed_heading(cand_xy[None], np.asarray(cand_heading, dtype=np.float64)[None], rows)[0]  # [T]
    e_xy = _fill_invalid(ego_xy, ego_valid)[:, ego_rows]  # [K, T, 2]
    e_h = smoothed_heading(ego_xy, np.asarray(ego_heading, dtype=np.float64), ego_rows, valid=ego_valid)
    hit = obb_overlap(
        cand_xy[None, :, 0], cand_xy[None, :, 1], c_h[None], adv_size_m[0], adv_size_m[1],
        e_xy[..., 0], e_xy[..., 1], e_h, ego_size_m[0], ego_size_m[1],
    ) & ok  # [K, T]
    gap = cand_xy[None] - e_xy
    dist = np.where(ok, np.hypot(gap[..., 0], gap[..., 1]), np.inf)
    min_dist = float(dist.min())
    if hit.any():
        first = np.where(hit.any(1), hit.argmax(1), n_fut)
        k = int(np.argmin(first))
        return ContactPrediction(int(steps[first[k]]), True, k, min_dist)
    if not np.isfinite(min_dist):  # no comparable step: the last roll-out step is as good a guess as any
        return ContactPrediction(int(steps[-1]), False, 0, min_dist)
    rollout, j = np.unravel_index(int(np.argmin(dist)), dist.shape)
    return ContactPrediction(int(steps[j]), False, int(rollout), min_dist)
