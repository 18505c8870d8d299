"""Cut 9.1 s scenario windows around interacting vehicle pairs out of a logged traffic run.

An *event* is a moment where two vehicles interact: their bodies come within `EVENT_GAP_M` (a local minimum of
the box gap, or a collision) other than by driving in neighbouring lanes (see `in_own_lanes`: with 4 m lanes
and 2 m wide cars every overtake passes within 2 m, which is lane keeping, not an interaction), or their paths
cross with less than `CONFLICT_DT_S` between their passages of
the crossing point (one yields to the other). For each event a window start ``t0`` is drawn so that the event
falls in steps 25..75 of the window (an adversary then has time to act before it and the ego time to react).
A window is kept when both vehicles exist over the whole window, both move (mean speed > 2 m/s and more than
10 m travelled) and, in the future part (steps 10..90), their gap falls below `EVENT_GAP_M` or their paths
cross (within `CONFLICT_DT_S`); oncoming vehicles merely passing each other in their own lanes do not count.
Qualifying windows are drawn uniformly (those whose closest approach falls in the preferred steps first), so
the pool keeps the natural mix of routine interactions, near misses and crashes, and at most ``cap`` are taken
per run, each with a distinct pair and each vehicle in at most two of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.core.geometry import box_corners, box_gap, wrap_angle
from seal.core.interaction import (
    CROSSING_TURN_RAD,
    EVENT_GAP_M,
    MAX_PER_AGENT,
    context_rows,
    is_moving,
    near_pair_distances,
)
from seal.core.interaction import in_own_lanes as own_lanes
from seal.core.scenario import CURRENT_STEP, N_STEPS
from seal.envs.traffic_kernels import path_crossings
from seal.envs.traffic_run import RunLog

EVENT_STEPS = (25, 75)
"""Preferred window steps for the closest approach / conflict."""


@dataclass(frozen=True)
class Window:
    """One scenario window: steps ``t0 .. t0 + 90`` of the run, with the pair and context rows of the log."""

    t0: int
    ego: int
    adv: int
    others: tuple[int, ...]
    min_gap_m: float
    pair_collision: bool
    any_collision: bool


def _run_corners(log: RunLog, row: int, steps: slice | np.ndarray) -> np.ndarray:
    """Box corners ``[K, 4, 2]`` of vehicle ``row`` at ``steps``."""
    s = log.states[row, steps]
    return box_corners(s[..., 0], s[..., 1], s[..., 2], s[..., 4], s[..., 5])


def in_own_lanes(log: RunLog, i: int, j: int, steps: np.ndarray) -> np.ndarray:
    """``[K]`` bool: at ``steps``, ``i`` and ``j`` keep to their own lanes (`seal.core.interaction.in_own_lanes`)."""
    si, sj = log.states[i, steps], log.states[j, steps]
    return own_lanes(si[:, :2], si[:, 2], si[:, 5], sj[:, :2], sj[:, 2], sj[:, 5])


def interaction_gap(log: RunLog, i: int, j: int, steps: np.ndarray) -> np.ndarray:
    """``[K]`` box gap (m) of ``i`` and ``j`` at ``steps``, inf where they keep to their own lanes."""
    g = box_gap(_run_corners(log, i, steps), _run_corners(log, j, steps))
    return np.where(in_own_lanes(log, i, j, steps), np.inf, g)


@dataclass(frozen=True)
class _Pairs:
    """Vehicle pairs ``(i[p], j[p])``, i < j, that come within `NEAR_M`; ``dist`` ``[P, T]`` centre distances
    (m), inf where one of them does not exist."""

    i: np.ndarray
    j: np.ndarray
    dist: np.ndarray


def _near_pairs(log: RunLog) -> _Pairs:
    """`seal.core.interaction.near_pair_distances` of the run (its logs are continuous)."""
    return _Pairs(*near_pair_distances(log.states[..., :2], log.valid))


def _pair_gaps(log: RunLog, pairs: _Pairs) -> dict[tuple[int, int], np.ndarray]:
    """Interaction gap (m, `interaction_gap`) over time of every pair that ever comes within `EVENT_GAP_M`; inf
    where farther, absent or in their own lanes."""
    t = log.valid.shape[1]
    diag = np.hypot(log.states[..., 4], log.states[..., 5])
    diag = np.nanmax(np.where(log.valid, diag, np.nan), axis=1)
    close = pairs.dist < ((diag[pairs.i] + diag[pairs.j]) / 2 + EVENT_GAP_M)[:, None]
    sel = np.flatnonzero(close.any(axis=1))
    # All pairs' close steps in one `interaction_gap` call (its operations are elementwise, so batching changes
    # no bit; one call per pair was most of the window finder's time).
    pp, steps = np.nonzero(close[sel])
    rows_i, rows_j = pairs.i[sel][pp], pairs.j[sel][pp]
    si, sj = log.states[rows_i, steps], log.states[rows_j, steps]
    g_all = box_gap(
        box_corners(si[:, 0], si[:, 1], si[:, 2], si[:, 4], si[:, 5]),
        box_corners(sj[:, 0], sj[:, 1], sj[:, 2], sj[:, 4], sj[:, 5]),
    )
    own = own_lanes(si[:, :2], si[:, 2], si[:, 5], sj[:, :2], sj[:, 2], sj[:, 5])
    g_all = np.where(own, np.inf, g_all)
    gaps = np.full((len(sel), t), np.inf)
    gaps[pp, steps] = g_all
    return {(int(pairs.i[p]), int(pairs.j[p])): gaps[k] for k, p in enumerate(sel.tolist())}


def _conflicts(log: RunLog, i: int, j: int, lo: int, hi: int) -> list[tuple[int, float]]:
    """Path crossings of ``i`` and ``j`` in steps ``lo..hi-1`` (every 2nd step): (step when the second passes, dt
    in s), in row-major order of the two vehicles' steps (`seal.core.interaction.crossing_hits`, compiled)."""
    steps, dts = path_crossings(log.states, log.valid, i, j, lo, hi)
    return list(zip(steps.tolist(), dts.tolist(), strict=True))


