"""Which demonstration windows are adversarial (thesis 6.3.2): segments *starting* within 2H before a collision or a
near miss that the agent *caused*.

Events are found on simulated (or logged) tracks ``[A, T, 8]`` (`seal.core.scenario` layout), for every pair of
present agents whose centres are within ``max_centre_m``:

* **collision**: the first step at which the two boxes overlap (`seal.core.geometry.box_gap` is 0);
* **near miss**: the first step of an encounter at which the box gap drops below ``near_miss_gap_m`` (0.5 m) while
  the gap closes at ``near_miss_closing_mps`` (1 m/s) or faster; the encounter lasts while the gap stays below the
  threshold, so a pair queueing bumper to bumper counts once, and a pair that touches later counts as a collision.

**Striker rule.** Each agent's contribution to closing the gap is the component of its own velocity along the line
from its centre to the other's, ``c_i = v_i . (p_j - p_i) / |p_j - p_i|`` (m/s), measured on the step before the
event (the motion that brought them together). The agent with the larger contribution is the striker: a follower
running into a leader contributes its speed, the leader (driving away) a negative amount, so the follower strikes
and the vehicle hit from behind does not. When the two contributions are within ``striker_margin_mps`` of each
other (head-on, two vehicles merging into the same gap) both are strikers. Known limit: a cut-in that ends with the
cutter's rear in front of the other car's bumper is attributed to the car behind (its forward speed points at the
cutter); the rule sees motion, not right of way.

**Windows.** A window of ``H`` steps starting at scenario step ``s`` is adversarial for an agent that struck at
step ``t_e`` when ``t_e - 2H <= s < t_e`` (`adversarial_start_mask`). Numpy only.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from seal.core.geometry import box_gap, track_corners
from seal.core.scenario import VALID, VX, VY, X, Y

COLLISION_EVENT, NEAR_MISS_EVENT = 0, 1
EVENT_KINDS = ("collision", "near_miss")


@dataclass(frozen=True)
class EventSpec:
    """Thresholds of `find_events` (see the module docstring).

    Attributes:
        near_miss_gap_m: box gap below which an approach is a near miss (m).
        near_miss_closing_mps: the gap must close at least this fast at that step (m/s).
        striker_margin_mps: contributions closer than this make both agents strikers (m/s).
        max_centre_m: pairs with centres farther apart are not examined (m; two 5 m cars touch within ~6 m).
    """

    near_miss_gap_m: float = 0.5
    near_miss_closing_mps: float = 1.0
    striker_margin_mps: float = 0.5
    max_centre_m: float = 12.0

    def __post_init__(self) -> None:
        for name in ("near_miss_gap_m", "near_miss_closing_mps", "striker_margin_mps", "max_centre_m"):
            if float(getattr(self, name)) < 0:
                raise ValueError(f"EventSpec: {name} must be >= 0, got {getattr(self, name)}")

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class Events:
    """One row per (event, agent): both agents of a pair get a row. All ``[E]``.

    Attributes:
        agent: agent row (index into the tracks' first axis).
        other: the other agent's row.
        step: scenario step of the event (first overlap / first step under the near-miss gap).
        kind: `COLLISION_EVENT` or `NEAR_MISS_EVENT`.
        striker: the agent caused it (the striker rule).
        contribution_mps: the agent's own closing contribution ``c_i`` (m/s).
    """

    agent: np.ndarray
    other: np.ndarray
    step: np.ndarray
    kind: np.ndarray
    striker: np.ndarray
    contribution_mps: np.ndarray

    def __len__(self) -> int:
        return int(self.agent.shape[0])

    @classmethod
    def empty(cls) -> Events:
        z = np.zeros(0, dtype=np.int64)
        return cls(z, z.copy(), z.astype(np.int32), z.astype(np.int8), z.astype(bool), z.astype(np.float64))


def closing_contributions(p_i: np.ndarray, v_i: np.ndarray, p_j: np.ndarray, v_j: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Each agent's velocity component towards the other (m/s), ``[...]`` for positions / velocities
    ``[..., 2]`` (m, m/s); 0 for coincident centres."""
    d = np.asarray(p_j, dtype=np.float64) - np.asarray(p_i, dtype=np.float64)
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    u = np.divide(d, norm, out=np.zeros_like(d), where=norm > 1e-9)
    return (np.asarray(v_i) * u).sum(-1), -(np.asarray(v_j) * u).sum(-1)


def strikers(c_i: np.ndarray, c_j: np.ndarray, margin_mps: float) -> tuple[np.ndarray, np.ndarray]:
    """Striker flags of both agents from their contributions (module docstring)."""
    c_i, c_j = np.asarray(c_i, dtype=np.float64), np.asarray(c_j, dtype=np.float64)
    tie = np.abs(c_i - c_j) <= margin_mps
    return tie | (c_i > c_j), tie | (c_j > c_i)


def _pair_gaps(tracks: np.ndarray, t: int, max_centre_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs ``i < j`` present at step ``t`` with centres within ``max_centre_m``, and their box gaps (m)."""
    present = np.flatnonzero(tracks[:, t, VALID] > 0.5)
    if present.size < 2:
        e = np.zeros(0, dtype=np.int64)
        return e, e.copy(), np.zeros(0)
    xy = tracks[present, t][:, [X, Y]]
    dist = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    a, b = np.nonzero(np.triu(dist <= max_centre_m, k=1))
    i, j = present[a], present[b]
    corners = track_corners(tracks[:, t])
    return i, j, box_gap(corners[i], corners[j])


def find_events(tracks: np.ndarray, spec: EventSpec | None = None) -> Events:
    """Collisions and near misses of every pair in ``tracks [A, T, 8]`` with striker flags (module docstring);
    rows ordered by step, then agent."""
    spec = spec or EventSpec()
    tracks = np.asarray(tracks, dtype=np.float64)
    prev_state: dict[tuple[int, int], int] = {}  # pair -> 0 apart, 1 near-miss encounter, 2 touching
    rows: list[tuple[int, int, int, int, bool, float]] = []
    for t in range(tracks.shape[1]):
        i_s, j_s, gaps = _pair_gaps(tracks, t, spec.max_centre_m)
        state: dict[tuple[int, int], int] = {}
        for i, j, gap in zip(i_s.tolist(), j_s.tolist(), gaps.tolist(), strict=True):
            before = prev_state.get((i, j), 0)
            if gap <= 0.0:
                state[i, j] = 2
                kind = COLLISION_EVENT if before < 2 else None
            elif gap < spec.near_miss_gap_m:
                state[i, j] = max(1, before)
                kind = NEAR_MISS_EVENT if before == 0 and _closing(tracks, i, j, t) >= spec.near_miss_closing_mps \
                    else None
                if kind is None and before == 0:
                    state[i, j] = 0  # not closing: a later closing step under the gap can still start an encounter
            else:
                continue
            if kind is None:
                continue
            s = t - 1 if t > 0 and tracks[i, t - 1, VALID] > 0.5 and tracks[j, t - 1, VALID] > 0.5 else t
            c_i, c_j = closing_contributions(tracks[i, s, [X, Y]], tracks[i, s, [VX, VY]],
                                             tracks[j, s, [X, Y]], tracks[j, s, [VX, VY]])
            st_i, st_j = strikers(c_i, c_j, spec.striker_margin_mps)
            rows.append((t, i, j, kind, bool(st_i), float(c_i)))
            rows.append((t, j, i, kind, bool(st_j), float(c_j)))
        prev_state = state
    if not rows:
        return Events.empty()
    rows.sort(key=lambda r: (r[0], r[1]))
    arr = list(zip(*rows, strict=True))
    return Events(agent=np.array(arr[1], dtype=np.int64), other=np.array(arr[2], dtype=np.int64),
                  step=np.array(arr[0], dtype=np.int32), kind=np.array(arr[3], dtype=np.int8),
                  striker=np.array(arr[4], dtype=bool), contribution_mps=np.array(arr[5], dtype=np.float64))


def _closing(tracks: np.ndarray, i: int, j: int, t: int) -> float:
    """Rate (m/s) at which the centres of ``i`` and ``j`` approach each other at step ``t`` (velocities of ``t``)."""
    c_i, c_j = closing_contributions(tracks[i, t, [X, Y]], tracks[i, t, [VX, VY]], tracks[j, t, [X, Y]],
                                     tracks[j, t, [VX, VY]])
    return float(c_i + c_j)


def adversarial_start_mask(window_start_step: np.ndarray, event_step: np.ndarray, horizon: int,
                           lead_steps: int | None = None) -> np.ndarray:
    """``[W]`` bool: the window starting at scenario step ``window_start_step[w]`` starts within ``lead_steps``
    (default ``2 * horizon``) steps before its agent's struck event at ``event_step[w]``: ``t_e - lead <= s < t_e``."""
    lead = 2 * int(horizon) if lead_steps is None else int(lead_steps)
    s = np.asarray(window_start_step, dtype=np.int64)
    e = np.asarray(event_step, dtype=np.int64)
    return (s >= e - lead) & (s < e)
