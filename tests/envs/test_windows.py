"""Window selection: what counts as an interaction between two logged vehicles."""

from __future__ import annotations

import numpy as np
import pytest

from seal.core.interaction import SIDE_GAP_M
from seal.envs.traffic_run import RunLog
from seal.envs.windows import in_own_lanes, interaction_gap


def _log(*tracks: np.ndarray) -> RunLog:
    """RunLog of vehicles given as ``[T, 4]`` (x, y, heading, speed) arrays; 5 m x 2 m boxes."""
    states = np.stack([np.concatenate([t, np.tile([5.0, 2.0], (len(t), 1))], axis=1) for t in tracks])
    return RunLog(states=states, valid=np.ones(states.shape[:2], dtype=bool), kinds=["idm"] * len(tracks))


def _straight(x0: float, y: np.ndarray | float, heading: float = 0.0, speed: float = 20.0, n: int = 50):
    x = x0 + np.cos(heading) * speed * 0.1 * np.arange(n)
    y = np.broadcast_to(np.asarray(y, dtype=float), (n,)) + np.sin(heading) * speed * 0.1 * np.arange(n)
    return np.stack([x, y, np.full(n, heading), np.full(n, speed)], axis=1)


def test_overtaking_in_the_neighbouring_lane_is_not_an_interaction() -> None:
    # A car overtakes in the next 4 m lane (lateral body gap 4 - 2 = 2 m >= SIDE_GAP_M): approaching, alongside
    # and pulling away it stays in its own lane, although the bodies pass within 2 m.
    log = _log(_straight(0.0, 0.0, speed=20.0), _straight(-20.0, 4.0, speed=28.0))
    steps = np.arange(50)
    assert in_own_lanes(log, 0, 1, steps).all()
    assert np.isinf(interaction_gap(log, 0, 1, steps)).all()


def test_oncoming_car_in_its_own_lane_is_not_an_interaction() -> None:
    log = _log(_straight(0.0, 0.0, speed=10.0), _straight(100.0, 4.0, heading=np.pi, speed=10.0))
    assert in_own_lanes(log, 0, 1, np.arange(50)).all()
    # Drifting onto the centre line (lateral body gap 0.5 m) makes it one.
    drift = _log(_straight(0.0, 0.0, speed=10.0), _straight(100.0, 2.5, heading=np.pi, speed=10.0))
    assert not in_own_lanes(drift, 0, 1, np.arange(50)).any()


def test_a_lane_change_across_the_path_is_an_interaction() -> None:
    # The neighbour cuts in: its lateral offset shrinks from 4 m to 0 over 3 s, ending 6 m (1 m body gap) ahead.
    ego = _straight(0.0, 0.0, speed=20.0, n=31)
    cut = _straight(6.0, np.linspace(4.0, 0.0, 31), speed=20.0, n=31)
    log = _log(ego, cut)
    own = in_own_lanes(log, 0, 1, np.arange(31))
    lateral_body_gap = np.linspace(4.0, 0.0, 31) - 2.0
    np.testing.assert_array_equal(own, lateral_body_gap >= SIDE_GAP_M)
    np.testing.assert_allclose(interaction_gap(log, 0, 1, np.array([30])), 1.0, atol=1e-9)


@pytest.mark.parametrize("lateral_m", [2.0 + SIDE_GAP_M - 0.2, 2.5])
def test_close_lateral_gaps_and_following_are_interactions(lateral_m: float) -> None:
    # Abreast with a lateral body gap below SIDE_GAP_M (a sideswipe in the making): the gap counts.
    log = _log(_straight(0.0, 0.0), _straight(0.0, lateral_m))
    gap = interaction_gap(log, 0, 1, np.arange(5))
    np.testing.assert_allclose(gap, lateral_m - 2.0, atol=1e-9)
    # Following 3 m behind in the same lane: the longitudinal body gap counts.
    follow = _log(_straight(0.0, 0.0), _straight(8.0, 0.0))
    np.testing.assert_allclose(interaction_gap(follow, 0, 1, np.arange(5)), 3.0, atol=1e-9)


def test_own_lanes_rule_is_shared_and_the_alongside_condition_is_optional() -> None:
    from seal.core.interaction import in_own_lanes as core_rule

    # b is 2 m + 2 m (bodies) to the left of a, parallel: own lanes. 10 m ahead it still is, unless the
    # vehicles must also be alongside (lengths given, as the importers ask).
    a_xy, b_alongside, b_ahead = np.zeros(2), np.array([1.0, 4.0]), np.array([10.0, 4.0])
    w = np.asarray(2.0)
    assert core_rule(a_xy, 0.0, w, b_alongside, 0.0, w)
    assert core_rule(a_xy, 0.0, w, b_ahead, 0.0, w)
    lengths = (np.asarray(4.5), np.asarray(4.5))
    assert core_rule(a_xy, 0.0, w, b_alongside, 0.0, w, lengths_m=lengths)
    assert not core_rule(a_xy, 0.0, w, b_ahead, 0.0, w, lengths_m=lengths)
    # Crossing at 90 degrees is never "own lanes".
    assert not core_rule(a_xy, 0.0, w, b_alongside, np.pi / 2, w)
