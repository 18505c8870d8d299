"""Cut 9.1 s scenario windows around interacting (ego, adversary) pairs out of a recorded `AgentLog`.

Same interaction criteria as the generated pool (`seal.envs.windows`): both call the rules and thresholds of
`seal.core.interaction`: two vehicles interact when their bodies come within `EVENT_GAP_M` other than by driving side
by side in their own lanes (`side_by_side`, which also asks them to be alongside: see `seal.core.interaction`), or
their paths cross with less than `CONFLICT_DT_S` between their passages of the crossing point.
Differences for recorded data, and why:

* Recordings may be shorter than 9.1 s (CommonRoad benchmark excerpts are 3-10 s). A window needs both focal
  agents over the full 1.1 s history and at least ``min_future_steps`` future steps; steps past the end of the
  recording are padded as invalid (`PairWindow.logged_steps` tells how many are real).
* The choice is deterministic (no random draw). The window is placed so that the pair's closest approach comes
  at least `EVENT_MIN_STEP` into it, with as many logged steps of the pair as the recording has, and then as
  near window step `EVENT_AT_STEP` as possible. Qualifying pairs are ranked lane changes / merges / crossings
  first, then by closest approach, so the most safety-relevant interactions of a recording come first.
* Roles: the adversary is the agent that changes lane (the one cutting in or merging); when both or neither do,
  the one ahead of the other at the current step.
* Each pair is used once and each agent in at most `MAX_PER_AGENT` windows (variety across windows).
* Agents whose log has gaps within a window (ScenarioNet ``valid`` masks) keep one contiguous block: the one
  holding the current step, else the longest; the focal agents must be valid without gap from the window start
  through the minimum future.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from seal.core.geometry import box_gap, boxes_overlap, track_corners
from seal.core.importers.lane_index import AgentLanes, LaneIndex
from seal.core.importers.tracks import AgentLog
from seal.core.interaction import (
    EVENT_GAP_M,
    MAX_PER_AGENT,
    NEAR_M,
    context_rows,
    crossing_hits,
    in_own_lanes,
    is_moving,
)
from seal.core.interaction import near_pairs as _near_pairs
from seal.core.road import RoadDescription
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, N_STEPS, VALID, VX, VY, WIDTH, X, Y

EVENT_AT_STEP = 40
"""Preferred window step of the pair's closest approach (3 s into the future)."""
EVENT_MIN_STEP = CURRENT_STEP + 5
"""The closest approach should come at least 0.5 s after the current step (time to react)."""
MIN_FUTURE_STEPS = 20
"""Default minimum number of logged future steps (2 s) of both focal agents."""
FOCAL_TYPES = ("vehicle",)
"""Agent types that can be the ego or the adversary (both are driven by the bicycle model)."""


@dataclass(frozen=True)
class PairWindow:
    """One scenario window: recording steps ``t0 .. t0 + 90`` with the pair and the context rows of the log.

    Attributes:
        t0: first recording step of the window.
        ego, adv: rows of the focal agents in the log.
        others: rows of the context agents.
        min_gap_m: closest body gap (m) of the pair over the window's future steps (0 = overlap).
        min_gap_step: window step of that closest approach.
        conflict: the pair's paths cross within `CONFLICT_DT_S`.
        lane_change: the ego or the adversary changes lane in the window.
        pair_collision: the pair's boxes overlap at some window step.
        any_collision: some two agents of the window overlap at some step.
        logged_steps: window steps ``0 .. logged_steps - 1`` lie inside the recording (the rest are padding).
    """

    t0: int
    ego: int
    adv: int
    others: tuple[int, ...]
    min_gap_m: float
    min_gap_step: int
    conflict: bool
    lane_change: bool
    pair_collision: bool
    any_collision: bool
    logged_steps: int


# ------------------------------------------------------------------------------------------ per-agent helpers
def run_ends(valid: np.ndarray) -> np.ndarray:
    """``[N, T]`` last step of the contiguous valid run holding each step (-1 where invalid)."""
    n, t = valid.shape
    out = np.full((n, t), -1, dtype=np.int64)
    nxt = np.full(n, -1, dtype=np.int64)
    for k in range(t - 1, -1, -1):
        nxt = np.where(valid[:, k], np.where(nxt >= 0, nxt, k), -1)
        out[:, k] = nxt
    return out


