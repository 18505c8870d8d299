"""The per-scenario queue of the last K ego roll-outs that generators condition on (ARCHITECTURE.md, Closed loop).

Each scenario's queue starts as K copies of the logged ego future (`logged_rollout`) and every finished episode
of that scenario is appended, dropping the oldest, so it always holds exactly K roll-outs, oldest first.

Where the queues live when environments run in several processes: inside each env process. A training or
evaluation job partitions the scenarios across its workers (`seal.adversaries.closed_loop.partition_scenarios`), so a
scenario is always played by the same worker and the roll-out of one episode reaches the queue used the next
time that scenario is perturbed without any inter-process traffic (no shared store, no locks, nothing on disk).
`RolloutHistory` is plain picklable data, so a job can still fetch the queues from its workers (SB3's
``get_attr``) to inspect them; to checkpoint them (`seal.experiments.training.train`) `RolloutHistory.get_state` turns
them into
numpy arrays plus JSON (saved with ``np.savez``, loaded with ``allow_pickle=False``) and `RolloutHistory.set_state`
rebuilds them.
"""

from __future__ import annotations

import hashlib
import json
from collections import deque
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np

from seal.adversaries.base import K_ROLLOUTS
from seal.core.geometry import boxes_overlap, track_corners
from seal.core.outcome import Outcome
from seal.core.scenario import CURRENT_STEP, VALID, Scenario
from seal.envs.rollout import Rollout

LOGGED_ADVERSARY = "log"
"""``Rollout.adversary`` of `logged_rollout`: the queue entry that is the log, not a roll-out the ego played."""


def logged_rollout(scenario: Scenario) -> Rollout:
    """The logged episode as a `Rollout`: what the queue holds before the scenario was ever played.

    ``tracks`` are the scenario's tracks (91 steps); ``last_step`` is the ego's last valid step; ``ego_crashes``
    / ``adv_crashes`` are the logged box overlaps after `CURRENT_STEP`; the outcome is ``"timeout"`` (the log ran
    to its end), route completion 1 and ``adversary = "log"``.
    """
    tracks = scenario.tracks
    ego_i, adv_i = scenario.ego_index, scenario.adv_index
    valid = tracks[:, :, VALID] > 0.5
    ego_valid = np.flatnonzero(valid[ego_i])
    last_step = int(ego_valid[-1]) if ego_valid.size else CURRENT_STEP
    corners = track_corners(tracks)
    future = np.arange(tracks.shape[1]) > CURRENT_STEP

    def crashes(i: int, skip: tuple[int, ...]) -> list[tuple[int, int]]:
        hit = boxes_overlap(corners[i][None], corners) & valid[i][None] & valid & future[None]  # [A, T]
        hit[list(skip)] = False
        steps, agents = np.nonzero(hit.T)
        return [(int(t), int(scenario.agent_ids[a])) for t, a in zip(steps, agents, strict=True)]

    return Rollout(
        scenario_id=scenario.scenario_id,
        tracks=tracks.copy(),
        agent_ids=scenario.agent_ids.copy(),
        ego_id=scenario.ego_id,
        adv_id=scenario.adv_id,
        last_step=last_step,
        outcome=Outcome.TIMEOUT,
        ego_crashes=crashes(ego_i, (ego_i,)),
        adv_crashes=crashes(adv_i, (adv_i, ego_i)),
        route_completion=1.0,
        adversary=LOGGED_ADVERSARY,
    )


def rollout_digest(rollout: Rollout) -> str:
    """Short content hash of a roll-out's executed ego track (identifies a roll-out across processes)."""
    h = hashlib.blake2b(digest_size=8)
    h.update(rollout.scenario_id.encode())
    h.update(np.ascontiguousarray(rollout.ego_track, dtype=np.float32).tobytes())
    h.update(str(rollout.last_step).encode())
    return h.hexdigest()


_ROLLOUT_SCALARS = (
    "scenario_id", "ego_id", "adv_id", "last_step", "outcome", "ego_crashes", "adv_crashes", "out_of_road_step",
    "success_step", "route_completion", "episode_return", "adversary",
)
"""`Rollout` fields stored as JSON by `RolloutHistory.get_state` (the two arrays are stored as arrays)."""


def _jsonable_field(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, list):
        return [[int(t), int(a)] for t, a in value]
    return value


