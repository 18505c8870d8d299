"""Vectorised oriented-box geometry shared by the env (collisions), traffic generation and scoring.

A box is ``(x, y, heading, length, width)`` in metres / radians; every function broadcasts over leading axes.
"""

from __future__ import annotations

import numpy as np

# Corner order: front-left, front-right, rear-right, rear-left (counter-clockwise would be FL, RL, RR, FR;
# any consistent cyclic order works for the edge-based tests below).
_CORNER_SIGNS = np.array([[0.5, 0.5], [0.5, -0.5], [-0.5, -0.5], [-0.5, 0.5]])


def box_corners(x: np.ndarray, y: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray) -> np.ndarray:
    """Corners ``[..., 4, 2]`` (m) of oriented boxes centred at (x, y)."""
    x, y, heading, length, width = np.broadcast_arrays(
        *(np.asarray(v, dtype=np.float64) for v in (x, y, heading, length, width))
    )
    c, s = np.cos(heading)[..., None], np.sin(heading)[..., None]
    dl = _CORNER_SIGNS[:, 0] * length[..., None]  # [..., 4] along heading
    dw = _CORNER_SIGNS[:, 1] * width[..., None]  # [..., 4] to the left
    cx = x[..., None] + dl * c - dw * s
    cy = y[..., None] + dl * s + dw * c
    return np.stack([cx, cy], axis=-1)


def boxes_overlap(corners_a: np.ndarray, corners_b: np.ndarray) -> np.ndarray:
    """Separating-axis test for two broadcastable sets of rectangles ``[..., 4, 2]`` -> bool ``[...]``."""
    a = np.asarray(corners_a, dtype=np.float64)
    b = np.asarray(corners_b, dtype=np.float64)
    a, b = np.broadcast_arrays(a, b)
    # Rectangles: two edge normals each are enough.
    axes = np.concatenate([a[..., 1:3, :] - a[..., 0:2, :], b[..., 1:3, :] - b[..., 0:2, :]], axis=-2)  # [...,4,2]
    proj_a = np.einsum("...kd,...cd->...kc", axes, a)  # [..., 4 axes, 4 corners]
    proj_b = np.einsum("...kd,...cd->...kc", axes, b)
    separated = (proj_a.max(-1) < proj_b.min(-1)) | (proj_b.max(-1) < proj_a.min(-1))
    return ~separated.any(-1)


def _point_segment_distance(p: np.ndarray, s0: np.ndarray, s1: np.ndarray) -> np.ndarray:
    """Distance from points ``[..., 2]`` to segments ``[..., 2]``-``[..., 2]`` (broadcast)."""
    d = s1 - s0
    denom = np.maximum((d * d).sum(-1), 1e-12)
    t = np.clip(((p - s0) * d).sum(-1) / denom, 0.0, 1.0)
    proj = s0 + t[..., None] * d
    return np.linalg.norm(p - proj, axis=-1)


def box_gap(corners_a: np.ndarray, corners_b: np.ndarray) -> np.ndarray:
    """Smallest distance (m) between two sets of rectangles ``[..., 4, 2]``; 0 where they overlap."""
    a = np.asarray(corners_a, dtype=np.float64)
    b = np.asarray(corners_b, dtype=np.float64)
    a, b = np.broadcast_arrays(a, b)
    a_next = np.roll(a, -1, axis=-2)
    b_next = np.roll(b, -1, axis=-2)
    # Each corner of a against each edge of b and vice versa: [..., 4 corners, 4 edges].
    d_ab = _point_segment_distance(a[..., :, None, :], b[..., None, :, :], b_next[..., None, :, :])
    d_ba = _point_segment_distance(b[..., :, None, :], a[..., None, :, :], a_next[..., None, :, :])
    gap = np.minimum(d_ab.min(axis=(-1, -2)), d_ba.min(axis=(-1, -2)))
    return np.where(boxes_overlap(a, b), 0.0, gap)


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Wrap radians to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi
