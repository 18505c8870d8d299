"""Pair gaps and collisions on logged tracks, against hand-computed geometry."""

from __future__ import annotations

import numpy as np
import pytest

from seal.core.geometry import box_corners, box_gap, boxes_overlap
from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import N_STEPS, VALID, Scenario, X, Y
from seal.scoring.proximity import any_collision, pair_gaps, pair_proximity, pool_proximity


def _two_cars(x_adv: np.ndarray, y_adv: float = 0.0, third_overlaps: bool = False) -> Scenario:
    tr = np.zeros((3, N_STEPS, 8), np.float32)
    tr[:, :, 5:7] = (5.0, 2.0)
    tr[:, :, VALID] = 1.0
    tr[0, :, X] = 0.0
    tr[1, :, X] = x_adv
    tr[1, :, Y] = y_adv
    tr[2, :, X] = 100.0
    tr[2, :, Y] = 50.0
    if third_overlaps:
        tr[2, 80, X], tr[2, 80, Y] = 0.0, 1.0  # touches the ego at one step only
    lane = LaneSpec("l", np.array([[-50.0, 0.0], [200.0, 0.0]]), 4.0)
    return Scenario("p", tr, [1, 2, 3], ["vehicle"] * 3, 1, 2, RoadDescription("polylines", (lane,)))


def test_box_gap_analytic() -> None:
    a = box_corners(0.0, 0.0, 0.0, 5.0, 2.0)
    assert box_gap(a, box_corners(8.0, 0.0, 0.0, 5.0, 2.0)) == pytest.approx(3.0)  # 8 - 2.5 - 2.5
    assert box_gap(a, box_corners(0.0, 5.0, 0.0, 5.0, 2.0)) == pytest.approx(3.0)  # 5 - 1 - 1
    # Rotated 90 deg, 4 m ahead: its half-width 1 m faces the ego's front at 2.5 m -> 0.5 m gap.
    assert box_gap(a, box_corners(4.0, 0.0, np.pi / 2, 5.0, 2.0)) == pytest.approx(0.5)
    assert boxes_overlap(a, box_corners(4.0, 0.0, 0.3, 5.0, 2.0))
    assert box_gap(a, box_corners(4.0, 0.0, 0.3, 5.0, 2.0)) == 0.0


def test_pair_closest_approach_and_collision() -> None:
    x_adv = 30.0 - 0.5 * np.arange(N_STEPS)  # closes at 0.5 m per step, starts 30 m ahead
    s = _two_cars(x_adv, y_adv=3.0)  # passes 3 m to the side: gap 1 m at closest
    prox = pair_proximity(s)
    assert prox.min_gap_m == pytest.approx(1.0)
    assert not prox.collision
    # 25 m longitudinal (30 m - two half lengths) and 1 m lateral (3 m - two half widths) between corners.
    np.testing.assert_allclose(pair_gaps(s, 1, 2)[0], np.hypot(25.0, 1.0), atol=1e-5)
    crash = pair_proximity(_two_cars(x_adv, y_adv=0.0))
    assert crash.collision and crash.min_gap_m == 0.0
    assert crash.min_gap_step == 10 + int(np.ceil((25.0 - 10 * 0.5) / 0.5))  # first step the gap reaches 0


def test_any_collision_sees_background_pairs_and_invalid_steps() -> None:
    far = np.full(N_STEPS, 30.0)
    assert not any_collision(_two_cars(far))
    assert any_collision(_two_cars(far, third_overlaps=True))
    s = _two_cars(far, third_overlaps=True)
    tr = s.tracks.copy()
    tr[2, 75:, VALID] = 0.0  # the touching agent has left by then
    s2 = Scenario("p2", tr, s.agent_ids, s.agent_types, 1, 2, s.road)
    assert not any_collision(s2)


def test_pool_shares() -> None:
    pool = [_two_cars(np.full(N_STEPS, x)) for x in (6.0, 8.5, 20.0, 4.0)]  # gaps 1.0, 3.5, 15, 0 (overlap)
    shares = pool_proximity(pool)
    assert shares["pair_within_2m"] == pytest.approx(0.5)
    assert shares["pair_within_5m"] == pytest.approx(0.75)
    assert shares["pair_collision"] == pytest.approx(0.25)
