"""Compiled kernels of base-scenario generation (`seal.envs.traffic_kernels`) against the numpy code they replaced
(kept here as the reference), and a fingerprint of generated runs, so that a speed-up that changes a bit fails."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from seal.core.geometry import box_corners, box_gap, boxes_overlap
from seal.core.interaction import EVENT_GAP_M, crossing_hits
from seal.envs.generate import RUN_STEPS, RunTask, run_rng, simulate_run
from seal.envs.layouts import LAYOUTS, sample_params
from seal.envs.traffic_kernels import contact_pairs, first_overlaps, path_crossings
from seal.envs.traffic_run import RunLog, Simulation
from seal.envs.windows import _near_pairs, _pair_gaps, interaction_gap

SHARES = (0.7, 0.15, 0.15)


# ------------------------------------------------------------------------------------------ numpy references
def _separation_ref(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    axes = np.concatenate([a[..., 1:3, :] - a[..., 0:2, :], b[..., 1:3, :] - b[..., 0:2, :]], axis=-2)
    axes = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
    pa = np.einsum("...kd,...cd->...kc", axes, a)
    pb = np.einsum("...kd,...cd->...kc", axes, b)
    return np.maximum(pb.min(-1) - pa.max(-1), pa.min(-1) - pb.max(-1)).max(-1)


def _contact_pairs_ref(state: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The pre-check `TrafficRoad.step` ran in numpy before `contact_pairs`."""
    reach = np.hypot(state[:, 3], state[:, 4]) / 2 + np.abs(state[:, 5]) * dt
    d = np.linalg.norm(state[:, None, :2] - state[None, :, :2], axis=-1)
    ii, jj = np.nonzero(np.triu(d <= reach[:, None] + reach[None] + 0.5, 1))
    if not ii.size:
        return ii, jj
    corners = box_corners(state[:, 0], state[:, 1], state[:, 2], state[:, 3], state[:, 4])
    vel = state[:, 5:6] * np.stack([np.cos(state[:, 2]), np.sin(state[:, 2])], axis=1)
    rel = np.linalg.norm(vel[ii] - vel[jj], axis=1) * dt
    touch = _separation_ref(corners[ii], corners[jj]) <= rel + 0.1
    return ii[touch], jj[touch]


def _traffic_state(rng: np.random.Generator, n: int) -> np.ndarray:
    """Dense random traffic on a 60 m square: many touching, near and far pairs."""
    return np.column_stack([
        rng.uniform(0, 60, n), rng.uniform(0, 60, n), rng.uniform(-np.pi, np.pi, n),
        rng.uniform(4.0, 10.0, n), rng.uniform(1.7, 2.5, n), rng.uniform(0.0, 30.0, n),
    ])


def test_contact_pairs_match_the_numpy_pre_check() -> None:
    rng = np.random.default_rng(0)
    found = 0
    for n in (2, 3, 10, 40, 80):
        for _ in range(20):
            state = _traffic_state(rng, n)
            ki, kj = contact_pairs(state, 0.1)
            ri, rj = _contact_pairs_ref(state, 0.1)
            assert np.array_equal(ki, ri) and np.array_equal(kj, rj)
            found += ki.size
    assert found > 100  # the draws exercise the test, not only the distance pre-filter


def test_first_overlaps_match_the_pairwise_box_tests() -> None:
    rng = np.random.default_rng(1)
    n, k = 30, 11
    pos = rng.uniform(0, 40, (n, 1, 2)) + np.cumsum(rng.normal(0, 2, (n, k, 2)), axis=1)
    head = rng.uniform(-np.pi, np.pi, (n, k))
    corners = box_corners(pos[..., 0], pos[..., 1], head, rng.uniform(6, 12, (n, 1)), rng.uniform(1.5, 2.3, (n, 1)))
    ii, jj = np.nonzero(np.triu(np.ones((n, n), dtype=bool), 1))
    close = rng.random((ii.size, k, k)) < 0.4
    ka, kb = first_overlaps(corners, ii, jj, close)
    hits = 0
    for p in range(ii.size):
        a, b = np.nonzero(close[p])
        overlap = boxes_overlap(corners[ii[p]][a], corners[jj[p]][b])
        if overlap.any():
            assert (ka[p], kb[p]) == (a[overlap].min(), b[overlap].min())
            hits += 1
        else:
            assert (ka[p], kb[p]) == (-1, -1)
    assert 20 < hits < ii.size


