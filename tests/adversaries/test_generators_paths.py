"""Candidate futures -> replayable tracks, and the map-based (lanes) candidate source."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf

from seal.adversaries.candidate_path import candidate_track
from seal.adversaries.lane_candidates import lane_candidates
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, LENGTH, N_FUTURE, VALID, VX, VY, WIDTH, X, Y

FUT_S = DT_S * np.arange(1, N_FUTURE + 1)


def test_candidate_track_keeps_history_and_size_and_differentiates_positions() -> None:
    scenario = sf.lane_change_scenario()
    adv = scenario.track(scenario.adv_id).astype(np.float64)
    x0, y0 = adv[CURRENT_STEP, X], adv[CURRENT_STEP, Y]
    v = np.array([12.0, -5.0])
    future = np.array([x0, y0]) + FUT_S[:, None] * v
    track = candidate_track(scenario, scenario.adv_index, future)
    assert track.shape == (91, 8)
    np.testing.assert_array_equal(track[: CURRENT_STEP + 1], adv[: CURRENT_STEP + 1])
    np.testing.assert_allclose(track[CURRENT_STEP + 1 :, [X, Y]], future)
    # Linear motion: central differences give the velocity exactly, heading along it, sizes from the log.
    np.testing.assert_allclose(track[CURRENT_STEP + 1 :, [VX, VY]], np.broadcast_to(v, (N_FUTURE, 2)), atol=1e-9)
    np.testing.assert_allclose(np.cos(track[11:, HEADING] - np.arctan2(v[1], v[0])), 1.0, atol=1e-12)
    assert np.all(track[11:, LENGTH] == adv[CURRENT_STEP, LENGTH])
    assert np.all(track[11:, WIDTH] == adv[CURRENT_STEP, WIDTH]) and np.all(track[:, VALID] == 1)


def test_candidate_track_extends_short_candidates_and_holds_heading_when_still() -> None:
    scenario = sf.lane_change_scenario()
    adv = scenario.track(scenario.adv_id)
    p0 = adv[CURRENT_STEP, [X, Y]].astype(np.float64)
    short = p0 + np.arange(1, 31)[:, None] * np.array([2.0, 0.0])  # 20 m/s for 3 s
    track = candidate_track(scenario, scenario.adv_index, short)
    np.testing.assert_allclose(track[-1, [X, Y]], p0 + [160.0, 0.0])  # extended at 2 m per step
    still = np.broadcast_to(p0, (N_FUTURE, 2))
    track = candidate_track(scenario, scenario.adv_index, still)
    np.testing.assert_allclose(track[11:, HEADING], adv[CURRENT_STEP, HEADING])
    np.testing.assert_allclose(track[11:, [VX, VY]], 0.0)
    with pytest.raises(ValueError, match="future_xy"):
        candidate_track(scenario, scenario.adv_index, np.zeros((80, 3)))


def test_lane_candidates_follow_the_lanes() -> None:
    scenario = sf.lane_change_scenario()  # adversary in lane 1 (y = 4 m) of a 3-lane road at 27 m/s
    cands = lane_candidates(scenario)
    adv = scenario.track(scenario.adv_id)
    x0, y0 = float(adv[CURRENT_STEP, X]), float(adv[CURRENT_STEP, Y])
    v0 = float(np.hypot(adv[CURRENT_STEP, VX], adv[CURRENT_STEP, VY]))
    assert cands.agent_index == scenario.adv_index and cands.n_steps == N_FUTURE
    assert cands.n_candidates <= 32 and np.all(np.diff(cands.probs) <= 0) and cands.probs.sum() == pytest.approx(1)
    # The most likely future keeps lane and speed.
    best = cands.xy[0]
    np.testing.assert_allclose(best[:, 0], x0 + v0 * FUT_S, atol=0.05)
    np.testing.assert_allclose(best[-1, 1], 4.0, atol=0.05)
    assert abs(y0 - 4.0) < 0.5
    # Changes into both neighbouring lanes and a range of speeds are among the candidates.
    end_y = np.round(cands.xy[:, -1, 1])
    assert {0.0, 4.0, 8.0} <= set(end_y.tolist())
    speed_end = cands.speed[:, -1]
    assert speed_end.min() < v0 - 10 and speed_end.max() > v0 + 5
    # No two candidates coincide.
    gaps = np.abs(cands.xy[:, None] - cands.xy[None]).max(axis=(2, 3))
    assert gaps[~np.eye(cands.n_candidates, dtype=bool)].min() > 0.5


def test_lane_candidates_on_a_curve_stay_on_the_lane() -> None:
    scenario = sf.curve_scenario()
    cands = lane_candidates(scenario)
    lane = scenario.road.lanes[1].centerline  # the adversary's (inner) lane
    seg_a, seg_e = lane[:-1], np.diff(lane, axis=0)
    for p in cands.xy[0]:
        u = np.clip(((p - seg_a) * seg_e).sum(1) / (seg_e * seg_e).sum(1), 0, 1)
        assert np.hypot(*(seg_a + u[:, None] * seg_e - p).T).min() < 0.3


def test_lane_candidates_without_an_aligned_lane_turn_at_constant_rates() -> None:
    road = sf.straight_road(2)
    lane = road.lanes[0].centerline
    ego = sf.simulate_track(lane, 100.0, 20.0)
    wrong_way = sf.simulate_track(lane[::-1].copy(), 500.0, 10.0)  # drives -x: no lane is aligned with it
    scenario = sf.make_scenario(road, [ego, wrong_way], "wrong_way")
    cands = lane_candidates(scenario)
    p0 = wrong_way[CURRENT_STEP, [X, Y]]
    assert cands.n_candidates == 32  # 5 turn rates x 7 accelerations, the 32 most likely
    np.testing.assert_allclose(cands.xy[0, :, 0], p0[0] - 10.0 * FUT_S, atol=1e-3)
    np.testing.assert_allclose(cands.xy[0, :, 1], p0[1], atol=1e-3)
