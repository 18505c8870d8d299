"""`AgentTracks`: one scenario's agents as float64 arrays plus their lane assignment, the input of all features.

Built from logged tracks (`from_tracks`) or by `seal.scoring.extrapolation` for the future-extrapolated variant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.core.scenario import HEADING, LENGTH, VALID, VX, VY, WIDTH, X, Y
from seal.scoring.frenet import RoadIndex


@dataclass(frozen=True)
class AgentTracks:
    """``A`` agents over ``T`` steps (10 Hz).

    Attributes:
        pos: ``[A, T, 2]`` centre positions (m).
        vel: ``[A, T, 2]`` velocities (m/s).
        heading: ``[A, T]`` (rad).
        length, width: ``[A]`` body size (m), the value at the agent's first valid step.
        valid: ``[A, T]`` bool; one contiguous block per agent.
        lane: ``[A, T]`` int lane index into the road's lanes, -1 for none (or invalid).
        in_lane: ``[A, T]`` bool, within half a lane width of the assigned lane's centre line.
        speed_limit: ``[A, T]`` (m/s) of the assigned lane, NaN where no lane.
    """

    pos: np.ndarray
    vel: np.ndarray
    heading: np.ndarray
    length: np.ndarray
    width: np.ndarray
    valid: np.ndarray
    lane: np.ndarray
    in_lane: np.ndarray
    speed_limit: np.ndarray

    @property
    def n_agents(self) -> int:
        return int(self.pos.shape[0])

    @property
    def speed(self) -> np.ndarray:
        """``[A, T]`` speed (m/s), 0 where invalid."""
        return np.where(self.valid, np.hypot(self.vel[..., 0], self.vel[..., 1]), 0.0)


def first_valid_value(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``[A]`` value of ``values [A, T]`` at each agent's first valid step."""
    first = np.argmax(valid, axis=1)
    return values[np.arange(values.shape[0]), first]


def lane_attributes(index: RoadIndex, pos: np.ndarray, heading: np.ndarray, valid: np.ndarray):
    """Lane ``[A, T]``, in-lane ``[A, T]`` and speed limit ``[A, T]`` of valid points (projection of all at once)."""
    lane = np.full(valid.shape, -1, dtype=np.int64)
    in_lane = np.zeros(valid.shape, dtype=bool)
    limit = np.full(valid.shape, np.nan)
    if valid.any():
        proj = index.project(pos[valid], heading[valid])
        lane[valid] = proj.lane
        in_lane[valid] = proj.in_lane
        limit[valid] = np.where(proj.lane >= 0, index.speed_limits[np.maximum(proj.lane, 0)], np.nan)
    return lane, in_lane, limit


def from_tracks(tracks: np.ndarray, index: RoadIndex) -> AgentTracks:
    """`AgentTracks` of logged scenario tracks ``[A, T, 8]`` (`seal.core.scenario.TRACK_FIELDS`)."""
    tr = np.asarray(tracks, dtype=np.float64)
    valid = tr[..., VALID] > 0.5
    pos = np.where(valid[..., None], tr[..., [X, Y]], 0.0)
    vel = np.where(valid[..., None], tr[..., [VX, VY]], 0.0)
    heading = np.where(valid, tr[..., HEADING], 0.0)
    lane, in_lane, limit = lane_attributes(index, pos, heading, valid)
    return AgentTracks(
        pos=pos,
        vel=vel,
        heading=heading,
        length=first_valid_value(tr[..., LENGTH], valid),
        width=first_valid_value(tr[..., WIDTH], valid),
        valid=valid,
        lane=lane,
        in_lane=in_lane,
        speed_limit=limit,
    )