class RolloutHistory:
    """Per-scenario queues of the last ``k`` ego roll-outs (oldest first).

    A scenario's queue is created on first use with ``k`` copies of `logged_rollout`; `append` adds a roll-out
    and drops the oldest, so every queue always holds exactly ``k`` roll-outs.

    Args:
        k: queue length (CAT / SEAL use 5).
    """

    def __init__(self, k: int = K_ROLLOUTS) -> None:
        if k < 1:
            raise ValueError(f"RolloutHistory: k must be >= 1, got {k}")
        self.k = int(k)
        self._queues: dict[str, deque[Rollout]] = {}

    def queue(self, scenario: Scenario) -> tuple[Rollout, ...]:
        """The scenario's ``k`` roll-outs, oldest first (initialised from the log on first use)."""
        return tuple(self._queue(scenario))

    def append(self, scenario: Scenario, rollout: Rollout) -> None:
        """Add the roll-out of a finished episode of ``scenario`` (the oldest one drops out)."""
        if rollout.scenario_id != scenario.scenario_id:
            raise ValueError(
                f"RolloutHistory.append: roll-out of scenario {rollout.scenario_id!r} given for "
                f"{scenario.scenario_id!r}"
            )
        self._queue(scenario).append(rollout)

    def digests(self, scenario: Scenario) -> list[str]:
        """`rollout_digest` of each roll-out in the scenario's queue, oldest first."""
        return [rollout_digest(r) for r in self._queue(scenario)]

    def _queue(self, scenario: Scenario) -> deque[Rollout]:
        q = self._queues.get(scenario.scenario_id)
        if q is None:
            logged = logged_rollout(scenario)
            q = deque([logged] * self.k, maxlen=self.k)
            self._queues[scenario.scenario_id] = q
        return q

    def __contains__(self, scenario_id: object) -> bool:
        return scenario_id in self._queues

    def __len__(self) -> int:
        """Number of scenarios with a queue."""
        return len(self._queues)

    def __iter__(self) -> Iterator[str]:
        return iter(self._queues)

    def get_state(self) -> dict[str, np.ndarray]:
        """The queues as flat arrays (no pickle needed to store them, e.g. ``np.savez(path, **state)``).

        Keys: ``meta`` (0-d str: JSON with ``k``, each distinct roll-out's scalar fields and each scenario's queue
        as indices into the roll-outs, oldest first), ``tracks_<i>`` (``[A, T, 8]`` float32) and
        ``agent_ids_<i>`` (``[A]`` int64) of roll-out ``i``. A roll-out held several times (the K logged copies
        a queue starts with) is stored once.
        """
        index: dict[int, int] = {}
        rollouts: list[Rollout] = []
        queues: dict[str, list[int]] = {}
        for sid, q in self._queues.items():
            refs = []
            for r in q:
                if id(r) not in index:
                    index[id(r)] = len(rollouts)
                    rollouts.append(r)
                refs.append(index[id(r)])
            queues[sid] = refs
        arrays: dict[str, np.ndarray] = {}
        fields = []
        for i, r in enumerate(rollouts):
            arrays[f"tracks_{i}"] = np.asarray(r.tracks, dtype=np.float32)
            arrays[f"agent_ids_{i}"] = np.asarray(r.agent_ids, dtype=np.int64)
            fields.append({name: _jsonable_field(getattr(r, name)) for name in _ROLLOUT_SCALARS})
        meta = {"k": self.k, "rollouts": fields, "queues": queues}
        arrays["meta"] = np.array(json.dumps(meta))
        return arrays

    @classmethod
    def from_state(cls, state: Mapping[str, np.ndarray], source: str = "history state") -> RolloutHistory:
        """Rebuild the queues written by `get_state`; ``source`` names the file in errors."""
        if "meta" not in state:
            raise ValueError(f"{source}: no 'meta' entry; not a roll-out history state")
        meta = json.loads(str(np.asarray(state["meta"])))
        history = cls(int(meta["k"]))
        rollouts = []
        for i, f in enumerate(meta["rollouts"]):
            try:
                tracks, ids = state[f"tracks_{i}"], state[f"agent_ids_{i}"]
            except KeyError as exc:
                raise ValueError(f"{source}: roll-out {i} has no {exc.args[0]!r} array") from None
            f = dict(f)
            f["ego_crashes"] = [(int(t), int(a)) for t, a in f["ego_crashes"]]
            f["adv_crashes"] = [(int(t), int(a)) for t, a in f["adv_crashes"]]
            rollouts.append(Rollout(tracks=np.array(tracks, dtype=np.float32), agent_ids=np.array(ids, dtype=np.int64),
                                    **f))
        for sid, refs in meta["queues"].items():
            if len(refs) != history.k:
                raise ValueError(f"{source}: queue of {sid!r} holds {len(refs)} roll-outs, expected k = {history.k}")
            history._queues[sid] = deque((rollouts[j] for j in refs), maxlen=history.k)
        return history

    def set_state(self, state: Mapping[str, np.ndarray], source: str = "history state") -> None:
        """Replace this history's queues (and ``k``) with those of a `get_state` result."""
        other = RolloutHistory.from_state(state, source)
        self.k, self._queues = other.k, other._queues

    def copy(self) -> RolloutHistory:
        """An independent copy (the roll-outs themselves are shared: they are never modified)."""
        other = RolloutHistory(self.k)
        other._queues = {sid: deque(q, maxlen=self.k) for sid, q in self._queues.items()}
        return other
