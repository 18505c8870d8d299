"""Importer building blocks: resampling to 10 Hz, lanes from bounds, width pieces, valid-block helpers."""

from __future__ import annotations

import numpy as np
import pytest
import shapely

from seal.core.importers.lane_index import LaneIndex
from seal.core.importers.lanes import (
    WIDTH_TOLERANCE_M,
    LaneGeometry,
    geometry_from_bounds,
    lane_pieces,
    link_successors,
    split_by_width,
)
from seal.core.importers.scenarionet import bridge_gaps
from seal.core.importers.tracks import resample_states
from seal.core.importers.windows import keep_one_block, run_ends, side_by_side
from seal.core.road import RoadDescription
from seal.core.scenario import HEADING, LENGTH, VALID, VX, VY, WIDTH, X, Y


@pytest.mark.parametrize("dt_s", [0.04, 0.05, 0.1, 0.2])
def test_resampling_reproduces_linear_motion_on_the_10hz_grid(dt_s: float) -> None:
    k = round(4.0 / dt_s) + 1  # 4 s of log starting at t = 0.3 s
    t = 0.3 + np.arange(k) * dt_s
    x, y = 5.0 + 12.0 * t, -2.0 + 1.5 * t
    g = resample_states(t, x, y, np.full(k, 0.12), np.full(k, 12.0), np.full(k, 1.5), 4.4, 1.8)
    assert g is not None and g.first == 3  # 0.3 s is grid step 3
    tn = (g.first + np.arange(len(g.rows))) * 0.1
    assert tn[-1] == pytest.approx(4.3)
    np.testing.assert_allclose(g.rows[:, X], 5.0 + 12.0 * tn, atol=1e-9)
    np.testing.assert_allclose(g.rows[:, Y], -2.0 + 1.5 * tn, atol=1e-9)
    np.testing.assert_allclose(g.rows[:, [HEADING, VX, VY, LENGTH, WIDTH, VALID]], [[0.12, 12.0, 1.5, 4.4, 1.8, 1.0]]
                               * len(tn), atol=1e-12)


def test_resampling_interpolates_headings_across_the_wrap() -> None:
    t = np.array([0.0, 0.2])
    g = resample_states(t, np.zeros(2), np.zeros(2), np.array([np.pi - 0.1, -np.pi + 0.1]), np.zeros(2),
                        np.zeros(2), 4.0, 2.0)
    assert abs(abs(g.rows[1, HEADING]) - np.pi) < 1e-9  # halfway is pi, not 0


def test_a_log_between_two_grid_points_gives_nothing() -> None:
    assert resample_states(np.array([0.11, 0.18]), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(2),
                           4.0, 2.0) is None


def test_centre_and_width_from_bounds_with_different_point_counts() -> None:
    left = np.array([[0.0, 3.0], [50.0, 3.0], [100.0, 3.0]])
    right = np.array([[0.0, 0.0], [100.0, 0.0]])
    g = geometry_from_bounds(left, right)
    np.testing.assert_allclose(g.centre[:, 1], 1.5)
    np.testing.assert_allclose(g.width, 3.0)
    assert g.centre[0, 0] == 0.0 and g.centre[-1, 0] == 100.0
    assert np.diff(g.centre[:, 0]).max() <= 2.0 + 1e-9  # densified every 2 m


def test_swapped_bounds_are_refused() -> None:
    with pytest.raises(ValueError, match="left border lies to the right"):
        geometry_from_bounds(np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[0.0, 3.0], [10.0, 3.0]]))


def test_a_tapering_lane_becomes_pieces_that_cover_it() -> None:
    # Right border widens the lane from 3.5 m to 5.5 m over 100 m.
    left = np.array([[0.0, 0.0], [100.0, 0.0]])
    right = np.array([[0.0, -3.5], [100.0, -5.5]])
    geom = geometry_from_bounds(left, right)
    pieces = lane_pieces("r", geom, ("striped", "continuous"), 25.0)
    assert len(pieces) >= 6  # 2 m of width change at most 0.3 m per piece
    assert [p.lane_id for p in pieces] == [f"r#{k}" for k in range(len(pieces))]
    assert all(p.successors == (q.lane_id,) for p, q in zip(pieces, pieces[1:], strict=False))
    widths = [p.width_m for p in pieces]
    assert widths == sorted(widths) and widths[-1] == pytest.approx(5.5, abs=1e-9)
    for a, b in split_by_width(geom.centre, geom.width):
        assert np.ptp(geom.width[a : b + 1]) <= WIDTH_TOLERANCE_M + 1e-9
    # Each piece is at least as wide as the recorded lane along it, so the pieces cover the lane (up to slivers
    # thinner than the 5 cm by which the env grows lane polygons before their union).
    cover = shapely.union_all([shapely.buffer(shapely.LineString(p.centerline), p.width_m / 2, cap_style="flat")
                               for p in pieces])
    lane = shapely.Polygon(np.vstack([left, right[::-1]]))
    assert shapely.difference(shapely.buffer(lane, -0.05), cover).area < 1e-6


