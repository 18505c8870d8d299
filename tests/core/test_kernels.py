"""Compiled per-step geometry (`seal.core.kernels`) against the numpy reference (`tests/kernel_reference.py`): the
box collision test and the route projection."""

from __future__ import annotations

import math

import numpy as np
import pytest
from kernel_reference import reference_box_hits, reference_projection

from seal.core.kernels import box_hits_rows, closest_segment
from seal.envs.kinematics import AgentState
from seal.envs.route import Route


def test_box_hits_equal_the_numpy_separating_axis_test() -> None:
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(300):
        n = int(rng.integers(0, 12))
        cur = np.zeros((n, 8))
        cur[:, :2] = rng.uniform(-8.0, 8.0, (n, 2))
        cur[:, 2] = rng.uniform(-math.pi, math.pi, n)
        cur[:, 5] = rng.uniform(3.0, 12.0, n)
        cur[:, 6] = rng.uniform(1.5, 2.6, n)
        cur[:, 7] = 1.0
        state = AgentState(float(rng.uniform(-2, 2)), float(rng.uniform(-2, 2)), float(rng.uniform(-3, 3)), 10.0,
                           float(rng.uniform(3.0, 6.0)), float(rng.uniform(1.5, 2.2)))
        idx = np.flatnonzero(rng.random(n) < 0.8)
        got = box_hits_rows(state.x, state.y, state.heading, state.length, state.width, cur, idx)
        np.testing.assert_array_equal(got, reference_box_hits(state, cur, idx))
        hits += got.size
    assert hits > 100  # the random layouts do overlap often


def test_touching_boxes_overlap_and_apart_ones_do_not() -> None:
    cur = np.array([[5.0, 0.0, 0.0, 0, 0, 5.0, 2.0, 1.0], [5.0001, 0.0, 0.0, 0, 0, 5.0, 2.0, 1.0],
                    [0.0, 2.0, 0.0, 0, 0, 5.0, 2.0, 1.0]])
    got = box_hits_rows(0.0, 0.0, 0.0, 5.0, 2.0, cur, np.arange(3))
    assert got.tolist() == [0, 2]  # nose to tail and side by side touch; 0.1 mm apart does not


def test_route_projection_equals_the_numpy_reference() -> None:
    rng = np.random.default_rng(1)
    pts = np.cumsum(rng.normal(0.0, 3.0, (60, 2)) + [3.0, 0.5], axis=0)
    route = Route(pts, speeds=np.full(60, 8.0))
    for _ in range(500):
        x, y = pts[rng.integers(60)] + rng.normal(0.0, 5.0, 2)
        hint = None if rng.random() < 0.3 else int(rng.integers(route.n_segments))
        p = route.project(float(x), float(y), hint)
        seg, s, lateral = reference_projection(route, float(x), float(y), hint)
        assert p.segment == seg
        assert p.s == pytest.approx(s, abs=1e-9)
        assert p.lateral == lateral
    k, t, cross = closest_segment(route._cols, route._len2, 1e6, 0.0, 0, route.n_segments)
    assert 0 <= k < route.n_segments and 0.0 <= t <= 1.0 and math.isfinite(cross)
