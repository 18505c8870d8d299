"""CAT's candidate selection (`ARCHITECTURE.md`), vectorised over candidates x roll-outs x sub-sampled times.

* P1: softmax of the mode scores with modes 7..32 (1-based, by rank) flattened to the 7th score; when only
  probabilities are known their logs are the scores.
* Both the candidate futures and the past ego roll-outs are sub-sampled every ``stride`` steps (0.5 s): samples
  ``k = 0..S-1`` sit at scenario steps ``CURRENT_STEP + stride * (k + 1)``. Oriented boxes take the adversary's and
  the ego's length / width and the heading of the smoothed polyline (the chord over +-`HALF_WINDOW` steps).
* Walking forward, an uncertainty factor is multiplied by ``decay`` (0.99) per sample; the first sample ``k``
  where the boxes intersect gives ``P3 = decay ** (k + 1)``, no intersection gives 0.
* The box test is `seal.core.geometry.obb_overlap` on ``[C, K, S]`` at once (32 x 5 x 16 pairs: ~0.3 ms).
* ``score_j = sum_i P1_j P3_ij`` over the K roll-outs; the argmax wins. When nothing collides the candidate with
  the smallest centre distance (over sub-sampled times and roll-outs) is taken.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.core.geometry import obb_overlap
from seal.core.scenario import CURRENT_STEP

STRIDE_STEPS = 5
DECAY = 0.99
N_KEPT_MODES = 7
HALF_WINDOW = 2
"""Half width (steps) of the chord that gives a polyline's smoothed heading."""
MIN_CHORD_M = 0.2
"""Shorter chords (a still vehicle) keep the given heading instead."""


@dataclass(frozen=True)
class CATSelection:
    """Outcome of `cat_select`.

    Attributes:
        index: chosen candidate.
        collided: True when the chosen candidate hits at least one roll-out (else it is the closest-distance
            fallback).
        predicted_step: scenario step of the chosen candidate's earliest predicted collision over the roll-outs,
            or of its closest approach in the fallback.
        scores: ``[C]`` ``sum_i P1_j P3_ij``.
        p1: ``[C]`` flattened prior.
        p3: ``[C, K]`` first-collision factors.
        first_hit: ``[C, K]`` first colliding sample index, -1 for none.
        min_distance_m: ``[C]`` smallest centre distance over sub-sampled times and roll-outs (inf if no sample of
            any roll-out is valid).
        sample_steps: ``[S]`` scenario steps of the samples.
    """

    index: int
    collided: bool
    predicted_step: int
    scores: np.ndarray
    p1: np.ndarray
    p3: np.ndarray
    first_hit: np.ndarray
    min_distance_m: np.ndarray
    sample_steps: np.ndarray


def flattened_prior(probs: np.ndarray, n_kept: int = N_KEPT_MODES, logits: np.ndarray | None = None) -> np.ndarray:
    """CAT's P1 ``[C]``: softmax of the scores where every mode ranked below ``n_kept`` gets the score of the
    ``n_kept``-th mode (1-based). Scores are ``logits`` when given, else ``log(probs)``; ranks follow the scores."""
    scores = np.log(np.maximum(np.asarray(probs, dtype=np.float64), 1e-300)) if logits is None else (
        np.asarray(logits, dtype=np.float64)
    )
    order = np.argsort(-scores, kind="stable")
    if scores.size > n_kept:
        scores = scores.copy()
        scores[order[n_kept:]] = scores[order[n_kept - 1]]
    e = np.exp(scores - scores.max())
    return e / e.sum()


