"""Social features with analytic answers: THW / TTC / DRAC, collisions, mTTCP, pair skipping, scene weighting."""

from __future__ import annotations

import numpy as np
import pytest
from scoring_builders import LENGTH_M, cross_road, scenario, straight_road, straight_track, track
from scoring_reference import segments_intersect

from seal.core.scenario import DT_S, N_STEPS
from seal.scoring.kernels import segments_cross
from seal.scoring.scores import scene_score, score_scenario
from seal.scoring.social import SOCIAL_FEATURES, social_score


def feature(res, name: str, variant: str = "gt", pair: tuple[int, int] = (0, 1)) -> float:
    k = int(np.flatnonzero((res.pair_i == pair[0]) & (res.pair_j == pair[1]))[0])
    return float(res.soc_features[variant][k, SOCIAL_FEATURES.index(name)])


def test_closing_in_one_lane_ttc_thw_drac() -> None:
    # Follower 20 m/s, leader 18 m/s, 30 m apart (centres) at t = 0: the bumper gap shrinks 2 m/s and is
    # smallest at the last step (t = 9 s): 30 - 4.5 - 2 * 9 = 7.5 m.
    s = scenario([straight_track(0.0, 20.0), straight_track(30.0, 18.0)], straight_road())
    res = score_scenario(s)
    gap = 30.0 - LENGTH_M - 2.0 * (N_STEPS - 1) * DT_S
    assert feature(res, "inv_ttc") == pytest.approx(2.0 / gap, rel=1e-4)
    assert feature(res, "inv_thw") == pytest.approx(20.0 / gap, rel=1e-4)
    assert feature(res, "drac") == pytest.approx(2.0**2 / (2 * gap), rel=1e-4)
    assert feature(res, "collisions") == 0


def test_equal_speeds_have_headway_but_no_ttc() -> None:
    s = scenario([straight_track(0.0, 15.0), straight_track(30.0, 15.0)], straight_road())
    res = score_scenario(s)
    assert feature(res, "inv_thw") == pytest.approx(15.0 / (30.0 - LENGTH_M), rel=1e-4)  # THW 1.7 s
    assert feature(res, "inv_ttc") == 0.0
    assert feature(res, "drac") == 0.0


def test_collision_found_by_segment_intersection_only() -> None:
    # A crosses the origin along x at step 45, B along y half a metre behind: centres are never within 0.25 m
    # and the (tiny, 0.2 m) bodies never overlap, but their motion segments of step 46 cross at the origin.
    k = np.arange(N_STEPS, dtype=float)
    a = track(np.stack([k - 45.0, np.zeros(N_STEPS)], axis=1), length=0.2, width=0.2)
    b = track(np.stack([np.zeros(N_STEPS), k - 45.5], axis=1), length=0.2, width=0.2)
    res = score_scenario(scenario([a, b], cross_road()))
    assert feature(res, "collisions") == 1.0
    assert np.hypot(a[:, 0] - b[:, 0], a[:, 1] - b[:, 1]).min() > 0.25


def test_collision_found_by_box_overlap() -> None:
    # Side-swipe: B drifts toward A and back while heading straight along +x (explicit velocity, so both boxes
    # stay axis-aligned). Centres stay >= 1.5 m apart laterally (never within 0.25 m, motion segments never
    # cross), but the 2 m wide bodies overlap exactly while the lateral offset is below 2 m: steps 41..49, one
    # contact. A second drift-in (steps 71..79) is a second contact: contacts count, not contact steps.
    k = np.arange(N_STEPS, dtype=float)
    vel = np.tile([20.0, 0.0], (N_STEPS, 1))
    a = track(np.stack([2.0 * k, np.zeros(N_STEPS)], axis=1), vel=vel)
    for centres, contacts in (([45.0], 1.0), ([45.0, 75.0], 2.0)):
        dips = [np.clip(np.abs(k - c) * 0.12 + 1.5, 1.5, 3.5) for c in centres]  # 1.98 m at |k - c| = 4, 2.1 at 5
        lateral = np.minimum.reduce(dips)
        b = track(np.stack([2.0 * k, lateral], axis=1), vel=vel)
        res = score_scenario(scenario([a, b], straight_road()))
        assert feature(res, "collisions") == contacts