def _events(log: RunLog, gaps: dict[tuple[int, int], np.ndarray], pairs: _Pairs) -> list[tuple[int, int, int]]:
    """(i, j, event step) for gap minima below `EVENT_GAP_M`, collisions and path conflicts."""
    events: list[tuple[int, int, int]] = []
    for (i, j), g in gaps.items():
        below = g < EVENT_GAP_M
        if not below.any():
            continue
        # Local minimum of each contiguous stretch below the threshold.
        edges = np.flatnonzero(np.diff(np.concatenate([[0], below.astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            events.append((i, j, int(a + np.argmin(g[a:b]))))
    for step, i, j in log.collisions:
        events.append((min(i, j), max(i, j), int(step)))
    # Path conflicts among the other near pairs while they head different ways (the heading test for all pairs
    # at once: elementwise, so the same bits as pair by pair).
    head = log.states[..., 2]
    finite = np.isfinite(pairs.dist)
    with np.errstate(invalid="ignore"):  # NaN headings where a vehicle does not exist; masked by `finite`
        turning = ((np.abs(wrap_angle(head[pairs.i] - head[pairs.j])) > CROSSING_TURN_RAD) & finite).any(axis=1)
    for p in np.flatnonzero(turning).tolist():
        i, j = int(pairs.i[p]), int(pairs.j[p])
        if (i, j) in gaps and (gaps[(i, j)] < EVENT_GAP_M).any():
            continue  # already an event pair
        common = np.flatnonzero(finite[p])
        hits = _conflicts(log, i, j, int(common[0]), int(common[-1]) + 1)
        if hits:
            events.append((i, j, min(hits, key=lambda h: h[1])[0]))
    return events


def _moving(log: RunLog, row: int, t0: int) -> bool:
    """`seal.core.interaction.is_moving` over the window starting at ``t0``."""
    s = log.states[row, t0 : t0 + N_STEPS]
    return is_moving(s[:, 3], s[:, :2])


def _span(valid: np.ndarray) -> tuple[int, int]:
    idx = np.flatnonzero(valid)
    return int(idx[0]), int(idx[-1])


def find_windows(log: RunLog, rng: np.random.Generator, cap: int, min_t0: int = 0) -> list[Window]:
    """Up to ``cap`` scenario windows of the run (module docstring); ego/adv roles drawn with ``rng``."""
    n_steps = log.valid.shape[1]
    if n_steps < N_STEPS:
        return []
    pairs = _near_pairs(log)
    gaps = _pair_gaps(log, pairs)
    collided = {(min(a, b), max(a, b)): s for s, a, b in log.collisions}
    candidates: list[tuple[float, int, int, int, float, bool, int]] = []
    seen: set[tuple[int, int, int]] = set()
    for i, j, t_ev in sorted(_events(log, gaps, pairs)):
        lo = max(_span(log.valid[i])[0], _span(log.valid[j])[0], min_t0)
        hi = min(_span(log.valid[i])[1], _span(log.valid[j])[1]) - (N_STEPS - 1)
        a, b = max(lo, t_ev - EVENT_STEPS[1]), min(hi, t_ev - EVENT_STEPS[0])
        if a > b:  # fall back to any future step for the event
            a, b = max(lo, t_ev - (N_STEPS - 2)), min(hi, t_ev - CURRENT_STEP - 2)
            if a > b:
                continue
        t0 = int(rng.integers(a, b + 1))
        if (i, j, t0) in seen or not (_moving(log, i, t0) and _moving(log, j, t0)):
            continue
        seen.add((i, j, t0))
        fut = slice(t0 + CURRENT_STEP, t0 + N_STEPS)
        g = box_gap(_run_corners(log, i, fut), _run_corners(log, j, fut))
        min_gap = float(g.min())
        g_interaction = np.where(in_own_lanes(log, i, j, np.arange(fut.start, fut.stop)), np.inf, g)
        t_min = int(np.argmin(g_interaction)) + CURRENT_STEP
        conflict = bool(_conflicts(log, i, j, t0 + CURRENT_STEP, t0 + N_STEPS))
        if g_interaction.min() >= EVENT_GAP_M and not conflict:
            continue
        pair_collision = (i, j) in collided and t0 <= collided[(i, j)] < t0 + N_STEPS
        turn = np.abs(wrap_angle(log.states[i, fut, 2] - log.states[j, fut, 2]))
        if np.median(turn) > 2.4 and g_interaction.min() > 1.0 and not conflict:
            continue  # oncoming traffic passing in its own lane is not an interaction
        # Rank: a uniform draw among qualifying interactions, so the pool keeps their natural mix of routine
        # interactions, near misses and crashes (ranking closest-first made nearly every pair a near miss and
        # left no long tail for scenario scoring to find); events outside the preferred steps come last.
        score = float(rng.uniform(0.0, 1.0))
        if not EVENT_STEPS[0] <= t_min <= EVENT_STEPS[1]:
            score += 1.0
        candidates.append((score, i, j, t0, min_gap, pair_collision, t_min))
    candidates.sort(key=lambda c: (c[0], c[1], c[2], c[3]))

    chosen: list[Window] = []
    used_pairs: set[tuple[int, int]] = set()
    uses: dict[int, int] = {}
    for _, i, j, t0, min_gap, pair_collision, _ in candidates:
        if len(chosen) >= cap:
            break
        if (i, j) in used_pairs or uses.get(i, 0) >= MAX_PER_AGENT or uses.get(j, 0) >= MAX_PER_AGENT:
            continue
        used_pairs.add((i, j))
        uses[i] = uses.get(i, 0) + 1
        uses[j] = uses.get(j, 0) + 1
        ego, adv = (i, j) if rng.random() < 0.5 else (j, i)
        others = _context(log, ego, adv, t0)
        members = {ego, adv, *others}
        any_collision = any(
            a in members and b in members and t0 <= s < t0 + N_STEPS for s, a, b in log.collisions
        )
        chosen.append(Window(t0, ego, adv, tuple(others), min_gap, bool(pair_collision), bool(any_collision)))
    return chosen


def _context(log: RunLog, ego: int, adv: int, t0: int) -> list[int]:
    """Rows valid in the window that come within `CONTEXT_M` of the ego or the adversary
    (`seal.core.interaction.context_rows`)."""
    win = slice(t0, t0 + N_STEPS)
    return list(context_rows(log.states[:, win, :2], log.valid[:, win], ego, adv))


def window_tracks(log: RunLog, w: Window) -> tuple[np.ndarray, np.ndarray]:
    """(tracks ``[A, 91, 8]`` float32, `seal.core.scenario.TRACK_FIELDS` order, in the map frame (y mirrored, see
    `seal.envs.layouts.describe_network`); agent ids ``[A]``): ego, adv, then the others."""
    rows = np.array([w.ego, w.adv, *w.others], dtype=np.int64)
    s = log.states[rows, w.t0 : w.t0 + N_STEPS]
    valid = log.valid[rows, w.t0 : w.t0 + N_STEPS]
    speed = s[..., 3]
    # highway-env's frame has y pointing down (its traffic keeps right on screen); scenarios use the map frame
    # (y up, heading counter-clockwise), so y and heading are mirrored: right-hand traffic like real logs.
    heading = -s[..., 2]
    tracks = np.stack(
        [
            s[..., 0],
            -s[..., 1],
            heading,
            speed * np.cos(heading),
            speed * np.sin(heading),
            s[..., 4],
            s[..., 5],
            valid.astype(np.float64),
        ],
        axis=-1,
    )
    tracks[~valid] = 0.0
    return tracks.astype(np.float32), rows
