"""SEAL criticality measures (thesis eq. 6.1, 6.2) on plain arrays, vectorised over any leading batch axes.

Both map to [0, 1], 1 = most critical; ``b`` (m) sets the distance scale (the thesis uses 8):

* ``f_coll = exp(-min_t ||ego_t - adv_t|| / b)`` — closeness of ego and adversary over a roll-out (1 on a crash);
* ``f_diff = 1 - exp(-sum_t ||ego_prev_t - ego_t|| / b)`` — how much the ego's roll-out changed from the previous
  one.

Positions are centre positions ``[..., T, 2]`` (m); batches broadcast, e.g. ego roll-outs ``[K, 1, T, 2]``
against candidate adversaries ``[1, C, T, 2]`` give ``[K, C]``.
"""

from __future__ import annotations

import numpy as np

B_M = 8.0


def _valid(valid: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    return np.ones(shape, dtype=bool) if valid is None else np.broadcast_to(np.asarray(valid, dtype=bool), shape)


def f_coll(
    ego_xy: np.ndarray, adv_xy: np.ndarray, b: float = B_M, crashed: np.ndarray | None = None,
    valid: np.ndarray | None = None,
) -> np.ndarray:
    """Collision closeness ``[...]``: ``exp(-min_t dist / b)``, 1 where ``crashed``; steps where ``valid
    [..., T]`` is False are ignored (none valid -> 0)."""
    diff = np.asarray(ego_xy, dtype=np.float64) - np.asarray(adv_xy, dtype=np.float64)
    dist = np.hypot(diff[..., 0], diff[..., 1])
    dist = np.where(_valid(valid, dist.shape), dist, np.inf)
    out = np.exp(-dist.min(axis=-1) / b)
    if crashed is not None:
        out = np.where(np.asarray(crashed, dtype=bool), 1.0, out)
    return out


def f_diff(ego_prev_xy: np.ndarray, ego_xy: np.ndarray, b: float = B_M, valid: np.ndarray | None = None) -> np.ndarray:
    """Behaviour change ``[...]``: ``1 - exp(-sum_t ||ego_prev_t - ego_t|| / b)`` over valid steps."""
    diff = np.asarray(ego_prev_xy, dtype=np.float64) - np.asarray(ego_xy, dtype=np.float64)
    dist = np.hypot(diff[..., 0], diff[..., 1])
    dist = np.where(_valid(valid, dist.shape), dist, 0.0)
    return 1.0 - np.exp(-dist.sum(axis=-1) / b)