def test_segments_cross() -> None:
    def cross(p0, p1, q0, q1) -> bool:  # the compiled test and the numpy reference agree on every case
        got = segments_cross(*p0, *p1, *q0, *q1)
        assert got == bool(segments_intersect(np.array(p0), np.array(p1), np.array(q0), np.array(q1)))
        return got

    p0, p1 = (0.0, 0.0), (1.0, 0.0)
    assert cross(p0, p1, (0.5, -1.0), (0.5, 1.0))
    assert not cross(p0, p1, (2.0, -1.0), (2.0, 1.0))
    assert cross(p0, p1, (1.0, 0.0), (1.0, 3.0))  # touching end points
    assert not cross(p0, p1, (0.0, 1.0), (1.0, 1.0))  # parallel
    assert cross(p0, p1, (0.5, 0.0), (3.0, 0.0))  # collinear overlap


def test_time_to_conflict_point_on_map_and_paths() -> None:
    # 25 m/s on crossing lanes: A is at the origin at step 40, B at step 52; path points are 2.5 m apart, so
    # the only close pair of path points is the crossing itself. Time difference to it: 12 steps = 1.2 s.
    k = np.arange(N_STEPS, dtype=float)
    a = track(np.stack([2.5 * (k - 40), np.zeros(N_STEPS)], axis=1))
    b = track(np.stack([np.zeros(N_STEPS), 2.5 * (k - 52)], axis=1))
    res = score_scenario(scenario([a, b], cross_road()))
    assert feature(res, "inv_mttcp_agents") == pytest.approx(1 / 1.2, rel=1e-4)
    assert feature(res, "inv_mttcp_map") == pytest.approx(1 / 1.2, rel=1e-4)
    # Crossing lanes: no same-lane measures, and no collision.
    assert feature(res, "inv_thw") == feature(res, "inv_ttc") == feature(res, "collisions") == 0.0


def test_pairs_skipped_when_far_or_both_stationary() -> None:
    road = straight_road()
    far = scenario([straight_track(0.0, 10.0), straight_track(0.0, 10.0, y=60.0)], road)
    still = scenario([straight_track(0.0, 0.0), straight_track(8.0, 0.0)], road)
    for s in (far, still):
        res = score_scenario(s)
        assert not res.pair_active["gt"].any()
        assert res.pair_score["gt"].sum() == 0.0


def test_social_score_weights_and_caps() -> None:
    f = {k: np.array([0.0, 100.0]) for k in SOCIAL_FEATURES}
    f["collisions"] = np.array([0.0, 3.0])
    # Caps: 2 + 4 + 4 + 2 + 2 (DRAC/5) + collisions + 5 (0.1 x anomaly).
    assert social_score(f).tolist() == [0.0, 2 + 4 + 4 + 2 + 2 + 3 + 5]
    f = {k: np.array([0.5]) for k in SOCIAL_FEATURES}
    assert social_score(f)[0] == pytest.approx(0.5 * 4 + 0.1 + 0.5 + 0.05)


def test_scene_score_weighting() -> None:
    traj = np.array([2.0, 4.0, 6.0, 8.0])
    focal = np.array([True, True, False, False])
    dist = np.array([0.0, 0.0, 1.0, 3.0])
    score, weights = scene_score(traj, focal, dist)
    assert weights.tolist() == [1.0, 1.0, 0.5, 0.25]
    assert score == pytest.approx((2 + 4 + 3 + 2) / (2 + np.sqrt(2)))