def keep_one_block(valid: np.ndarray, prefer: int) -> np.ndarray:
    """``valid`` ``[T]`` reduced to one contiguous block: the one holding step ``prefer`` if valid there, else the
    longest (the first of equally long ones)."""
    idx = np.flatnonzero(valid)
    if idx.size == 0:
        return valid.copy()
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    if valid[prefer]:
        k = int(np.flatnonzero((starts <= prefer) & (ends >= prefer))[0])
    else:
        k = int(np.argmax(ends - starts))
    out = np.zeros_like(valid)
    out[starts[k] : ends[k] + 1] = True
    return out


def _moving(tracks: np.ndarray) -> bool:
    """`seal.core.interaction.is_moving` over the valid rows of ``[K, 8]``."""
    v = tracks[tracks[:, VALID] > 0.5]
    if len(v) < 2:
        return False
    return is_moving(np.hypot(v[:, VX], v[:, VY]), v[:, [X, Y]])


def side_by_side(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[T]`` bool for two ``[T, 8]`` tracks: alongside each other in their own lanes
    (`seal.core.interaction.in_own_lanes` with the lengthwise-overlap condition)."""
    return in_own_lanes(
        a[:, [X, Y]], a[:, HEADING], a[:, WIDTH], b[:, [X, Y]], b[:, HEADING], b[:, WIDTH],
        lengths_m=(a[:, LENGTH], b[:, LENGTH]),
    )


def _crossing(a: np.ndarray, b: np.ndarray) -> bool:
    """Paths of ``[K, 8]`` tracks (valid rows) cross within `CONFLICT_DIST_M` and `CONFLICT_DT_S` at a heading
    difference above 15 degrees (following in one lane is not a crossing)."""
    stride = 2
    ia = np.flatnonzero(a[:, VALID] > 0.5)[::stride]
    ib = np.flatnonzero(b[:, VALID] > 0.5)[::stride]
    if ia.size == 0 or ib.size == 0:
        return False
    hit, _ = crossing_hits(a[ia, :2], ia, a[ia, HEADING], b[ib, :2], ib, b[ib, HEADING])
    return bool(hit.any())


# ------------------------------------------------------------------------------------------ window search
@dataclass(frozen=True)
class _Candidate:
    rank: tuple
    t0: int
    i: int
    j: int
    min_gap_m: float
    min_gap_step: int
    conflict: bool
    lane_change_i: bool
    lane_change_j: bool


def near_pairs(log: AgentLog, rows: list[int], block: int = 16) -> list[tuple[int, int]]:
    """Pairs ``(i, j)``, ``i < j`` among ``rows`` (ascending), whose centres come within `NEAR_M` at a step where
    both exist (`seal.core.interaction.near_pairs`)."""
    r = np.asarray(rows, dtype=np.int64)
    return [(int(r[p]), int(r[q])) for p, q in _near_pairs(log.tracks[r][..., :2], log.valid[r], block)]


def _pair_candidate(
    log: AgentLog, valid: np.ndarray, lanes: AgentLanes, ends: np.ndarray, i: int, j: int, min_future_steps: int,
    priority: int | None, require_interaction: bool,
) -> _Candidate | None:
    """The pair's best window, or None when it has none. ``priority``: the pair's place in a given order of
    adversaries (kept without an interaction event and ranked first, in that order); None for other pairs.
    ``valid`` is ``log.valid`` (computed once by the caller)."""
    forced = priority is not None
    n_steps = log.n_steps
    need = CURRENT_STEP + 1 + min_future_steps
    t = np.arange(n_steps)
    feasible = valid[i] & valid[j] & (ends[i] >= t + need - 1) & (ends[j] >= t + need - 1)
    starts = np.flatnonzero(feasible)
    if starts.size == 0:
        return None
    tr = log.tracks
    steps = np.flatnonzero(valid[i] & valid[j])
    dist = np.hypot(tr[i, steps, X] - tr[j, steps, X], tr[i, steps, Y] - tr[j, steps, Y])
    if require_interaction and dist.min() > NEAR_M:
        return None
    gaps = np.full(n_steps, np.inf)
    gaps[steps] = box_gap(track_corners(tr[i, steps]), track_corners(tr[j, steps]))
    igaps = np.where(side_by_side(tr[i], tr[j]), np.inf, gaps)
    # Closest approach after the earliest possible current step -> window start placing it at EVENT_AT_STEP.
    later = igaps.copy()
    later[: starts[0] + CURRENT_STEP + 1] = np.inf
    event = int(np.argmin(later)) if np.isfinite(later).any() else int(starts[0] + CURRENT_STEP)
    t0 = _place(starts, ends[i], ends[j], event)

    win = slice(t0, t0 + N_STEPS)
    a = _focal_block(tr[i, win])
    b = _focal_block(tr[j, win])
    if not (_moving(a) and (forced or _moving(b))):
        return None
    both = (a[:, VALID] > 0.5) & (b[:, VALID] > 0.5)
    fut = np.where(both, gaps[t0 : t0 + both.shape[0]], np.inf)[CURRENT_STEP:]
    ifut = np.where(both, igaps[t0 : t0 + both.shape[0]], np.inf)[CURRENT_STEP:]
    k = int(np.argmin(fut))
    min_gap = float(fut[k])
    conflict = _crossing(a[CURRENT_STEP:], b[CURRENT_STEP:])
    interacting = float(ifut.min()) < EVENT_GAP_M or conflict
    if require_interaction and not forced and not interacting:
        return None
    lc_i = lanes.changes_lane(i, t0 + np.flatnonzero(a[:, VALID] > 0.5))
    lc_j = lanes.changes_lane(j, t0 + np.flatnonzero(b[:, VALID] > 0.5))
    lateral = interacting and (lc_i or lc_j or conflict)
    order = (0, priority) if forced else (1, 0)
    rank = (*order, 0 if interacting else 1, 0 if lateral else 1, float(ifut.min()), min_gap, t0, i, j)
    return _Candidate(rank, t0, i, j, min_gap, k + CURRENT_STEP, conflict, lc_i, lc_j)


def _place(starts: np.ndarray, end_i: np.ndarray, end_j: np.ndarray, event: int) -> int:
    """Window start among the feasible ``starts``: the event at least `EVENT_MIN_STEP` into the window (when
    possible), then the most logged steps of the pair, then the event closest to `EVENT_AT_STEP`."""
    offset = event - starts
    ok = (offset >= EVENT_MIN_STEP) & (offset < N_STEPS)
    if ok.any():
        starts = starts[ok]
    cover = np.minimum(np.minimum(end_i[starts], end_j[starts]), starts + N_STEPS - 1) - starts
    best = starts[cover == cover.max()]
    return int(best[np.argmin(np.abs(event - best - EVENT_AT_STEP))])


def _focal_block(window: np.ndarray) -> np.ndarray:
    """A focal agent's ``[<=91, 8]`` window rows with only the valid block holding the current step."""
    out = window.copy()
    keep = keep_one_block(out[:, VALID] > 0.5, CURRENT_STEP)
    out[~keep] = 0.0
    return out


def find_windows(
    log: AgentLog,
    road: RoadDescription,
    max_windows: int,
    min_future_steps: int = MIN_FUTURE_STEPS,
    ego_row: int | None = None,
    adv_rows: tuple[int, ...] = (),
    ego_ok: Callable[[np.ndarray], bool] | None = None,
) -> tuple[list[PairWindow], int]:
    """Up to ``max_windows`` windows of the recording (module docstring), best first, and how many windows were
    passed over because ``ego_ok`` refused their ego.

    Args:
        log: the recording on the 10 Hz grid.
        road: its road (for the lane-change test).
        max_windows: cap on the number of windows.
        min_future_steps: logged future steps both focal agents need (1..80).
        ego_row: fix the ego (e.g. the SDC of a ScenarioNet scenario); None: any vehicle.
        adv_rows: with ``ego_row``, adversaries to use in this order (objects of interest) before the most
            interacting other vehicle; these pairs are kept even without an interaction event.
        ego_ok: test of a window's ego rows ``[91, 8]`` (e.g. that its logged path stays on the mapped road); a
            refused window is passed over (counted) and the next best takes its place.
    """
    if not 1 <= min_future_steps <= N_STEPS - CURRENT_STEP - 1:
        raise ValueError(f"min_future_steps must be in [1, {N_STEPS - CURRENT_STEP - 1}], got {min_future_steps}")
    valid = log.valid
    lanes = AgentLanes(LaneIndex(road), log.tracks[..., :2], valid)
    ends = run_ends(valid)
    focal = [r for r in range(log.n_agents) if log.agent_types[r] in FOCAL_TYPES]
    pairs: list[tuple[int, int, int | None]]
    if ego_row is None:
        pairs = [(i, j, None) for i, j in near_pairs(log, focal)]
    else:
        forced = [r for r in adv_rows if r != ego_row and log.agent_types[r] in FOCAL_TYPES]
        pairs = [(ego_row, r, k) for k, r in enumerate(forced)]
        pairs += [(ego_row, r, None) for r in focal if r != ego_row and r not in forced]
    # A fixed ego always gets its most interacting partner, even without an interaction event.
    require = ego_row is None
    candidates = [
        c for i, j, priority in pairs
        if (c := _pair_candidate(log, valid, lanes, ends, i, j, min_future_steps, priority, require)) is not None
    ]
    candidates.sort(key=lambda c: c.rank)

    chosen: list[PairWindow] = []
    uses: dict[int, int] = {}
    refused = 0
    for c in candidates:
        if len(chosen) >= max_windows:
            break
        if ego_row is None and (uses.get(c.i, 0) >= MAX_PER_AGENT or uses.get(c.j, 0) >= MAX_PER_AGENT):
            continue
        ego, adv = (c.i, c.j) if ego_row is not None else _roles(log, c)
        if ego_ok is not None and not ego_ok(_cut(log, c.t0, (ego,))[0][0]):
            refused += 1
            continue
        uses[c.i] = uses.get(c.i, 0) + 1
        uses[c.j] = uses.get(c.j, 0) + 1
        chosen.append(_window(log, c, ego, adv))
    return chosen, refused


def _roles(log: AgentLog, c: _Candidate) -> tuple[int, int]:
    """(ego, adv): the adversary is the one that changes lane; else the one ahead at the current step."""
    if c.lane_change_i != c.lane_change_j:
        return (c.j, c.i) if c.lane_change_i else (c.i, c.j)
    s = log.tracks[:, c.t0 + CURRENT_STEP]
    h = s[c.i, HEADING]
    ahead = np.cos(h) * (s[c.j, X] - s[c.i, X]) + np.sin(h) * (s[c.j, Y] - s[c.i, Y])
    return (c.i, c.j) if ahead >= 0 else (c.j, c.i)


def _window(log: AgentLog, c: _Candidate, ego: int, adv: int) -> PairWindow:
    win = slice(c.t0, c.t0 + N_STEPS)
    logged = min(N_STEPS, log.n_steps - c.t0)
    others = context_rows(log.tracks[:, win, :2], log.valid[:, win], ego, adv)
    tracks, _ = _cut(log, c.t0, (ego, adv, *others))
    pair_collision = bool(_overlap_steps(tracks[0], tracks[1]).any())
    any_collision = pair_collision or _any_overlap(tracks)
    return PairWindow(
        t0=c.t0, ego=ego, adv=adv, others=others, min_gap_m=c.min_gap_m, min_gap_step=c.min_gap_step,
        conflict=c.conflict, lane_change=c.lane_change_i or c.lane_change_j, pair_collision=pair_collision,
        any_collision=any_collision, logged_steps=int(logged),
    )


def _overlap_steps(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    both = (a[:, VALID] > 0.5) & (b[:, VALID] > 0.5)
    out = np.zeros(len(a), dtype=bool)
    if both.any():
        out[both] = boxes_overlap(track_corners(a[both]), track_corners(b[both]))
    return out


def _any_overlap(tracks: np.ndarray) -> bool:
    """Some two agents' boxes overlap at some step of ``[A, T, 8]`` (centre-distance pre-filter, one SAT call)."""
    valid = tracks[:, :, VALID] > 0.5
    reach = 0.5 * np.hypot(tracks[:, :, LENGTH], tracks[:, :, WIDTH])
    dist = np.linalg.norm(tracks[:, None, :, :2] - tracks[None, :, :, :2], axis=-1)
    close = valid[:, None] & valid[None, :] & (dist <= reach[:, None] + reach[None, :])
    close &= np.triu(np.ones(close.shape[:2], dtype=bool), k=1)[:, :, None]
    a, b, t = np.nonzero(close)
    if a.size == 0:
        return False
    return bool(boxes_overlap(track_corners(tracks[a, t]), track_corners(tracks[b, t])).any())


def _cut(log: AgentLog, t0: int, rows: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    out = np.zeros((len(rows), N_STEPS, log.tracks.shape[2]), dtype=np.float64)
    logged = min(N_STEPS, log.n_steps - t0)
    out[:, :logged] = log.tracks[list(rows), t0 : t0 + logged]
    for k in range(len(rows)):
        keep = keep_one_block(out[k, :, VALID] > 0.5, CURRENT_STEP)
        out[k, ~keep] = 0.0
    return out, log.agent_ids[list(rows)]


def window_tracks(log: AgentLog, w: PairWindow) -> tuple[np.ndarray, np.ndarray]:
    """(tracks ``[A, 91, 8]`` float32 in `seal.core.scenario.TRACK_FIELDS` layout, agent ids ``[A]``): ego, adversary,
    then the context agents; steps past the recording are invalid, each agent keeps one contiguous block."""
    tracks, ids = _cut(log, w.t0, (w.ego, w.adv, *w.others))
    return tracks.astype(np.float32), ids
