"""Route projection and completion, road geometry helpers, the rendering network."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scenario_factory as sf
from highway_env.road.lane import LineType

from seal.core.scenario import CURRENT_STEP
from seal.envs.road_geometry import RoadGeometry, box_segment_hits, get_road_geometry
from seal.envs.road_network import build_road_network
from seal.envs.route import MIN_ROUTE_M, Route


def test_projection_and_completion() -> None:
    route = Route(np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [20.0, 10.0]]), start_index=1)
    assert route.length == pytest.approx(30.0) and route.start_s == pytest.approx(10.0)
    p = route.project(15.0, 2.0)
    assert (p.s, p.lateral, p.heading) == pytest.approx((15.0, 2.0, 0.0))
    assert route.completion(p.s) == pytest.approx(0.25)
    p = route.project(18.0, 5.0, hint=p.segment)  # closer to the last leg (going +y), left of it
    assert (p.s, p.lateral, p.heading) == pytest.approx((25.0, 2.0, math.pi / 2))
    # Beyond the end the straight extension continues: completion above 1.
    p = route.project(20.0, 15.0)
    assert route.completion(p.s) == pytest.approx(1.25)
    assert route.point_at(35.0) == pytest.approx((20.0, 15.0))
    assert route.point_at(-5.0) == pytest.approx((-5.0, 0.0))


def test_stationary_route_is_extended() -> None:
    route = Route(np.zeros((5, 2)), speeds=np.zeros(5))
    assert route.length == pytest.approx(MIN_ROUTE_M)


def test_route_from_track_skips_invalid_steps(lane_change) -> None:
    track = lane_change.track(2)  # valid from step 20
    route = Route.from_track(track, CURRENT_STEP)
    assert route.points[0] == pytest.approx(track[20, :2])
    assert route.speed_at(0.0) == pytest.approx(np.hypot(*track[20, 3:5]))


def test_hint_keeps_projection_on_the_right_leg() -> None:
    """An out-and-back route: 60 m out along y = 0, back along y = 2 (1 m segments, so the legs lie more
    segments apart than the hint's window). Near x = 5 both legs pass within ~1 m; the hint decides which leg the
    projection stays on, even when the other leg is the closer one."""
    out_leg = np.stack([np.arange(0.0, 61.0), np.zeros(61)], axis=1)
    back_leg = np.stack([np.arange(60.0, -1.0, -1.0), np.full(61, 2.0)], axis=1)
    route = Route(np.vstack([out_leg, back_leg]))
    # Without a hint the closest leg wins: y = 1.1 is nearer the way back.
    free = route.project(5.0, 1.1)
    assert free.s == pytest.approx(60.0 + 2.0 + 55.0) and free.lateral == pytest.approx(0.9)  # left of the way back
    out_hint = route.project(5.0, 0.1).segment  # plainly on the way out
    kept = route.project(5.0, 1.1, hint=out_hint)
    assert kept.s == pytest.approx(5.0) and kept.lateral == pytest.approx(1.1) and kept.heading == 0.0
    back_hint = route.project(5.0, 1.9).segment  # plainly on the way back
    assert back_hint - out_hint > 40
    back = route.project(5.0, 0.9, hint=back_hint)  # nearer the way out, but the car is on its way back
    assert back.s == pytest.approx(117.0) and back.lateral == pytest.approx(1.1)
    assert back.heading == pytest.approx(np.pi)


def test_box_segment_hits() -> None:
    ax, ay = np.array([-10.0, -10.0, 0.0]), np.array([0.9, 1.1, 0.0])
    ex, ey = np.array([20.0, 20.0, 0.1]), np.array([0.0, 0.0, 0.1])  # through, beside, inside
    hit = box_segment_hits(0.0, 0.0, 0.0, 5.0, 2.0, ax, ay, ex, ey)
    assert hit.tolist() == [True, False, True]


def test_geometry_is_cached_per_road() -> None:
    road = sf.straight_road(2)
    assert get_road_geometry(road) is get_road_geometry(road)
    g = RoadGeometry(road)
    assert g.on_road(np.array([0.0, 100.0]), np.array([0.0, 5.9]))
    assert not g.on_road(np.array([0.0]), np.array([6.5]))
    assert g.on_road(np.array([0.0]), np.array([6.3]), tolerance_m=0.5)
    assert g.speed_limit_at(0.0, 0.0) == 30.0


def test_shared_borders_are_deduplicated() -> None:
    g = RoadGeometry(sf.straight_road(3))
    # Lines at y = -2 (edge), 2, 6, 10 (edge): each once.
    assert len(g.painted_polylines) == 4 and len(g.continuous_polylines) == 2


def test_rendering_network_line_sides() -> None:
    road = sf.straight_road(2)  # lane 0: right border continuous; lane 1: left border continuous
    net = build_road_network(road)
    lane0 = net.get_lane(("a:b:0", "a:b:0>", 0))
    # highway-env draws line_types[0] at lateral -width/2, i.e. the right side in seal's convention.
    assert lane0.line_types == (LineType.CONTINUOUS, LineType.STRIPED)
    assert lane0.position(10.0, -2.0)[1] == pytest.approx(-2.0)
    mirrored = build_road_network(road, mirror_y=True).get_lane(("a:b:0", "a:b:0>", 0))
    assert mirrored.line_types == (LineType.STRIPED, LineType.CONTINUOUS)
