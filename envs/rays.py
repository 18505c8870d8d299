"""Vectorised 2-D ray casting against line segments (no per-ray Python loops).

All rays start at one origin; segments are given relative to that origin as start point ``a`` and edge
vector ``e = b - a``. A ray ``t * d`` (t >= 0, unit d) hits a segment ``a + u * e`` (0 <= u <= 1) at
``t = (a x e) / (d x e)``, ``u = (a x d) / (d x e)`` (2-D cross products).
"""

from __future__ import annotations

import numpy as np


def ray_angles(n: int) -> np.ndarray:
    """Angles ``[n]`` (rad) of ``n`` rays spread over 360 deg, ray 0 straight ahead, counter-clockwise."""
    return 2.0 * np.pi * np.arange(n) / n


def cast_rays(
    dx: np.ndarray, dy: np.ndarray, ax: np.ndarray, ay: np.ndarray, ex: np.ndarray, ey: np.ndarray,
    max_range: float,
) -> np.ndarray:
    """Distance (m) along each ray to the first segment hit, ``max_range`` when nothing is hit within it.

    Args:
        dx, dy: ``[K]`` unit ray directions (world frame).
        ax, ay: ``[M]`` segment starts relative to the ray origin (m).
        ex, ey: ``[M]`` segment vectors (m).
        max_range: sensor range (m).

    Returns:
        ``[K]`` float64 distances in ``[0, max_range]``.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return _cast(dx, dy, ax, ay, ex, ey, max_range)


def _cast(
    dx: np.ndarray, dy: np.ndarray, ax: np.ndarray, ay: np.ndarray, ex: np.ndarray, ey: np.ndarray,
    max_range: float,
) -> np.ndarray:
    """`cast_rays` without its ``np.errstate`` (the caller silences division warnings: parallel rays divide by
    zero, giving inf / nan that the hit test rejects)."""
    if ax.shape[0] == 0:
        return np.full(dx.shape[0], max_range)
    denom = np.multiply.outer(dx, ey) - np.multiply.outer(dy, ex)  # [K, M]
    inv = 1.0 / denom
    t = (ax * ey - ay * ex) * inv
    u = (np.multiply.outer(dy, ax) - np.multiply.outer(dx, ay)) * inv
    hit = (t >= 0.0) & (u >= 0.0) & (u <= 1.0)
    return np.minimum(np.where(hit, t, max_range).min(axis=1), max_range)
