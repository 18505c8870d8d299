"""Compiled lane geometry of base-scenario generation (`seal.envs.lane_kernels`) against the scalar Python it
replaced: the same floats, bit for bit (the generated data must not change)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from seal.envs.drivers import KP_HEADING_PER_S, KP_LATERAL_PER_S, MAX_STEERING_RAD, TAU_PURSUIT_S, Driver
from seal.envs.lane_kernels import closest_lanes, lane_distance, lane_local, py_hypot, steering_commands
from seal.envs.layouts import LAYOUTS, make_network, sample_params
from seal.envs.network_index import NetworkIndex, _lane_distance


def test_py_hypot_is_cpythons_hypot() -> None:
    rng = np.random.default_rng(0)
    for scale in (1e-3, 1.0, 30.0, 1e4):
        a, b = rng.normal(0, scale, 20_000), rng.normal(0, scale, 20_000)
        for other in (b, b * 1e-9):  # comparable sizes, and one much smaller
            for x, y in zip(a.tolist(), other.tolist(), strict=True):
                assert py_hypot(x, y) == math.hypot(x, y)
    # Decimal inputs give the hard cases (a result next to a representable number) where libm's hypot and a
    # plain sqrt(x^2 + y^2) round the other way.
    for x, y in zip(np.round(rng.normal(0, 3, 50_000), 1).tolist(), np.round(rng.normal(0, 3, 50_000), 2).tolist(),
                    strict=True):
        assert py_hypot(x, y) == math.hypot(x, y)
    for x, y in ((0.0, 0.0), (-0.0, 5.0), (3.0, -4.0), (1e-310, 1e-311), (1e300, 1e300), (math.inf, 1.0)):
        assert py_hypot(x, y) == math.hypot(x, y)
    assert math.isnan(py_hypot(math.nan, 1.0)) and py_hypot(math.inf, math.nan) == math.inf


@pytest.fixture(scope="module", params=LAYOUTS)
def index(request: pytest.FixtureRequest) -> NetworkIndex:
    layout = request.param
    return NetworkIndex(make_network(layout, sample_params(layout, np.random.default_rng(3))))


def _poses(index: NetworkIndex, rng: np.random.Generator, n: int) -> tuple[np.ndarray, ...]:
    """Poses near random lanes (some far off, to reach the search over every lane), and a current lane each."""
    rows = rng.integers(0, len(index.indices), n)
    x, y, h = np.empty(n), np.empty(n), np.empty(n)
    for k, r in enumerate(rows.tolist()):
        lane = index.lanes[index.indices[r]]
        s = rng.uniform(-3.0, lane.length + 3.0)
        x[k], y[k] = lane.position(s, rng.normal(0, 2.0 if k % 10 else 12.0))
        h[k] = lane.heading_at(s) + rng.normal(0, 0.3)
    return x, y, h, rng.integers(0, len(index.indices), n).astype(np.int64)


def test_lane_geometry_matches_the_scalar_lanes(index: NetworkIndex) -> None:
    x, y, h, _ = _poses(index, np.random.default_rng(1), 400)
    for k, i in enumerate(index.indices):
        lane = index.lanes[i]
        for px, py, ph in zip(x.tolist(), y.tolist(), h.tolist(), strict=True):
            assert lane_local(index.table[k], px, py) == lane.local(px, py)
            d = lane_distance(index.table[k], px, py, ph)
            assert d == _lane_distance(lane, px, py, ph) == lane.distance(px, py, ph)


def test_closest_lanes_match_the_scalar_search(index: NetworkIndex) -> None:
    x, y, h, cur = _poses(index, np.random.default_rng(2), 3000)
    got = closest_lanes(index.table, index.sib_ptr, index.sib, index.nxt_ptr, index.nxt, x, y, h, cur)
    ref = [index.row[index.closest_lane(px, py, ph, index.indices[c])]
           for px, py, ph, c in zip(x.tolist(), y.tolist(), h.tolist(), cur.tolist(), strict=True)]
    assert got.tolist() == ref
    assert (got != cur).any() and (got == cur).any()


def test_steering_commands_match_the_drivers_controller(index: NetworkIndex) -> None:
    rng = np.random.default_rng(4)
    x, y, h, target = _poses(index, rng, 2000)
    speed = np.where(rng.random(2000) < 0.1, rng.uniform(-0.02, 0.02, 2000), rng.uniform(0.0, 35.0, 2000))
    length = rng.uniform(4.0, 10.0, 2000)
    got = steering_commands(index.table, target, x, y, h, speed, length, TAU_PURSUIT_S, KP_LATERAL_PER_S,
                            KP_HEADING_PER_S, float(MAX_STEERING_RAD))
    road = SimpleNamespace(index=index)
    for k in range(2000):
        driver = SimpleNamespace(road=road, xy=[x[k], y[k]], speed=float(speed[k]), heading=float(h[k]),
                                 LENGTH=float(length[k]))
        assert got[k] == Driver._steering(driver, index.indices[target[k]])  # type: ignore[arg-type]
