"""SafeShift safety labels of agent behaviours (thesis 7.3.2, eq. 7.1).

``diff_i = GT_i - FE_i``: agent i's SafeShift trajectory score on its logged track (GT) minus the score on the
counterfactual where it proceeds passively (FE, `seal.scoring.extrapolation`). Positive = its active behaviour made
the scene more critical. Discretised with a threshold ``delta``::

    safe     if diff < -delta
    neutral  if |diff| <= delta
    unsafe   if diff > delta

`even_delta` picks ``delta`` so that the three classes are as even as the data allow (the thesis: "selected to
ensure roughly even class distributions").
"""

from __future__ import annotations

import numpy as np

SAFE, NEUTRAL, UNSAFE = 0, 1, 2
SAFETY_CLASSES = ("safe", "neutral", "unsafe")
"""Class names by label value."""


def safety_labels(diff: np.ndarray, delta: float) -> np.ndarray:
    """``[N]`` int64 labels (`SAFE`, `NEUTRAL`, `UNSAFE`) of the score differences ``diff [N]`` (eq. 7.1)."""
    if delta < 0:
        raise ValueError(f"safety_labels: delta must be >= 0, got {delta}")
    diff = np.asarray(diff, dtype=np.float64)
    return np.where(diff > delta, UNSAFE, np.where(diff < -delta, SAFE, NEUTRAL)).astype(np.int64)


def class_shares(labels: np.ndarray) -> np.ndarray:
    """``[3]`` share of each class in ``labels``."""
    labels = np.asarray(labels)
    return np.bincount(labels, minlength=len(SAFETY_CLASSES))[: len(SAFETY_CLASSES)] / max(labels.size, 1)


def even_delta(diff: np.ndarray) -> float:
    """The ``delta >= 0`` (one of the ``|diff|`` values, or 0) whose labels have the smallest largest deviation from
    a 1/3 share per class; ties go to the smaller ``delta``."""
    diff = np.asarray(diff, dtype=np.float64)
    if diff.size == 0:
        raise ValueError("even_delta: no score differences")
    candidates = np.unique(np.r_[0.0, np.abs(diff)])
    a = np.sort(np.abs(diff))
    neg = np.sort(diff[diff < 0])
    pos = np.sort(diff[diff > 0])
    n = diff.size
    # Counts for every candidate at once: neutral = |diff| <= d, safe = diff < -d, unsafe = diff > d.
    n_neutral = np.searchsorted(a, candidates, side="right")
    n_safe = np.searchsorted(neg, -candidates, side="left")
    n_unsafe = pos.size - np.searchsorted(pos, candidates, side="right")
    shares = np.stack([n_safe, n_neutral, n_unsafe], axis=1) / n
    worst = np.abs(shares - 1.0 / 3.0).max(axis=1)
    return float(candidates[int(np.argmin(worst))])
