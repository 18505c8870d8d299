"""Mode anchors from data: k-means over the control profiles (acceleration, yaw rate at the knots) of logged futures.

Controls are speed-independent in a way positions are not (a 0.3 rad/s turn is a turn at any speed), so one set
of anchors serves slow and fast agents alike.
"""

from __future__ import annotations

import numpy as np
import torch

from seal.core.scenario import DT_S
from seal.models.prior.kinematics import knot_matrix


def future_controls(
    future_xy: np.ndarray, start: np.ndarray, n_knots: int, min_speed_mps: float = 1.0
) -> np.ndarray:
    """Least-squares knot controls ``[N, 2, n_knots]`` (m/s^2, rad/s) of full futures.

    Args:
        future_xy: ``[N, T, 2]`` positions in each target's frame (m); the point before step 0 is the origin.
        start: ``[N, 2]`` initial speed (m/s) and direction of travel (rad).
        n_knots: knots of the profile.
        min_speed_mps: below this speed the direction of travel is noise; the yaw rate there counts as zero.
    """
    xy = np.asarray(future_xy, dtype=np.float64)
    prev = np.concatenate([np.zeros((xy.shape[0], 1, 2)), xy[:, :-1]], axis=1)
    delta = xy - prev
    speed = np.linalg.norm(delta, axis=-1) / DT_S  # [N, T]
    course = np.arctan2(delta[..., 1], delta[..., 0])
    speed_prev = np.concatenate([start[:, :1], speed[:, :-1]], axis=1)
    course_prev = np.concatenate([start[:, 1:2], course[:, :-1]], axis=1)
    acc = (speed - speed_prev) / DT_S
    turn = np.arctan2(np.sin(course - course_prev), np.cos(course - course_prev)) / DT_S
    yaw = np.where((speed > min_speed_mps) & (speed_prev > min_speed_mps), turn, 0.0)
    w = knot_matrix(n_knots, xy.shape[1]).double().numpy()  # [T, knots]
    pinv = np.linalg.pinv(w)  # [knots, T]
    return np.stack([acc @ pinv.T, yaw @ pinv.T], axis=1)


def _nearest(x: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Index of the nearest row of ``c`` for every row of ``x`` (squared distances by expansion: no [N, k, D])."""
    return ((c * c).sum(1)[None, :] - 2.0 * x @ c.T).argmin(1)


def kmeans(x: np.ndarray, k: int, seed: int, n_iter: int = 50) -> np.ndarray:
    """Lloyd's k-means with k-means++ seeding: ``k`` centres of the rows of ``x`` ``[N, D]`` (N >= k)."""
    if x.shape[0] < k:
        raise ValueError(f"kmeans: need at least {k} samples, got {x.shape[0]}")
    rng = np.random.default_rng(seed)
    centres = [x[rng.integers(x.shape[0])]]
    d2 = ((x - centres[0]) ** 2).sum(1)
    for _ in range(1, k):
        p = d2 / d2.sum() if d2.sum() > 0 else np.full(len(d2), 1.0 / len(d2))
        centres.append(x[rng.choice(x.shape[0], p=p)])
        d2 = np.minimum(d2, ((x - centres[-1]) ** 2).sum(1))
    c = np.stack(centres)
    for _ in range(n_iter):
        assign = _nearest(x, c)
        new = np.stack([x[assign == j].mean(0) if np.any(assign == j) else c[j] for j in range(k)])
        if np.allclose(new, c):
            break
        c = new
    return c


def fit_anchors(
    future_xy: torch.Tensor, future_valid: torch.Tensor, start: torch.Tensor, n_modes: int, n_knots: int,
    limits: tuple[float, float], seed: int = 0, max_samples: int = 20000, fill: torch.Tensor | None = None,
) -> torch.Tensor:
    """``[n_modes, 2, n_knots]`` anchors: k-means centres of the knot controls of the targets with a full future.

    Controls are clipped to the limits (acceleration m/s^2, yaw rate rad/s) and each channel is scaled by its
    limit for the clustering, so both count alike. With fewer than ``n_modes`` such targets (tiny data sets) the
    missing anchors are taken from ``fill`` (``[n_modes, 2, n_knots]``, e.g. `default_anchors`).
    """
    full = future_valid.all(dim=1).numpy()
    idx = np.flatnonzero(full)
    if idx.size < n_modes:
        if fill is None:
            raise ValueError(f"fit_anchors: {idx.size} targets with a full future, need {n_modes} or a fill")
        if idx.size == 0:
            return fill.clone()
        found = fit_anchors(
            future_xy[idx].repeat(n_modes, 1, 1), future_valid[idx].repeat(n_modes, 1),
            start[idx].repeat(n_modes, 1), idx.size, n_knots, limits, seed,
        )
        return torch.cat([found, fill[: n_modes - idx.size]])
    rng = np.random.default_rng(seed)
    if idx.size > max_samples:
        idx = np.sort(rng.choice(idx, max_samples, replace=False))
    ctrl = future_controls(future_xy[idx].numpy(), start[idx].numpy(), n_knots)  # [N, 2, knots]
    lim = np.array(limits, dtype=np.float64).reshape(1, 2, 1)
    scaled = np.clip(ctrl / lim, -0.95, 0.95).reshape(len(idx), -1)
    centres = kmeans(scaled, n_modes, seed).reshape(n_modes, 2, n_knots) * lim
    # Order by cluster size so anchor 0 is the most common behaviour (only cosmetic: modes are symmetric).
    assign = _nearest(scaled, (centres / lim).reshape(n_modes, -1))
    order = np.argsort(-np.bincount(assign, minlength=n_modes), kind="stable")
    return torch.from_numpy(centres[order]).float()
