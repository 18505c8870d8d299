"""When two vehicles interact: the rules shared by the scenario-window finders of the generator
(`seal.envs.windows`, on simulated traffic runs) and of the importers (`seal.core.importers.windows`, on
recordings). Both finders call these functions and read these thresholds; what differs between them is only how
a window is placed and chosen (a random draw for the generated pool, a deterministic ranking for recordings: see
their module docstrings) and the layout of their logs.

* Closeness: bodies within `EVENT_GAP_M` interact, except when the vehicles keep to their own lanes
  (`in_own_lanes`).
* Crossing: paths passing within `CONFLICT_DIST_M` of each other, both within `CONFLICT_DT_S`, at a heading
  difference above `CROSSING_TURN_RAD` (`crossing_hits`).
* Candidates: only pairs whose centres come within `NEAR_M` (`near_pairs`; `near_pair_distances` is its fast path
  for continuous simulated logs) and vehicles that move (`is_moving`);
  a window's context is every agent within `CONTEXT_M` of the ego or the adversary (`context_rows`); a vehicle
  is in at most `MAX_PER_AGENT` windows.

Own lanes: lanes are about 4 m wide and cars about 2 m wide, so every overtake on a multi-lane road passes within a
couple of metres; such closeness is not an interaction. Two vehicles keep to their own lanes when they drive parallel
or oncoming (headings within `PARALLEL_RAD` of 0 or pi) with a lateral body gap of at least `SIDE_GAP_M`.
"""

from __future__ import annotations

import numpy as np

from seal.core.geometry import wrap_angle
from seal.core.scenario import DT_S

EVENT_GAP_M = 5.0
"""Bodies closer than this (m) interact."""
CONFLICT_DIST_M = 1.5
"""Paths cross where they pass within this distance (m) of each other."""
CONFLICT_DT_S = 2.5
"""A crossing is a conflict when both pass it within this many seconds."""
CROSSING_TURN_RAD = float(np.radians(15))
"""Smallest heading difference (rad) at a crossing: following in one lane is not a crossing."""
NEAR_M = 30.0
"""Pairs whose centres never come closer than this (m) cannot interact."""
CONTEXT_M = 80.0
"""Other agents within this distance (m) of the ego or the adversary are part of the scenario."""
MIN_MEAN_SPEED_MPS = 2.0
"""A focal vehicle moves faster than this on average (m/s) ..."""
MIN_DISPLACEMENT_M = 10.0
"""... and travels more than this (m, first to last position) in its window."""
MAX_PER_AGENT = 2
"""Most windows a vehicle takes part in (variety across windows)."""
SIDE_GAP_M = 1.0
"""Parallel (or oncoming) vehicles whose bodies keep at least this lateral gap (m), measured across the first
vehicle's heading, are in their own lanes."""
PARALLEL_RAD = float(np.radians(20.0))
"""Largest heading difference (rad) from 0 or pi that still counts as parallel / oncoming."""