def _fill_invalid(xy: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Copy of ``xy [N, T, 2]`` whose invalid rows repeat the nearest valid row (earlier first)."""
    t = np.arange(valid.shape[-1])
    last = np.maximum.accumulate(np.where(valid, t, -1), axis=-1)
    nxt = np.minimum.accumulate(np.where(valid, t, t.size)[..., ::-1], axis=-1)[..., ::-1]
    src = np.where(last >= 0, last, np.minimum(nxt, t.size - 1))
    return np.take_along_axis(xy, src[..., None], axis=-2)


def smoothed_heading(
    xy: np.ndarray, heading: np.ndarray, rows: np.ndarray, valid: np.ndarray | None = None,
    half_window: int = HALF_WINDOW, min_chord_m: float = MIN_CHORD_M,
) -> np.ndarray:
    """Heading ``[N, len(rows)]`` of the polylines ``xy [N, T, 2]`` at ``rows``: the direction of the chord from
    row ``r - half_window`` to ``r + half_window`` (clipped to the track, invalid rows filled from the nearest
    valid one); ``heading [N, T]`` where the chord is shorter than ``min_chord_m``."""
    if valid is not None:
        xy = _fill_invalid(xy, valid)
    n_rows = xy.shape[-2]
    lo = np.clip(rows - half_window, 0, n_rows - 1)
    hi = np.clip(rows + half_window, 0, n_rows - 1)
    chord = xy[:, hi] - xy[:, lo]
    fallback = heading[:, np.clip(rows, 0, n_rows - 1)]
    long_enough = np.hypot(chord[..., 0], chord[..., 1]) >= min_chord_m
    return np.where(long_enough, np.arctan2(chord[..., 1], chord[..., 0]), fallback)


def cat_select(
    cand_xy: np.ndarray,
    cand_heading: np.ndarray,
    probs: np.ndarray,
    adv_size_m: tuple[float, float],
    ego_xy: np.ndarray,
    ego_heading: np.ndarray,
    ego_valid: np.ndarray,
    ego_size_m: tuple[float, float],
    stride: int = STRIDE_STEPS,
    decay: float = DECAY,
    n_kept: int = N_KEPT_MODES,
    logits: np.ndarray | None = None,
) -> CATSelection:
    """Pick the adversary candidate CAT's way (see the module docstring).

    Args:
        cand_xy: ``[C, T, 2]`` candidate positions (m); row ``j`` is scenario step ``CURRENT_STEP + 1 + j``.
        cand_heading: ``[C, T]`` candidate headings (rad), used where a candidate stands still.
        probs: ``[C]`` candidate probabilities (or pass ``logits``).
        adv_size_m: adversary (length, width).
        ego_xy: ``[K, T_e, 2]`` past ego roll-outs indexed by scenario step (row ``t`` = step ``t``).
        ego_heading: ``[K, T_e]`` their headings (rad).
        ego_valid: ``[K, T_e]`` bool.
        ego_size_m: ego (length, width).
        stride: sub-sampling step (5 = 0.5 s).
        decay: uncertainty factor per sample (0.99).
        n_kept: modes ranked below this share its score (7).
        logits: ``[C]`` mode scores, when the prior provides them.
    """
    cand_xy = np.asarray(cand_xy, dtype=np.float64)
    ego_xy = np.asarray(ego_xy, dtype=np.float64)
    ego_valid = np.asarray(ego_valid, dtype=bool)
    n_cand, n_fut = cand_xy.shape[:2]
    n_roll, n_ego = ego_valid.shape
    if n_cand == 0 or n_roll == 0:
        raise ValueError(f"cat_select needs candidates and roll-outs, got {n_cand} candidates and {n_roll} roll-outs")
    n_samples = n_fut // stride
    cand_rows = stride * (1 + np.arange(n_samples)) - 1
    steps = CURRENT_STEP + 1 + cand_rows
    ego_rows = np.minimum(steps, n_ego - 1)
    ego_ok = ego_valid[:, ego_rows] & (steps < n_ego)[None]  # [K, S]

    c_xy = cand_xy[:, cand_rows]  # [C, S, 2]
    c_h = smoothed_heading(cand_xy, np.asarray(cand_heading, dtype=np.float64), cand_rows)
    e_xy = _fill_invalid(ego_xy, ego_valid)[:, ego_rows]  # [K, S, 2]
    e_h = smoothed_heading(ego_xy, np.asarray(ego_heading, dtype=np.float64), ego_rows, valid=ego_valid)

    hit = obb_overlap(
        c_xy[:, None, :, 0], c_xy[:, None, :, 1], c_h[:, None], adv_size_m[0], adv_size_m[1],
        e_xy[None, :, :, 0], e_xy[None, :, :, 1], e_h[None], ego_size_m[0], ego_size_m[1],
    ) & ego_ok[None]  # [C, K, S]
    any_hit = hit.any(-1)
    first_hit = np.where(any_hit, hit.argmax(-1), -1)
    p3 = np.where(any_hit, decay ** (first_hit + 1.0), 0.0)
    p1 = flattened_prior(probs, n_kept, logits)
    scores = (p1[:, None] * p3).sum(-1)

    gap = c_xy[:, None] - e_xy[None]  # [C, K, S, 2]
    dist = np.where(ego_ok[None], np.hypot(gap[..., 0], gap[..., 1]), np.inf)
    min_dist = dist.min(axis=(1, 2))
    index, k, collided = _choose(scores, p3, first_hit, any_hit, dist, min_dist)
    return CATSelection(
        index=index,
        collided=collided,
        predicted_step=int(steps[k]),
        scores=scores,
        p1=p1,
        p3=p3,
        first_hit=first_hit,
        min_distance_m=min_dist,
        sample_steps=steps,
    )


def _choose(
    scores: np.ndarray, p3: np.ndarray, first_hit: np.ndarray, any_hit: np.ndarray, dist: np.ndarray,
    min_dist: np.ndarray,
) -> tuple[int, int, bool]:
    """(chosen candidate, its predicted sample, collided): the best-scoring colliding candidate at its first hit,
    or, when none collides, the one coming closest at its closest sample. Shapes as in `cat_select`
    (``scores [C]``, ``p3 / any_hit [C, K]``, ``first_hit [C, K]``, ``dist [C, K, S]``, ``min_dist [C]``)."""
    if any_hit.any():
        # A colliding candidate whose P1 underflowed to 0 still beats every non-colliding one.
        index = int(np.argmax(scores)) if scores.max() > 0 else int(np.argmax(p3.sum(-1)))
        return index, int(first_hit[index][any_hit[index]].min()), True
    index = int(np.argmin(min_dist))
    return index, int(np.unravel_index(np.argmin(dist[index]), dist[index].shape)[1]), False
