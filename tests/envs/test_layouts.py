"""Layouts: parameters rebuild the same network; the road description has the right geometry and markings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seal.core.road import RoadDescription
from seal.envs.layouts import LAYOUTS, make_network, sample_params
from seal.envs.network_index import NetworkIndex
from seal.envs.network_topology import describe_network, successor_map


@pytest.mark.parametrize("layout", LAYOUTS)
def test_params_rebuild_the_same_description(layout: str) -> None:
    for seed in range(3):
        params = sample_params(layout, np.random.default_rng(seed))
        stored = json.loads(json.dumps(params))  # as kept in a RoadDescription
        first = describe_network(make_network(layout, params), layout, params)
        again = describe_network(make_network(layout, stored), layout, stored)
        assert first.to_json() == again.to_json()
        restored = RoadDescription.from_json(first.to_json())
        assert (
            describe_network(
                make_network(restored.layout, restored.params), restored.layout, restored.params
            ).to_json()
            == first.to_json()
        )
        assert restored.layout == layout and restored.params == stored


@pytest.mark.parametrize("layout", LAYOUTS)
def test_sampled_params_vary(layout: str) -> None:
    samples = [json.dumps(sample_params(layout, np.random.default_rng(s)), sort_keys=True) for s in range(5)]
    assert len(set(samples)) == 5


def test_highway_markings_widths_and_successors() -> None:
    params = {
        "lanes": 3,
        "lane_width": 3.75,
        "length_in": 150.0,
        "arc_length": 150.0,
        "curve_deg": 20.0,
        "length_out": 150.0,
        "speed_limit": 30.0,
    }
    road = describe_network(make_network("highway", params), "highway", params)
    assert len(road.lanes) == 9
    for edge in ("a:b", "b:c", "c:d"):
        # Map frame (y mirrored from highway-env): lane 0 is the leftmost lane, as in highway-env.
        left, middle, right = (road.lane(f"{edge}:{i}") for i in range(3))
        # (left, right) seen in the driving direction: outer borders are road edges, inner ones lane lines.
        assert right.line_types == ("striped", "continuous")
        assert middle.line_types == ("striped", "striped")
        assert left.line_types == ("continuous", "striped")
        for lane in (right, middle, left):
            assert lane.width_m == pytest.approx(3.75)
            assert lane.speed_limit_mps == pytest.approx(30.0)
    for i in range(3):
        assert road.lane(f"a:b:{i}").successors == (f"b:c:{i}",)
        assert road.lane(f"b:c:{i}").successors == (f"c:d:{i}",)
        assert road.lane(f"c:d:{i}").successors == ()
        assert road.lane(f"a:b:{i}").centerline.shape == (2, 2)  # straight: end points only
        arc = road.lane(f"b:c:{i}").centerline
        steps = np.linalg.norm(np.diff(arc, axis=0), axis=1)
        assert arc.shape[0] > 100 and steps.max() <= 1.0 + 1e-6  # curved: sampled every ~1 m
    # Lanes are side by side, one lane width apart, and the arc joins both straights.
    a0, a1 = road.lane("a:b:0").centerline, road.lane("a:b:1").centerline
    assert np.linalg.norm(a1[0] - a0[0]) == pytest.approx(3.75)
    assert np.linalg.norm(road.lane("b:c:2").centerline[-1] - road.lane("c:d:2").centerline[0]) < 1e-6


def test_merge_ramp_lane_ends_and_shares_a_lane_line() -> None:
    params = sample_params("merge", np.random.default_rng(0))
    lanes = params["lanes"]
    road = describe_network(make_network("merge", params), "merge", params)
    ramp = road.lane(f"b:c:{lanes}")
    assert ramp.successors == ()  # the acceleration lane ends: ramp traffic must merge
    # The ramp joins from the right (right-hand traffic in the map frame): its left border is the lane line
    # it shares with the rightmost main lane, its right border the road edge.
    assert ramp.line_types == ("striped", "continuous")
    assert road.lane(f"b:c:{lanes - 1}").line_types[1] == "striped"  # no road edge along the ramp
    assert road.lane(f"a:b:{lanes - 1}").line_types[1] == "continuous"
    ramp_y = ramp.centerline[:, 1].mean()
    assert ramp_y < road.lane(f"b:c:{lanes - 1}").centerline[:, 1].mean()  # ramp is to the right (-y) of +x traffic
    assert road.lane("j:k:0").successors == ("k:b:0",)
    assert road.lane("k:b:0").successors == (f"b:c:{lanes}",)


def test_junction_topology() -> None:
    params = sample_params("intersection", np.random.default_rng(0))
    succ = successor_map(make_network("intersection", params))
    for k in range(4):
        assert sorted(s[1] for s in succ[(f"o{k}", f"ir{k}", 0)]) == sorted(
            f"il{j}" for j in range(4) if j != k
        )
    params = {"radius": 20.0, "lanes": 2, "access_length": 60.0, "speed_limit": 10.0}
    road = describe_network(make_network("roundabout", params), "roundabout", params)
    assert road.lane("ses:se:0").successors == ("se:ex:1",)  # entries join the outer ring lane
    assert "ex:exs:0" in road.lane("se:ex:1").successors  # exits leave from the outer lane only
    assert "ex:exs:0" not in road.lane("se:ex:0").successors


def test_unknown_layout() -> None:
    with pytest.raises(ValueError, match="unknown layout 'foo'"):
        make_network("foo", {})
    with pytest.raises(ValueError, match="unknown layout"):
        sample_params("foo", np.random.default_rng(0))
    with pytest.raises(ValueError, match="missing parameter 'lanes'"):
        make_network("highway", {"lane_width": 4.0})


@pytest.mark.parametrize("layout", LAYOUTS)
def test_fast_lane_geometry_matches_highway_env(layout: str) -> None:
    network = make_network(layout, sample_params(layout, np.random.default_rng(1)))
    index = NetworkIndex(network)
    rng = np.random.default_rng(0)
    for lane_index, fast in index.lanes.items():
        lane = network.get_lane(lane_index)
        for _ in range(5):
            s, r = rng.uniform(-2.0, lane.length + 2.0), rng.uniform(-3.0, 3.0)
            p = lane.position(s, r)
            np.testing.assert_allclose(fast.position(s, r), p, atol=1e-9)
            np.testing.assert_allclose(fast.local(*p), lane.local_coordinates(p), atol=1e-9)
            assert fast.heading_at(s) == pytest.approx(lane.heading_at(s), abs=1e-9)
    # The full closest-lane search agrees with highway-env's.
    for _ in range(50):
        lane_index = index.indices[int(rng.integers(len(index.indices)))]
        lane = network.get_lane(lane_index)
        s = rng.uniform(0.0, lane.length)
        p, h = lane.position(s, rng.uniform(-1.0, 1.0)), lane.heading_at(s)
        assert index.closest_lane(p[0], p[1], h, None) == network.get_closest_lane_index(p, h)