# ------------------------------------------------------------------------------------------ runs
@pytest.fixture(scope="module")
def logs() -> list[RunLog]:
    """One simulated run per layout."""
    out = []
    for layout in LAYOUTS:
        rng = run_rng(4, 2)
        out.append(Simulation(layout, sample_params(layout, rng), rng, SHARES).run(RUN_STEPS))
    return out


def _conflicts_ref(log: RunLog, i: int, j: int, lo: int, hi: int) -> list[tuple[int, float]]:
    """`seal.envs.windows._conflicts` in numpy, as it was before `path_crossings`."""
    steps = np.arange(lo, hi, 2)
    vi, vj = log.valid[i, steps], log.valid[j, steps]
    if not vi.any() or not vj.any():
        return []
    si, sj = log.states[i, steps], log.states[j, steps]
    hit, dt = crossing_hits(si[:, :2], steps, si[:, 2], sj[:, :2], steps, sj[:, 2])
    hit &= vi[:, None] & vj[None]
    return [(int(max(steps[a], steps[b])), float(dt[a, b])) for a, b in zip(*np.nonzero(hit), strict=True)]


def test_path_crossings_match_the_numpy_crossing_test(logs: list[RunLog]) -> None:
    hits = 0
    for log in logs:
        pairs = _near_pairs(log)
        for p in range(len(pairs.i)):
            i, j = int(pairs.i[p]), int(pairs.j[p])
            for lo, hi in ((0, RUN_STEPS), (13, 104), (50, 51), (60, 60)):
                steps, dts = path_crossings(log.states, log.valid, i, j, lo, hi)
                ref = _conflicts_ref(log, i, j, lo, hi)
                assert list(zip(steps.tolist(), dts.tolist(), strict=True)) == ref
                hits += len(ref)
    assert hits > 0


def test_batched_pair_gaps_match_pair_by_pair(logs: list[RunLog]) -> None:
    for log in logs:
        pairs = _near_pairs(log)
        gaps = _pair_gaps(log, pairs)
        diag = np.nanmax(np.where(log.valid, np.hypot(log.states[..., 4], log.states[..., 5]), np.nan), axis=1)
        close = pairs.dist < ((diag[pairs.i] + diag[pairs.j]) / 2 + EVENT_GAP_M)[:, None]
        ref = {}
        for p in np.flatnonzero(close.any(axis=1)):
            i, j = int(pairs.i[p]), int(pairs.j[p])
            steps = np.flatnonzero(close[p])
            g = np.full(log.valid.shape[1], np.inf)
            g[steps] = interaction_gap(log, i, j, steps)
            ref[(i, j)] = g
        assert gaps.keys() == ref.keys()
        assert all(np.array_equal(gaps[k], ref[k]) for k in ref)
    # `interaction_gap` itself is `box_gap` where the vehicles do not keep to their own lanes.
    s = logs[0].states[:2, 100]
    assert box_gap(box_corners(*s[0, [0, 1, 2, 4, 5]]), box_corners(*s[1, [0, 1, 2, 4, 5]])) >= 0.0


# The SHA-256 of one generated run per layout (tracks, ids, roles, metadata), as generated before the speed-ups
# of issue 23 (commit 55cf447). A change of the generated data must bump `GENERATOR_VERSION` and this digest.
GENERATED_DIGEST = "3fc83a4e8f0fe22390ef24faf1b55d549c16af2055e9466647d276d3ca5269db"


def generated_digest() -> str:
    """Digest of `simulate_run` for run 1 of seed 5 on every layout."""
    h = hashlib.sha256()
    for layout in LAYOUTS:
        for s in simulate_run(RunTask(run=1, layout=layout, seed=5, kind_shares=SHARES)):
            h.update(s.scenario_id.encode())
            h.update(np.ascontiguousarray(s.tracks).tobytes())
            h.update(np.ascontiguousarray(s.agent_ids).tobytes())
            h.update(json.dumps([s.ego_id, s.adv_id, dict(s.metadata)], sort_keys=True).encode())
    return h.hexdigest()


def test_generated_runs_are_bit_identical_to_the_reference() -> None:
    assert generated_digest() == GENERATED_DIGEST
