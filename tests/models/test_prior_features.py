"""Prior inputs: lane chunks, agent / chunk selection, the agent-centric frame, the road-distance test."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scenario_factory as sf
import torch

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import CURRENT_STEP
from seal.models.prior.features import AGENT_FEATURES, FeatureConfig, build_tables, featurise
from seal.models.prior.lanes import CHUNK_ATTRS, chunk_road, distance_to_lanes
from seal.models.prior.metrics import drivability


def test_chunks_cut_lanes_by_arc_length() -> None:
    lane = LaneSpec("a:b:0", np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 15.0]]), 3.5, ("continuous", "striped"), 25.0)
    chunks = chunk_road(RoadDescription("polylines", (lane,)), chunk_length_m=20.0, n_points=5)
    assert chunks.points.shape == (3, 5, 2)  # 45 m -> 20 + 20 + 5
    assert np.allclose(chunks.points[0, :, 0], [0, 5, 10, 15, 20]) and np.allclose(chunks.points[0, :, 1], 0)
    assert np.allclose(chunks.points[1, -1], [30.0, 10.0])  # 40 m along: 10 m up the second leg
    assert np.allclose(chunks.points[2, :, 1], np.linspace(10.0, 15.0, 5))
    assert np.allclose(chunks.direction[0], 0.0) and np.allclose(chunks.direction[2], math.pi / 2)
    attrs = dict(zip(CHUNK_ATTRS, chunks.attrs[0], strict=True))
    assert attrs["width_m"] == 3.5 and attrs["speed_limit_mps"] == 25.0
    assert attrs["left_continuous"] == 1.0 and attrs["right_striped"] == 1.0 and attrs["left_striped"] == 0.0


def test_distance_to_lanes() -> None:
    road = sf.straight_road(2, length_m=100.0, x0=0.0)  # lanes at y = 0 and y = 4, 4 m wide
    d, w = distance_to_lanes(road, np.array([[10.0, 1.0], [50.0, 4.5], [50.0, 30.0], [110.0, 0.0]]))
    assert np.allclose(d, [1.0, 0.5, 26.0, 10.0]) and np.allclose(w, 4.0)


def test_drivability_flags_candidates_leaving_the_road() -> None:
    road = sf.straight_road(2, length_m=400.0, x0=0.0)
    t = np.arange(1, 81) * 0.1
    along = np.stack([50 + 10 * t, np.zeros(80)], axis=-1)
    drifting = np.stack([50 + 10 * t, 1.5 * t], axis=-1)  # 12 m to the left after 8 s: off the road
    d = drivability(np.stack([along, drifting]), np.array([50.0, 0.0]), 0.0, road)
    assert d.on_road.tolist() == [True, False] and d.drivable.tolist() == [True, False]
    assert np.all(d.within_acc) and np.all(d.within_yaw)


def test_target_frame_features() -> None:
    s = sf.lane_change_scenario()
    cfg = FeatureConfig(n_agents=4, n_chunks=6)
    tables = build_tables([s], [[1, 0]], cfg)  # the adversary, then the ego
    f = featurise(tables, torch.arange(2), cfg)
    assert f["agents"].shape == (2, 4, AGENT_FEATURES) and f["chunks"].shape == (2, 6, cfg.chunk_features)
    # Row 0 is the target: at its current step it sits at the origin heading +x.
    cur = f["agents"][0, 0].view(-1)[: 7 * 11].view(11, 7)[CURRENT_STEP]
    speed = float(np.hypot(*s.tracks[1, CURRENT_STEP, 3:5]))
    assert torch.allclose(cur[:4], torch.tensor([0.0, 0.0, 1.0, 0.0]), atol=1e-5)
    assert cur[4].item() == pytest.approx(speed / cfg.vel_scale_mps, rel=1e-4) and abs(cur[5].item()) < 1e-3
    assert f["agents"][0, 0, -1] == 1.0 and f["agents"][0, 1, -1] == 0.0  # is-target flag
    # Agent 2 appears at step 20: no history, so it is not a token; three agents are present.
    assert f["agent_mask"].sum(1).tolist() == [3, 3]
    assert (tables.agent_idx[0, 0] - 1).item() == 1 and (tables.agent_idx[1, 0] - 1).item() == 0
    # The ego's frame sees the adversary ahead (+x) and one lane to the left (+y): both are in the log.
    j = int(torch.nonzero(tables.agent_idx[1] - 1 == 1)[0, 0])
    ego_view = f["agents"][1, j].view(-1)[: 7 * 11].view(11, 7)[CURRENT_STEP] * cfg.pos_scale_m
    rel = s.tracks[1, CURRENT_STEP, :2] - s.tracks[0, CURRENT_STEP, :2]
    h = float(s.tracks[0, CURRENT_STEP, 2])
    expected = [math.cos(h) * rel[0] + math.sin(h) * rel[1], -math.sin(h) * rel[0] + math.cos(h) * rel[1]]
    assert np.allclose(ego_view[:2].numpy(), expected, atol=1e-3) and expected[0] > 40.0


def test_chunks_are_chosen_along_the_path_ahead() -> None:
    s = sf.lane_change_scenario()  # agents at 25-27 m/s on an 800 m straight road
    cfg = FeatureConfig(n_agents=4, n_chunks=6)
    tables = build_tables([s], [[1]], cfg)
    f = featurise(tables, torch.arange(1), cfg)
    xs = f["chunks"][0, :, : 4 * cfg.chunk_points].view(6, cfg.chunk_points, 4)[..., 0] * cfg.pos_scale_m
    # 6 chunks of 20 m hug the 108 m constant-velocity path over 4 s, not the road behind.
    assert xs.max().item() > 90.0 and xs.min().item() > -25.0


def test_targets_must_be_present_now() -> None:
    s = sf.lane_change_scenario()
    with pytest.raises(ValueError, match="not valid at the current step"):
        build_tables([s], [[2]], FeatureConfig())
    with pytest.raises(ValueError, match="out of range"):
        build_tables([s], [[9]], FeatureConfig())


def test_road_points_and_road_loss() -> None:
    from seal.models.prior.features import road_points
    from seal.models.prior.losses import road_loss

    s = sf.lane_change_scenario()  # straight road along +x, lanes at y = 0, 4, 8
    cfg = FeatureConfig(n_agents=4, n_chunks=6)
    tables = build_tables([s], [[1]], cfg, road_chunks=20)
    pts, mask = road_points(tables, torch.arange(1))
    assert pts.shape == (1, 20 * cfg.chunk_points, 2) and bool(mask.all())
    # In the adversary's frame (lane 1, y = 4, heading ~0) the lanes lie at y ~ -4, 0, +4.
    lateral = np.unique(np.round(pts[0, :, 1].numpy(), 0))
    assert set(lateral.tolist()) <= {-4.0, 0.0, 4.0}
    line = torch.stack([torch.arange(0.0, 50.0, 1.0), torch.zeros(50)], dim=-1)[None]  # points on y = 0
    xy = torch.tensor([[[[10.0, 5.0], [20.0, 1.0]]]])  # [B=1, M=1, T=2, 2]: 5 m and 1 m off the line
    loss = road_loss(xy, line, torch.ones(1, 50, dtype=torch.bool), margin_m=2.0)
    assert loss.item() == pytest.approx((3.0 + 0.0) / 2)
    masked = torch.ones(1, 50, dtype=torch.bool)
    masked[0, :30] = False  # only x >= 30 counts: (10, 5) is now sqrt(20^2 + 5^2) away
    expected = (math.hypot(20.0, 5.0) - 2.0 + math.hypot(10.0, 1.0) - 2.0) / 2
    assert road_loss(xy, line, masked, margin_m=2.0).item() == pytest.approx(expected, rel=1e-5)


def test_open_map_edges_continues_only_lanes_that_leave_the_map() -> None:
    from seal.models.prior.lanes import open_map_edges

    main_in = LaneSpec("a:b:0", np.array([[0.0, 0.0], [100.0, 0.0]]), 4.0, successors=("b:c:0",))
    main_out = LaneSpec("b:c:0", np.array([[100.0, 0.0], [200.0, 0.0]]), 4.0)  # runs off the map at x = 200
    merge = LaneSpec("m:b:0", np.array([[0.0, -8.0], [60.0, -8.0], [100.0, -4.0]]), 4.0)  # ends inside the map
    road = RoadDescription("polylines", (main_in, main_out, merge))
    opened = open_map_edges(road, length_m=50.0)
    assert np.allclose(opened.lane("b:c:0").centerline[-1], [250.0, 0.0])
    assert np.array_equal(opened.lane("m:b:0").centerline, merge.centerline)
    assert np.array_equal(opened.lane("a:b:0").centerline, main_in.centerline)
    # Past the map edge a candidate is off the stored road but on the opened one.
    t = np.arange(1, 81) * 0.1
    fast = np.stack([160.0 + 15.0 * t, np.zeros(80)], axis=-1)[None]  # ends at x = 280: 80 m past the edge
    d = drivability(fast, np.array([160.0, 0.0]), 0.0, road)
    assert d.on_road.tolist() == [True] and d.on_road_strict.tolist() == [False]
