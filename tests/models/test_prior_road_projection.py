"""Road projection of decoded candidates (`seal.models.prior.road_projection`): the lane lookup grid against a scan of
every segment, on-lane candidates untouched, off-road candidates re-driven onto the road within the kinematic
limits with their own speeds, and the prior's / steered prior's switches."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf
import torch
from kernel_reference import reference_lane_excess

from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, X, Y
from seal.models.prior.kinematics import integrate_controls
from seal.models.prior.metrics import drivability, kinematic_limits
from seal.models.prior.prior import TrajectoryPrior
from seal.models.prior.road_projection import (
    GridCache,
    RoadProjection,
    closest_on_grid,
    lane_grid,
    project_to_road,
)


@pytest.mark.parametrize("road", [sf.straight_road(3), sf.curved_road(2, radius_m=30.0)], ids=["straight", "curve"])
def test_grid_lookup_equals_a_scan_of_every_segment(road) -> None:
    grid = lane_grid(road)
    lo = grid.origin
    hi = lo + np.array(grid.shape) * grid.cell_m
    rng = np.random.default_rng(0)
    # Points everywhere in the grid and beyond it (those are scanned in full).
    pts = rng.uniform(lo - 30.0, hi + 30.0, (3000, 2))
    q, e = closest_on_grid(pts, grid)
    q_ref, e_ref = reference_lane_excess(pts, road)
    np.testing.assert_allclose(e, e_ref, atol=1e-9)
    np.testing.assert_allclose(q, q_ref, atol=1e-9)
    # Cells are filled on first use: asking again (every cell now filled) gives the same answer.
    filled = int((grid.span[:, 0] >= 0).sum())
    assert filled > 0 and grid.fill[0] == grid.span[:, 1].max()
    q2, e2 = closest_on_grid(pts[::-1].copy(), grid)
    np.testing.assert_array_equal(e2, e[::-1])
    assert int((grid.span[:, 0] >= 0).sum()) == filled
    assert (e_ref < 0).any() and (e_ref > 5).any()  # the draw covers lanes and far off-road points


def _arc_candidates(speed_mps: float, yaw_rate_rps: np.ndarray) -> np.ndarray:
    """Candidates ``[K, 80, 2]`` from the origin along +x at constant speed and yaw rates ``[K]`` (rad/s)."""
    k = len(yaw_rate_rps)
    yaw = torch.as_tensor(np.repeat(yaw_rate_rps[:, None], 80, 1), dtype=torch.float64)
    return integrate_controls(torch.zeros(k, 80, dtype=torch.float64), yaw,
                              torch.full((k,), speed_mps, dtype=torch.float64),
                              torch.zeros(k, dtype=torch.float64)).numpy()


def test_candidates_on_the_lanes_come_back_unchanged() -> None:
    road = sf.straight_road(3)  # lanes at y = 0, 4, 8 along +x from x = -100
    xy = _arc_candidates(15.0, np.zeros(4)) + np.array([[0.0, 0.0], [0.0, 4.0], [0.0, 8.0], [0.0, 1.9]])[:, None]
    out, moved = project_to_road(xy, np.zeros(2), 0.0, lane_grid(road), RoadProjection())
    assert not moved.any()
    np.testing.assert_array_equal(out, xy)


def test_a_candidate_that_runs_off_a_curve_is_driven_along_it_within_the_limits() -> None:
    road = sf.curved_road(1, radius_m=60.0)  # one lane: straight along +x to the origin, then a left arc of 60 m
    start = np.array([-20.0, 0.0])
    # Straight on (off the road after the bend), and one already following the bend (8 m/s on r = 60 m: 0.133 rad/s).
    yaw = np.array([0.0, 0.0])
    xy = _arc_candidates(8.0, yaw) + start
    xy[1] = _bend(start)
    cfg = RoadProjection(yaw_rate_limit_rps=0.98)
    before = drivability(xy, start, 0.0, road)
    assert not before.on_road[0] and before.on_road[1]
    out, moved = project_to_road(xy, start, 0.0, lane_grid(road), cfg)
    assert moved.tolist() == [True, False] and np.array_equal(out[1], xy[1])
    after = drivability(out, start, 0.0, road)
    assert after.drivable.all()
    # Its speed at every step is the candidate's own (so its acceleration is too), and its yaw rate is bounded.
    step = np.linalg.norm(np.diff(np.concatenate([start[None], out[0]]), axis=0), axis=1) / DT_S
    np.testing.assert_allclose(step, 8.0, atol=1e-9)
    acc, yaw_rate = kinematic_limits(out[:1], start, 0.0)
    assert acc[0] < 1e-6 and yaw_rate[0] <= 0.98 + 1e-9
    # It ends near the lane: within half a lane width of the centreline, not just within the check's tolerance.
    _, excess = closest_on_grid(out[0, 4::5], lane_grid(road))
    assert excess.max() <= 0.5


def _bend(start: np.ndarray) -> np.ndarray:
    """80 steps at 8 m/s from ``start`` along the lane of `sf.curved_road` (r = 60 m), positions by arc length."""
    centre = sf.curve_centerline(60.0)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(centre, axis=0), axis=1))])
    s0 = float(cum[np.argmin(np.linalg.norm(centre - start, axis=1))])
    s = s0 + 8.0 * DT_S * np.arange(1, 81)
    return np.stack([np.interp(s, cum, centre[:, 0]), np.interp(s, cum, centre[:, 1])], axis=1)


def test_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="lookahead_steps"):
        RoadProjection(lookahead_steps=0)
    with pytest.raises(ValueError, match="yaw_rate_limit_rps"):
        RoadProjection(yaw_rate_limit_rps=-1.0)


def test_grid_cache_builds_once_per_road_content() -> None:
    cache = GridCache()
    a, b = sf.curved_road(2), sf.curved_road(2)  # equal content, different objects
    assert cache.get(a) is cache.get(b) and cache.get(sf.straight_road(2)) is not cache.get(a)


def test_the_prior_projects_only_when_asked() -> None:
    torch.set_num_threads(1)
    prior = TrajectoryPrior.untrained(seed=0)
    scenario = sf.curve_scenario()
    plain = prior.predict([scenario])[0]
    assert prior.road_projection is None
    prior.road_projection = prior.default_road_projection()
    assert prior.road_projection.yaw_rate_limit_rps == prior.config.yaw_rate_limit_rps
    projected = prior.predict([scenario])[0]
    prior.road_projection = None
    np.testing.assert_array_equal(prior.predict([scenario])[0].xy, plain.xy)
    now = scenario.tracks[scenario.adv_index, CURRENT_STEP]
    raw = drivability(plain.xy, now[[X, Y]], float(now[HEADING]), scenario.road)
    new = drivability(projected.xy, now[[X, Y]], float(now[HEADING]), scenario.road)
    # The untrained prior's candidates swerve at up to 0.5 rad/s and speed up to 22 m/s, some turning around:
    # projection brings most of them onto the road, and none leaves it where its raw candidate stayed on it.
    assert new.on_road.sum() >= raw.on_road.sum() + 10 and not (raw.on_road & ~new.on_road).any()
    assert new.max_yaw_rate_rps.max() <= prior.config.yaw_rate_limit_rps + 1e-6
    # Probabilities and speeds are the decoder's: the projection only turns candidates onto the road.
    np.testing.assert_array_equal(projected.probs, plain.probs)
    np.testing.assert_allclose(projected.speed, plain.speed, atol=1e-6)
