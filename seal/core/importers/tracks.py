"""Recorded agents on the 10 Hz scenario grid: `AgentLog` and resampling of logged states.

Importers turn each agent's logged states (at the recording's own rate) into rows of one ``[N, T, 8]`` array in
`seal.core.scenario.TRACK_FIELDS` layout on the global 10 Hz grid ``t_n = n * DT_S`` (step ``n`` of the recording).
`resample_states` does the conversion: linear interpolation of positions, velocities and sizes, headings
interpolated on the unwrapped angle; a recording already at 10 Hz on the grid passes through unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from seal.core.geometry import wrap_angle
from seal.core.scenario import AGENT_TYPES, DT_S, HEADING, LENGTH, TRACK_FIELDS, VALID, VX, VY, WIDTH, X, Y

_GRID_EPS_S = 1e-6
"""Times within this many seconds of a grid point count as on it (float noise in ``step * dt``)."""


@dataclass(frozen=True, eq=False)
class AgentLog:
    """Every agent of one recording on the 10 Hz grid.

    Attributes:
        tracks: ``[N, T, 8]`` float64 in `TRACK_FIELDS` layout; step ``n`` is time ``n * DT_S`` of the recording;
            values are 0 where ``valid`` is 0.
        agent_ids: ``[N]`` int64 unique ids (the recording's ids where they are integers).
        agent_types: ``N`` strings from `seal.core.scenario.AGENT_TYPES`.
        source_ids: ``N`` original ids as strings (ScenarioNet ids need not be integers).
    """

    tracks: np.ndarray
    agent_ids: np.ndarray
    agent_types: tuple[str, ...]
    source_ids: tuple[str, ...]

    def __post_init__(self) -> None:
        tracks = np.asarray(self.tracks, dtype=np.float64)
        if tracks.ndim != 3 or tracks.shape[2] != len(TRACK_FIELDS):
            raise ValueError(f"AgentLog tracks must be [N, T, {len(TRACK_FIELDS)}], got {tracks.shape}")
        n = tracks.shape[0]
        ids = np.asarray(self.agent_ids, dtype=np.int64).reshape(-1)
        if ids.shape != (n,) or len(self.agent_types) != n or len(self.source_ids) != n:
            raise ValueError("AgentLog: tracks, agent_ids, agent_types and source_ids must have one entry per agent")
        if np.unique(ids).size != n:
            raise ValueError("AgentLog: agent_ids must be unique")
        bad = [t for t in self.agent_types if t not in AGENT_TYPES]
        if bad:
            raise ValueError(f"AgentLog: unknown agent types {sorted(set(bad))}; expected {AGENT_TYPES}")
        object.__setattr__(self, "tracks", tracks)
        object.__setattr__(self, "agent_ids", ids)
        object.__setattr__(self, "agent_types", tuple(self.agent_types))
        object.__setattr__(self, "source_ids", tuple(str(s) for s in self.source_ids))

    @property
    def n_agents(self) -> int:
        return int(self.tracks.shape[0])

    @property
    def n_steps(self) -> int:
        return int(self.tracks.shape[1])

    @property
    def valid(self) -> np.ndarray:
        """``[N, T]`` bool."""
        return self.tracks[:, :, VALID] > 0.5


@dataclass(frozen=True)
class GridTrack:
    """One agent's contiguous stretch on the 10 Hz grid: rows ``[M, 8]`` for grid steps ``first .. first+M-1``."""

    first: int
    rows: np.ndarray


def grid_step(time_s: float) -> int:
    """Grid step at or after ``time_s`` (s)."""
    return int(math.ceil(time_s / DT_S - _GRID_EPS_S / DT_S))


def resample_states(
    times_s: np.ndarray, x: np.ndarray, y: np.ndarray, heading: np.ndarray, vx: np.ndarray, vy: np.ndarray,
    length_m: np.ndarray | float, width_m: np.ndarray | float,
) -> GridTrack | None:
    """One agent's logged states (``[K]`` arrays at strictly increasing ``times_s``) on the 10 Hz grid.

    Grid steps from the first at or after ``times_s[0]`` to the last at or before ``times_s[-1]``; None when no
    grid point falls inside (a log shorter than one 0.1 s step between grid points). The caller decides what
    counts as a gap in the input; this interpolates across whatever spacing it gets.

    Returns:
        `GridTrack` with rows in `TRACK_FIELDS` layout (valid = 1).
    """
    t = np.asarray(times_s, dtype=np.float64).reshape(-1)
    k = t.shape[0]
    cols = [np.broadcast_to(np.asarray(v, dtype=np.float64), (k,)) for v in (x, y, heading, vx, vy, length_m, width_m)]
    first, last = grid_step(t[0]), int(math.floor(t[-1] / DT_S + _GRID_EPS_S / DT_S))
    if last < first:
        return None
    grid = np.arange(first, last + 1) * DT_S
    if k == 1:
        rows = np.tile(np.array([c[0] for c in cols] + [1.0]), (grid.shape[0], 1))
        return GridTrack(first, rows)
    out = np.empty((grid.shape[0], len(TRACK_FIELDS)), dtype=np.float64)
    for field, c in zip((X, Y, HEADING, VX, VY, LENGTH, WIDTH), cols, strict=True):
        values = np.unwrap(c) if field == HEADING else c
        out[:, field] = np.interp(grid, t, values)
    out[:, HEADING] = wrap_angle(out[:, HEADING])
    out[:, VALID] = 1.0
    return GridTrack(first, out)


def stack_tracks(tracks: list[GridTrack]) -> np.ndarray:
    """``[N, T, 8]`` array of grid tracks (T = one past the last step of any of them; 0 where absent)."""
    n_steps = max((g.first + g.rows.shape[0] for g in tracks), default=0)
    out = np.zeros((len(tracks), n_steps, len(TRACK_FIELDS)), dtype=np.float64)
    for i, g in enumerate(tracks):
        out[i, g.first : g.first + g.rows.shape[0]] = g.rows
    return out


def speeds_from_positions(times_s: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``[K]`` speed (m/s) from positions by central differences (one-sided at the ends; 0 for one state)."""
    t = np.asarray(times_s, dtype=np.float64)
    if t.shape[0] < 2:
        return np.zeros_like(t)
    return np.hypot(np.gradient(np.asarray(x, dtype=np.float64), t), np.gradient(np.asarray(y, dtype=np.float64), t))
