"""The scoring's compiled kernels against their numpy reference forms (tests/scoring_reference.py) on generated
traffic of every layout, and the polyline kernels against `Polyline`'s numpy methods."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scoring_reference import agent_mttcp_reference, collisions_reference, project_reference

from seal.core.scenario import HEADING, VALID, Scenario
from seal.envs.generate import generate_dataset
from seal.scoring.extrapolation import future_extrapolate
from seal.scoring.frenet import Polyline
from seal.scoring.kernels import polyline_at, polyline_project, rank_by_dwell
from seal.scoring.scores import road_index
from seal.scoring.social import STATIONARY_MPS, TrackContext, _agent_mttcp, _collisions
from seal.scoring.tracks import from_tracks


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> list[Scenario]:
    root: Path = tmp_path_factory.mktemp("kernels") / "ds"
    return generate_dataset(root, n=16, seed=3, workers=1, progress=False).load()


def test_projection_kernel_matches_the_numpy_reference(generated: list[Scenario]) -> None:
    rng = np.random.default_rng(0)
    n_points = 0
    for s in generated:
        index = road_index(s.road)
        valid = s.tracks[..., VALID] > 0.5
        xy = s.tracks[..., :2][valid].astype(np.float64)
        heading = s.tracks[..., HEADING][valid].astype(np.float64)
        # Plus points scattered around the traffic, some off every lane.
        xy = np.concatenate([xy, xy[rng.integers(xy.shape[0], size=200)] + rng.normal(0, 4.0, (200, 2))])
        heading = np.concatenate([heading, rng.uniform(-np.pi, np.pi, 200)])
        for h in (heading, None):
            got, ref = index.project(xy, h), project_reference(index, xy, h)
            np.testing.assert_array_equal(got.lane, ref.lane)
            np.testing.assert_array_equal(got.in_lane, ref.in_lane)
            np.testing.assert_allclose(got.s, ref.s, rtol=0, atol=1e-9)
            np.testing.assert_allclose(got.d, ref.d, rtol=0, atol=1e-9)
        n_points += xy.shape[0]
    assert n_points > 10_000


def test_agent_conflict_kernel_matches_the_numpy_reference(generated: list[Scenario]) -> None:
    n_conflicts = 0
    for s in generated:
        index = road_index(s.road)
        gt = from_tracks(s.tracks, index)
        ctx_gt, ctx_fe = TrackContext(gt, index), TrackContext(future_extrapolate(gt, index), index)
        i, j = np.triu_indices(gt.n_agents, 1)
        for ca, cb, pi, pj in ((ctx_gt, ctx_gt, i, j), (ctx_fe, ctx_gt, np.r_[i, j], np.r_[j, i])):
            mask = ca.tracks.valid[pi] & cb.tracks.valid[pj]
            both = np.maximum(mask.sum(1), 1)
            st_i = (ca.speed[pi] * mask).sum(1) / both <= STATIONARY_MPS
            st_j = (cb.speed[pj] * mask).sum(1) / both <= STATIONARY_MPS
            got = _agent_mttcp(ca, cb, pi, pj, st_i, st_j, mask)
            ref = agent_mttcp_reference(ca, cb, pi, pj, st_i, st_j, mask)
            np.testing.assert_array_equal(got > 0, ref > 0)
            # The reference works on float32 positions; the social score caps the feature at 4 (1 / 0.25 s).
            np.testing.assert_allclose(np.minimum(got, 4.0), np.minimum(ref, 4.0), rtol=1e-3)
            n_conflicts += int((ref > 0).sum())
    assert n_conflicts > 100


def test_polyline_kernels_match_polyline() -> None:
    rng = np.random.default_rng(1)
    ang = np.linspace(0.0, 1.5, 40)
    line = Polyline(np.stack([50.0 * np.cos(ang), 50.0 * np.sin(ang)], axis=1))
    for xy in rng.uniform(-20.0, 70.0, size=(50, 2)):
        s, d, k = polyline_project(line.points, line.cum, line.tang, line.seg_len, float(xy[0]), float(xy[1]))
        s_ref, d_ref, tangent = line.project(xy)
        assert (s, d) == pytest.approx((s_ref, d_ref), abs=1e-9)
        np.testing.assert_array_equal(line.tang[int(k)], tangent)
    s = np.concatenate([[-5.0, 0.0], rng.uniform(0.0, line.length, 30), [line.length, line.length + 7.0]])
    for d in (0.0, 1.5, -2.0):
        pts, head, seg = polyline_at(line.points, line.cum, line.tang, line.vertex_tang, s, d)
        pts_ref, head_ref = line.at(s, d)
        np.testing.assert_allclose(pts, pts_ref, atol=1e-9)
        np.testing.assert_allclose(head, head_ref, atol=1e-12)
        np.testing.assert_array_equal(seg, np.clip(np.searchsorted(line.cum, s, side="right") - 1, 0, 38))


def test_rank_by_dwell_orders_by_time_then_first_visit() -> None:
    lanes = np.array([-1, 3, 3, 1, 1, 1, 5, 5, 5, -1, 2], dtype=np.int64)
    assert rank_by_dwell(lanes).tolist() == [1, 5, 3, 2]
    assert rank_by_dwell(np.array([-1, -1], dtype=np.int64)).tolist() == []


def test_contact_kernel_matches_the_numpy_reference(generated: list[Scenario]) -> None:
    n_contacts = 0
    for s in generated:
        index = road_index(s.road)
        gt = from_tracks(s.tracks, index)
        fe = future_extrapolate(gt, index)
        ctx_gt, ctx_fe = TrackContext(gt, index), TrackContext(fe, index)
        i, j = np.triu_indices(gt.n_agents, 1)
        variants = ((ctx_gt, ctx_gt, i, j), (ctx_fe, ctx_fe, i, j), (ctx_fe, ctx_gt, np.r_[i, j], np.r_[j, i]))
        for ca, cb, pi, pj in variants:
            mask = ca.tracks.valid[pi] & cb.tracks.valid[pj]
            a, b = ca.tracks, cb.tracks
            pos_i, pos_j = a.pos[pi], b.pos[pj]
            dist = np.hypot(ca.x[pi] - cb.x[pj], ca.y[pi] - cb.y[pj])
            ref = collisions_reference(a, b, pi, pj, pos_i, pos_j, dist, mask)
            np.testing.assert_array_equal(_collisions(ca, cb, pi, pj, mask), ref)
            n_contacts += int(ref.sum())
    assert n_contacts > 0
