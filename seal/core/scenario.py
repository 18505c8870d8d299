"""The scenario data model: 9.1 s of logged traffic around an interacting (ego, adversary) pair.

Time base is 10 Hz (``DT_S = 0.1``). A scenario has ``N_STEPS = 91`` steps: ``N_HISTORY = 11`` history steps
(indices 0..10, the current step is ``CURRENT_STEP = 10``) and ``N_FUTURE = 80`` future steps (8 s).

Tracks are one float32 array ``[A, T, 8]`` whose last axis is `TRACK_FIELDS`:
``x, y`` (m, world frame), ``heading`` (rad, world frame, counter-clockwise from +x), ``vx, vy`` (m/s, world
frame), ``length, width`` (m), ``valid`` (1.0 where the agent exists at that step, else 0.0). Values at invalid
steps are ignored (stored as 0).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from seal.core.road import RoadDescription

DT_S = 0.1
N_HISTORY = 11
N_FUTURE = 80
N_STEPS = N_HISTORY + N_FUTURE
CURRENT_STEP = N_HISTORY - 1

TRACK_FIELDS = ("x", "y", "heading", "vx", "vy", "length", "width", "valid")
X, Y, HEADING, VX, VY, LENGTH, WIDTH, VALID = range(len(TRACK_FIELDS))
AGENT_TYPES = ("vehicle", "pedestrian", "cyclist", "other")


class ScenarioError(ValueError):
    """A scenario violates the data model. The message names the scenario, the field and the agent."""


@dataclass(frozen=True, eq=False)
class Scenario:
    """A base scenario (see the module docstring for the time base and track layout).

    Attributes:
        scenario_id: unique id within a dataset.
        tracks: ``[A, N_STEPS, 8]`` float32, fields `TRACK_FIELDS`.
        agent_ids: ``[A]`` int64 unique agent ids.
        agent_types: ``A`` strings from `AGENT_TYPES`.
        ego_id: id of the agent the RL policy drives; valid at `CURRENT_STEP`.
        adv_id: id of the agent generators may perturb; valid at `CURRENT_STEP`; different from ``ego_id``.
        road: the road the agents drive on.
        source: where the scenario comes from, e.g. ``"highway-env"`` or ``"commonroad:FILE"``.
        metadata: free JSON-serialisable data (layout, scores, split, ...).
    """

    scenario_id: str
    tracks: np.ndarray
    agent_ids: np.ndarray
    agent_types: tuple[str, ...]
    ego_id: int
    adv_id: int
    road: RoadDescription
    source: str = "unknown"
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "tracks", np.ascontiguousarray(self.tracks, dtype=np.float32))
        object.__setattr__(self, "agent_ids", np.asarray(self.agent_ids, dtype=np.int64).reshape(-1))
        object.__setattr__(self, "agent_types", tuple(str(t) for t in self.agent_types))
        object.__setattr__(self, "ego_id", int(self.ego_id))
        object.__setattr__(self, "adv_id", int(self.adv_id))
        object.__setattr__(self, "metadata", dict(self.metadata))
        validate_scenario(self)

    # ----------------------------------------------------------------------------------------- accessors
    @property
    def n_agents(self) -> int:
        return int(self.tracks.shape[0])

    @property
    def valid(self) -> np.ndarray:
        """``[A, T]`` bool validity mask."""
        return self.tracks[:, :, VALID] > 0.5

    def index_of(self, agent_id: int) -> int:
        """Row of ``agent_id`` in `tracks`."""
        hits = np.flatnonzero(self.agent_ids == agent_id)
        if hits.size == 0:
            raise KeyError(f"scenario {self.scenario_id!r} has no agent {agent_id}")
        return int(hits[0])

    @property
    def ego_index(self) -> int:
        return self.index_of(self.ego_id)

    @property
    def adv_index(self) -> int:
        return self.index_of(self.adv_id)

    def track(self, agent_id: int) -> np.ndarray:
        """``[T, 8]`` track of one agent (a view, do not modify)."""
        return self.tracks[self.index_of(agent_id)]

    @property
    def layout(self) -> str:
        return str(self.metadata.get("layout", self.road.layout))

    def with_roles(self, ego_id: int, adv_id: int) -> Scenario:
        """A copy where ``ego_id`` drives as the ego and ``adv_id`` is the adversary (tracks are shared).

        When the two roles are exchanged, metadata keys that describe a role (``ego_*`` / ``adv_*``, e.g. the
        drivers of a generated scenario) are exchanged with them and ``roles_swapped`` records it.
        """
        if (int(ego_id), int(adv_id)) == (self.ego_id, self.adv_id):
            return self
        meta = dict(self.metadata)
        if (int(ego_id), int(adv_id)) == (self.adv_id, self.ego_id):
            for key in [k for k in self.metadata if k.startswith("ego_")]:
                twin = "adv_" + key[len("ego_"):]
                if twin in self.metadata:
                    meta[key], meta[twin] = self.metadata[twin], self.metadata[key]
            meta["roles_swapped"] = not bool(self.metadata.get("roles_swapped", False))
        return dataclasses.replace(self, ego_id=ego_id, adv_id=adv_id, metadata=meta)

    def with_metadata(self, **updates: Any) -> Scenario:
        """A copy with ``metadata`` updated (tracks are shared, they are never modified in place)."""
        meta = dict(self.metadata)
        meta.update(updates)
        return Scenario(
            scenario_id=self.scenario_id,
            tracks=self.tracks,
            agent_ids=self.agent_ids,
            agent_types=self.agent_types,
            ego_id=self.ego_id,
            adv_id=self.adv_id,
            road=self.road,
            source=self.source,
            metadata=meta,
        )


class GroupError(ScenarioError):
    """A scenario does not say which recording or traffic run it was cut from."""


def group_of(s: Scenario) -> str:
    """The recording / traffic run ``s`` was cut from: windows of one group must stay in one split.

    ``metadata["group"]`` where the builder recorded it; for datasets built before group ids existed it is
    derived from what their metadata already holds: a generated window's build seed and run number, or an
    imported window's source (its recording file). Raises `GroupError` when neither is there (hand-built
    scenarios: give them ``metadata["group"]``).
    """
    group = s.metadata.get("group")
    if group is not None:
        return str(group)
    if "run" in s.metadata:
        return f"{s.source}:seed{s.metadata.get('seed', '?')}:run{int(s.metadata['run']):05d}"
    if "source_file" in s.metadata:  # imported before group ids: the recording is the source
        return s.source
    raise GroupError(
        f"scenario {s.scenario_id!r}: no 'group' in its metadata and no source or run to derive it from; "
        "rebuild the dataset with this seal (`seal data generate` / `seal data import`) so every window records "
        "the recording it was cut from"
    )


def validate_scenario(s: Scenario) -> None:
    """Raise `ScenarioError` naming scenario, field and agent if ``s`` breaks the data model."""
    sid = s.scenario_id
    tracks = s.tracks
    if tracks.ndim != 3 or tracks.shape[1] != N_STEPS or tracks.shape[2] != len(TRACK_FIELDS):
        raise ScenarioError(
            f"scenario {sid!r}: field 'tracks' must have shape [A, {N_STEPS}, {len(TRACK_FIELDS)}], "
            f"got {tracks.shape}"
        )
    n_agents = tracks.shape[0]
    if n_agents < 2:
        raise ScenarioError(f"scenario {sid!r}: field 'tracks' needs at least 2 agents (ego and adv), got {n_agents}")
    if s.agent_ids.shape != (n_agents,):
        raise ScenarioError(
            f"scenario {sid!r}: field 'agent_ids' must have {n_agents} entries, got {s.agent_ids.shape[0]}"
        )
    if np.unique(s.agent_ids).size != n_agents:
        ids, counts = np.unique(s.agent_ids, return_counts=True)
        raise ScenarioError(f"scenario {sid!r}: field 'agent_ids' has duplicates {ids[counts > 1].tolist()}")
    if len(s.agent_types) != n_agents:
        raise ScenarioError(
            f"scenario {sid!r}: field 'agent_types' must have {n_agents} entries, got {len(s.agent_types)}"
        )
    for i, agent_type in enumerate(s.agent_types):
        if agent_type not in AGENT_TYPES:
            raise ScenarioError(
                f"scenario {sid!r}: field 'agent_types' of agent {int(s.agent_ids[i])} is {agent_type!r}, "
                f"expected one of {AGENT_TYPES}"
            )

    valid_raw = tracks[:, :, VALID]
    if not np.all((valid_raw == 0.0) | (valid_raw == 1.0)):
        bad = int(np.flatnonzero(~np.all((valid_raw == 0.0) | (valid_raw == 1.0), axis=1))[0])
        raise ScenarioError(f"scenario {sid!r}: field 'valid' of agent {int(s.agent_ids[bad])} must be 0 or 1")
    valid = valid_raw > 0.5

    # Finite values wherever the agent is valid.
    finite = np.isfinite(tracks)
    bad_mask = ~finite & valid[:, :, None]
    if bad_mask.any():
        a, t, f = (int(v[0]) for v in np.nonzero(bad_mask))
        raise ScenarioError(
            f"scenario {sid!r}: field {TRACK_FIELDS[f]!r} of agent {int(s.agent_ids[a])} is NaN or inf at step {t}"
        )
    sizes = tracks[:, :, [LENGTH, WIDTH]]
    bad_size = (sizes <= 0).any(axis=2) & valid
    if bad_size.any():
        a, t = (int(v[0]) for v in np.nonzero(bad_size))
        raise ScenarioError(
            f"scenario {sid!r}: field 'length'/'width' of agent {int(s.agent_ids[a])} must be > 0 (step {t})"
        )

    # The env replays an agent from its first to its last valid step: validity must be one contiguous block.
    n_valid = valid.sum(axis=1)
    starts = np.argmax(valid, axis=1)
    ends = valid.shape[1] - np.argmax(valid[:, ::-1], axis=1)
    gap = (n_valid > 0) & (ends - starts != n_valid)
    if gap.any():
        a = int(np.flatnonzero(gap)[0])
        raise ScenarioError(
            f"scenario {sid!r}: field 'valid' of agent {int(s.agent_ids[a])} has a gap (valid from step "
            f"{int(starts[a])} to {int(ends[a]) - 1} but only {int(n_valid[a])} valid steps); the env cannot "
            "replay agents that disappear and reappear"
        )
    if (n_valid == 0).any():
        a = int(np.flatnonzero(n_valid == 0)[0])
        raise ScenarioError(f"scenario {sid!r}: field 'valid' of agent {int(s.agent_ids[a])} is never valid")

    if s.ego_id == s.adv_id:
        raise ScenarioError(f"scenario {sid!r}: field 'adv_id' equals 'ego_id' ({s.ego_id})")
    for name, agent_id in (("ego_id", s.ego_id), ("adv_id", s.adv_id)):
        hits = np.flatnonzero(s.agent_ids == agent_id)
        if hits.size == 0:
            raise ScenarioError(f"scenario {sid!r}: field {name!r} = {agent_id} is not among 'agent_ids'")
        if not valid[hits[0], CURRENT_STEP]:
            raise ScenarioError(
                f"scenario {sid!r}: agent {agent_id} ({name}) must be valid at the current step {CURRENT_STEP}"
            )
    if not isinstance(s.road, RoadDescription):
        raise ScenarioError(f"scenario {sid!r}: field 'road' must be a RoadDescription")


def speed(tracks: np.ndarray) -> np.ndarray:
    """Speed in m/s from a ``[..., 8]`` track array (norm of vx, vy)."""
    return np.hypot(tracks[..., VX], tracks[..., VY])