def test_short_pieces_merge_and_tiny_lanes_vanish() -> None:
    centre = np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0]])
    assert split_by_width(centre, np.array([3.0, 4.0, 4.0])) == [(0, 2)]  # the 1 m piece joins the next
    assert lane_pieces("x", LaneGeometry(np.array([[0.0, 0.0], [0.5, 0.0]]), np.array([3.0, 3.0])),
                       ("none", "none"), 20.0) == []


def test_successors_link_last_piece_to_first_piece_and_drop_unknown() -> None:
    a = lane_pieces("a", geometry_from_bounds([[0, 3], [50, 3]], [[0, 0], [50, 0]]), ("none", "none"), 20.0)
    b = lane_pieces("b", geometry_from_bounds([[50, 3], [100, 3]], [[50, 0], [100, -2]]), ("none", "none"), 20.0)
    lanes = link_successors({"a": a, "b": b}, {"a": ["b", "ghost"]})
    assert lanes[len(a) - 1].successors == ("b#0",)
    road = RoadDescription("polylines", tuple(lanes))  # validates the successor ids
    index = LaneIndex(road)
    # Driving from a into b follows a successor; jumping sideways between the lanes of a 2-lane road does not.
    assert not index.changes_lane(np.array([[10.0, 1.5], [60.0, 1.0], [90.0, 0.0]]))


def test_lane_change_detection() -> None:
    lanes = [
        lane_pieces(str(i), geometry_from_bounds([[0, 3.5 * (i + 1)], [200, 3.5 * (i + 1)]],
                                                 [[0, 3.5 * i], [200, 3.5 * i]]), ("none", "none"), 20.0)[0]
        for i in range(2)
    ]
    index = LaneIndex(RoadDescription("polylines", tuple(lanes)))
    np.testing.assert_array_equal(index.nearest(np.array([[10.0, 1.0], [10.0, 5.0], [150.0, 2.0]])), [0, 1, 0])
    assert index.changes_lane(np.array([[10.0, 1.75], [50.0, 3.0], [90.0, 5.25]]))
    assert not index.changes_lane(np.array([[10.0, 1.75], [90.0, 1.5]]))


def test_valid_block_helpers() -> None:
    valid = np.array([[0, 1, 1, 0, 1, 1, 1, 0], [1, 1, 1, 1, 1, 1, 1, 1]], dtype=bool)
    np.testing.assert_array_equal(run_ends(valid)[0], [-1, 2, 2, -1, 6, 6, 6, -1])
    np.testing.assert_array_equal(run_ends(valid)[1], [7] * 8)
    np.testing.assert_array_equal(keep_one_block(valid[0], prefer=1), [0, 1, 1, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(keep_one_block(valid[0], prefer=0), [0, 0, 0, 0, 1, 1, 1, 0])  # the longest
    np.testing.assert_array_equal(bridge_gaps(np.array([1, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1], bool), max_steps=2),
                                  [1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1])


def test_side_by_side_is_not_an_interaction_but_a_cut_in_is() -> None:
    def track(xs: list[float], ys: list[float], h: float = 0.0) -> np.ndarray:
        t = np.zeros((len(xs), 8))
        t[:, X], t[:, Y], t[:, HEADING], t[:, LENGTH], t[:, WIDTH], t[:, VALID] = xs, ys, h, 4.5, 1.8, 1
        return t

    ego = track([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    beside = track([1.0, 1.0, 1.0], [3.6, 3.6, 3.6])  # 1.8 m lateral body gap
    close = track([1.0, 1.0, 1.0], [2.4, 2.4, 2.4])  # 0.6 m: squeezing in
    ahead = track([6.0, 6.0, 6.0], [0.0, 0.0, 0.0])  # same lane, not alongside
    assert side_by_side(ego, beside).all()
    assert not side_by_side(ego, close).any() and not side_by_side(ego, ahead).any()