def test_trajectory_scores_add_pair_scores_to_both_agents() -> None:
    s = scenario([straight_track(0.0, 20.0), straight_track(30.0, 18.0), straight_track(-60.0, 10.0, y=80.0)],
                 straight_road())
    res = score_scenario(s)
    pair_sum = np.bincount(res.pair_i, res.pair_score["gt"], 3) + np.bincount(res.pair_j, res.pair_score["gt"], 3)
    np.testing.assert_allclose(res.traj["gt"], res.ind_score["gt"] + pair_sum)
    np.testing.assert_allclose(res.traj["ac"], np.maximum(res.traj["gt"], res.traj["as"]))
    assert res.weights["gt"][2] == pytest.approx(1.0 / (1.0 + np.hypot(80.0, 60.0)), rel=1e-3)


def _dense_agent_mttcp(ctx_a, ctx_b, I, J, mask, st_i, st_j) -> np.ndarray:
    """Straightforward O(T^2) per pair reference of the path-conflict measure (SafeShift's loop)."""
    out = np.zeros(I.size)
    for p, (i, j) in enumerate(zip(I, J, strict=True)):
        pi, pj, m = ctx_a.tracks.pos[i], ctx_b.tracks.pos[j], mask[p]
        close = (np.linalg.norm(pi[:, None] - pj[None], axis=-1) <= 1.0) & m[:, None] & m[None, :]
        best = np.inf
        for ti in np.flatnonzero(close.any(1)):
            tj = int(np.argmax(close[ti]))
            t = np.arange(min(ti, tj) + 1)
            t = t[m[t]]
            time_i = 0 * t if st_i[p] else np.linalg.norm(pi[t] - pi[ti], axis=1) / (ctx_a.speed[i, t] + 1e-3)
            time_j = 0 * t if st_j[p] else np.linalg.norm(pj[t] - pi[ti], axis=1) / (ctx_b.speed[j, t] + 1e-3)
            best = min(best, float(np.abs(time_i - time_j).min()))
        out[p] = 1.0 / max(best, 1e-3) if np.isfinite(best) else 0.0
    return out


def test_path_conflicts_match_dense_reference() -> None:
    # A queue: a car standing on the lane, one stopping behind it, one passing through both spots later, and
    # one slowly creeping; exercises the collapsing of repeated positions in the fast implementation.
    from seal.scoring.extrapolation import future_extrapolate
    from seal.scoring.frenet import RoadIndex
    from seal.scoring.social import TrackContext, _agent_mttcp
    from seal.scoring.tracks import from_tracks

    t = np.arange(N_STEPS) * DT_S
    stop_x = np.minimum(10.0 * t, 25.0)  # brakes hard at x = 25 m
    creep = 40.0 + 0.05 * t
    tracks = [
        straight_track(30.0, 0.0),
        track(np.stack([stop_x, np.zeros(N_STEPS)], axis=1)),
        straight_track(-40.0, 12.0),
        track(np.stack([creep, np.zeros(N_STEPS)], axis=1)),
        straight_track(-10.0, 6.0, y=0.6),
    ]
    road = straight_road()
    s = scenario(tracks, road)
    index = RoadIndex(road)
    gt = from_tracks(s.tracks, index)
    fe = future_extrapolate(gt, index)
    for a, b in ((gt, gt), (fe, gt)):
        ca, cb = TrackContext(a, index), TrackContext(b, index)
        I, J = np.nonzero(~np.eye(a.n_agents, dtype=bool))
        mask = a.valid[I] & b.valid[J]
        si, sj = ca.speed[I], cb.speed[J]
        mean_i = (si * mask).sum(1) / mask.sum(1)
        mean_j = (sj * mask).sum(1) / mask.sum(1)
        st_i, st_j = mean_i <= 0.25, mean_j <= 0.25
        fast = _agent_mttcp(ca, cb, I, J, st_i, st_j, mask)
        dense = _dense_agent_mttcp(ca, cb, I, J, mask, st_i, st_j)
        np.testing.assert_allclose(np.minimum(fast, 4.0), np.minimum(dense, 4.0), rtol=1e-3, atol=1e-3)
        assert (dense > 0).sum() >= 4