def in_own_lanes(
    xy_a: np.ndarray, heading_a: np.ndarray, width_a: np.ndarray,
    xy_b: np.ndarray, heading_b: np.ndarray, width_b: np.ndarray,
    lengths_m: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """``[...]`` bool: vehicles ``a`` and ``b`` keep to their own lanes (see the module docstring).

    Args:
        xy_a, xy_b: ``[..., 2]`` centre positions (m).
        heading_a, heading_b: ``[...]`` headings (rad).
        width_a, width_b: ``[...]`` body widths (m).
        lengths_m: body lengths ``([...], [...])`` (m) of ``a`` and ``b``; when given, the vehicles must also
            overlap along ``a``'s heading (be alongside). The importers use this: recorded freeway traffic is
            all parallel, and a neighbour ahead or behind in the next lane is where lane changes come from.
    """
    d = np.asarray(xy_b, dtype=np.float64) - np.asarray(xy_a, dtype=np.float64)
    lat = -d[..., 0] * np.sin(heading_a) + d[..., 1] * np.cos(heading_a)
    turn = np.abs(wrap_angle(np.asarray(heading_b) - np.asarray(heading_a)))
    parallel = (turn < PARALLEL_RAD) | (turn > np.pi - PARALLEL_RAD)
    own = parallel & (np.abs(lat) - 0.5 * (np.asarray(width_a) + np.asarray(width_b)) >= SIDE_GAP_M)
    if lengths_m is not None:
        lon = d[..., 0] * np.cos(heading_a) + d[..., 1] * np.sin(heading_a)
        own &= np.abs(lon) < 0.5 * (np.asarray(lengths_m[0]) + np.asarray(lengths_m[1]))
    return own


def crossing_hits(
    xy_a: np.ndarray, steps_a: np.ndarray, heading_a: np.ndarray,
    xy_b: np.ndarray, steps_b: np.ndarray, heading_b: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the paths of ``a`` and ``b`` cross (see the module docstring).

    Args:
        xy_a, xy_b: ``[Ka, 2]``, ``[Kb, 2]`` positions (m) of the two vehicles at ``steps_a``, ``steps_b``.
        steps_a, steps_b: ``[Ka]``, ``[Kb]`` their log steps (10 Hz).
        heading_a, heading_b: ``[Ka]``, ``[Kb]`` headings (rad).

    Returns:
        ``hit [Ka, Kb]`` bool (the paths cross there) and ``dt [Ka, Kb]`` (s between the two passages).
    """
    d = np.linalg.norm(xy_a[:, None] - xy_b[None], axis=-1)
    dt = np.abs(steps_a[:, None] - steps_b[None]) * DT_S
    turn = np.abs(wrap_angle(heading_a[:, None] - heading_b[None]))
    return (d < CONFLICT_DIST_M) & (dt <= CONFLICT_DT_S) & (turn > CROSSING_TURN_RAD), dt


def is_moving(speed_mps: np.ndarray, xy: np.ndarray) -> bool:
    """A focal vehicle moves: mean of ``speed_mps [K]`` above `MIN_MEAN_SPEED_MPS` and more than
    `MIN_DISPLACEMENT_M` between the first and the last of the positions ``xy [K, 2]`` (m)."""
    return bool(speed_mps.mean() > MIN_MEAN_SPEED_MPS and np.hypot(*(xy[-1] - xy[0])) > MIN_DISPLACEMENT_M)


def near_pairs(xy: np.ndarray, valid: np.ndarray, block: int = 16) -> list[tuple[int, int]]:
    """Pairs ``(p, q)``, ``p < q``, of rows of ``xy [R, T, 2]`` (m) whose centres come within `NEAR_M` at a step
    where both are ``valid [R, T]``, in row-major order (vectorised in blocks of rows, so large recordings stay
    within memory)."""
    pos = np.where(valid[..., None], xy, np.nan)
    out = []
    for a in range(0, len(pos), block):
        diff = pos[a : a + block, None] - pos[None]  # [block, R, T, 2]
        with np.errstate(invalid="ignore"):
            close = (np.nan_to_num(np.hypot(diff[..., 0], diff[..., 1]), nan=np.inf) < NEAR_M).any(axis=-1)
        for p, q in zip(*np.nonzero(close), strict=True):
            if a + p < q:
                out.append((int(a + p), int(q)))
    return out


def near_pair_distances(
    xy: np.ndarray, valid: np.ndarray, coarse_stride: int = 10, coarse_margin_m: float = 40.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`near_pairs` for simulated traffic runs, the fast path: a coarse pass on every ``coarse_stride``-th step
    with ``coarse_margin_m`` of slack (vehicles at most ~40 m/s move at most 2 x 5 steps x 4 m between samples),
    then the exact test on the candidates. Needs continuous logs (each vehicle valid from its spawn to its
    removal, as the generator's are); recordings with gaps take `near_pairs`.

    Args:
        xy: ``[R, T, 2]`` centre positions (m).
        valid: ``[R, T]`` bool.

    Returns:
        ``i [P]``, ``j [P]`` (``i < j``, row-major order) and ``dist [P, T]``: centre distances (m), inf where one
        of them does not exist.
    """
    x = np.where(valid, xy[..., 0], np.nan)
    y = np.where(valid, xy[..., 1], np.nan)
    k = coarse_stride
    dc = np.hypot(x[:, None, ::k] - x[None, :, ::k], y[:, None, ::k] - y[None, :, ::k])
    cand = np.triu(np.nan_to_num(dc, nan=np.inf).min(axis=-1) < NEAR_M + coarse_margin_m, 1)
    ii, jj = np.nonzero(cand)
    d = np.nan_to_num(np.hypot(x[ii] - x[jj], y[ii] - y[jj]), nan=np.inf)
    keep = d.min(axis=1) < NEAR_M
    return ii[keep], jj[keep], d[keep]


def context_rows(xy: np.ndarray, valid: np.ndarray, ego: int, adv: int) -> tuple[int, ...]:
    """Rows of a window (``xy [A, T, 2]`` in m, ``valid [A, T]``) other than ``ego`` and ``adv`` that come within
    `CONTEXT_M` of one of them at a step where both exist, ascending."""
    near = np.zeros(valid.shape[0], dtype=bool)
    for focal in (ego, adv):
        d = np.linalg.norm(xy - xy[focal][None], axis=-1)
        near |= (valid & valid[focal][None] & (d < CONTEXT_M)).any(axis=1)
    near[[ego, adv]] = False
    return tuple(int(r) for r in np.flatnonzero(near))
