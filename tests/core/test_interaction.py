"""The interaction rules both window finders share (`seal.core.interaction`)."""

from __future__ import annotations

import numpy as np

from seal.core.interaction import (
    CONFLICT_DIST_M,
    NEAR_M,
    context_rows,
    crossing_hits,
    is_moving,
    near_pair_distances,
    near_pairs,
)


def _continuous_traffic(n: int = 30, steps: int = 200, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Vehicles on random straight paths at up to 30 m/s, each valid over one contiguous span."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(-300, 300, (n, 1, 2))
    vel = rng.uniform(-3.0, 3.0, (n, 1, 2))  # m per 10 Hz step
    xy = start + vel * np.arange(steps)[None, :, None]
    first = rng.integers(0, steps // 2, n)
    last = first + rng.integers(20, steps // 2, n)
    t = np.arange(steps)[None]
    return xy, (t >= first[:, None]) & (t <= last[:, None])


def test_the_fast_near_pairs_agree_with_the_general_ones_on_continuous_logs() -> None:
    xy, valid = _continuous_traffic()
    i, j, dist = near_pair_distances(xy, valid)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == near_pairs(xy, valid)
    assert len(i) > 0 and (dist.min(axis=1) < NEAR_M).all()
    both = valid[i] & valid[j]
    assert np.isinf(dist[~both]).all()


def test_crossing_needs_closeness_timing_and_a_turn() -> None:
    steps = np.arange(0, 40, 2)
    east = np.stack([steps * 1.0, np.zeros(steps.size)], axis=1)
    north = np.stack([np.full(steps.size, 20.0), (steps - 20) * 1.0], axis=1)
    hit, dt = crossing_hits(east, steps, np.zeros(steps.size), north, steps, np.full(steps.size, np.pi / 2))
    assert hit.any() and (dt[hit] <= 2.5).all()
    a, b = np.nonzero(hit)
    assert (np.linalg.norm(east[a] - north[b], axis=1) < CONFLICT_DIST_M).all()
    # Following the same path is not a crossing.
    hit, _ = crossing_hits(east, steps, np.zeros(steps.size), east, steps + 1, np.zeros(steps.size))
    assert not hit.any()


def test_moving_and_context() -> None:
    xy = np.stack([np.arange(20) * 1.0, np.zeros(20)], axis=1)
    assert is_moving(np.full(20, 10.0), xy)
    assert not is_moving(np.full(20, 1.0), xy)  # too slow on average
    assert not is_moving(np.full(20, 10.0), xy[:5])  # too little displacement
    pos = np.zeros((4, 3, 2))
    pos[1, :, 0] = 5.0
    pos[2, :, 0] = 79.0
    pos[3, :, 0] = 81.0
    valid = np.ones((4, 3), dtype=bool)
    assert context_rows(pos, valid, 0, 1) == (2, 3)  # row 3 is within 80 m of the adversary at x = 5
    pos[3, :, 0] = 120.0
    assert context_rows(pos, valid, 0, 1) == (2,)
