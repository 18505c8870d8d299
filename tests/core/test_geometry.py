"""The geometry mechanisms of `seal.core.geometry`: each fast path agrees bit for bit with the general form."""

from __future__ import annotations

import math

import numpy as np

from seal.core.geometry import (
    box_corners,
    boxes_overlap,
    corners_xy,
    obb_overlap,
    overlaps_one,
    pairwise_overlaps,
    track_corners,
    wrap_angle,
    wrap_angle_f,
)


def _boxes(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    boxes = np.zeros((n, 8))
    boxes[:, :2] = rng.uniform(0, 15, (n, 2))
    boxes[:, 2] = rng.uniform(-np.pi, np.pi, n)
    boxes[:, 5] = rng.uniform(3, 8, n)
    boxes[:, 6] = rng.uniform(1.5, 2.5, n)
    boxes[:, 7] = 1.0
    return boxes


def test_scalar_corners_are_bit_identical_to_box_corners() -> None:
    boxes = _boxes(50)
    full = track_corners(boxes)
    for i, b in enumerate(boxes):
        cx, cy = corners_xy(b[0], b[1], b[2], b[5], b[6])
        assert np.array_equal(full[i, :, 0], cx) and np.array_equal(full[i, :, 1], cy)
    assert np.array_equal(full, box_corners(boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 5], boxes[:, 6]))


def test_every_overlap_form_agrees() -> None:
    boxes = _boxes(40, seed=1)
    pair = pairwise_overlaps(boxes)
    assert pair.any() and not pair.all() and np.array_equal(pair, pair.T) and not pair.diagonal().any()
    corners = track_corners(boxes)
    for i, b in enumerate(boxes):
        one = overlaps_one(b[0], b[1], b[2], b[5], b[6], boxes)
        centre = obb_overlap(*b[[0, 1, 2, 5, 6]], *boxes[:, [0, 1, 2, 5, 6]].T)
        by_corners = boxes_overlap(corners[i][None], corners)
        assert one[i] and centre[i] and by_corners[i]  # a box overlaps itself
        one[i] = centre[i] = by_corners[i] = False
        assert np.array_equal(one, pair[i]) and np.array_equal(centre, pair[i]) and np.array_equal(by_corners, pair[i])


def test_scalar_wrap_angle_is_bit_identical() -> None:
    angles = np.random.default_rng(2).uniform(-20.0, 20.0, 1000).tolist() + [math.pi, -math.pi, 0.0, 3 * math.pi]
    for a in angles:
        w = wrap_angle_f(a)
        assert w == float(wrap_angle(a)) and -math.pi <= w < math.pi
