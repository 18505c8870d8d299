"""Skill demonstrations: per-agent (observation, action) sequences and their 10-step windows.

Storage (one ``.npz``, no pickled objects) keeps every simulated agent-step once; windows are index ranges into
it, labelled on load by `label_windows` (so the labelling rule can change without re-simulating):

=================== ============ ===========================================================================
array               shape, dtype meaning
=================== ============ ===========================================================================
obs                 [M, D] f16   observation of the acting agent, from its own viewpoint (in [-1, 1])
actions             [M, 2] f32   applied normalised action ``[steering, acceleration]``
seg_row             [S] i64      first row of each agent segment (a segment = one agent's simulated span)
seg_len             [S] i32      rows of the segment (steps the agent acted)
seg_scenario        [S] i32      index into ``scenario_ids``
seg_agent           [S] i64      agent id in its scenario
seg_start_step      [S] i32      scenario step of the segment's first row
seg_end_reason      [S] i8       index into `END_REASONS`: what happened at step ``start + len``
seg_impaired        [S] bool     the agent drove with the impaired noise model
seg_source          [S] i8       index into `SOURCES`: how the segment was produced
ev_seg              [E] i64      segment of each event row (one row per agent of a collision / near miss)
ev_step             [E] i32      scenario step of the event (`seal.models.skills.events`)
ev_kind             [E] i8       index into `seal.models.skills.events.EVENT_KINDS`
ev_striker          [E] bool     the segment's agent caused the event (the striker rule)
scenario_ids        [N] str      scenarios simulated
params              [] str       JSON of the settings that produced the file
=================== ============ ===========================================================================
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.atomic import atomic_write
from seal.envs.multi_agent import COLLISION, END_REASONS, OUT_OF_ROAD
from seal.models.skills.events import EVENT_KINDS, NEAR_MISS_EVENT, adversarial_start_mask

FORMAT = "seal-skill-demos"
FORMAT_VERSION = 2
BENIGN, ADVERSARIAL = 0, 1
LABEL_NAMES = ("benign", "adversarial")
SOURCES = ("log", "heuristic", "ego_rollout", "expert")
"""How a segment was produced: ``log``: the logged traffic's own drivers (the actions that reproduce each logged
track, `seal.models.skills.demonstrations.roll_out_log_demonstrations`); ``heuristic``: the noisy, partly impaired
heuristic drivers; ``ego_rollout``: an adversary in closed loop against an ego policy
(`seal.experiments.fitting.skill_rollouts`); ``expert``: DART demonstrations of the clean heuristic driver
(`seal.models.skills.demonstrations.roll_out_expert_demonstrations`)."""
LOG, HEURISTIC, EGO_ROLLOUT, EXPERT = range(len(SOURCES))

_SEG_FIELDS = {
    "seg_row": np.int64, "seg_len": np.int32, "seg_scenario": np.int32, "seg_agent": np.int64,
    "seg_start_step": np.int32, "seg_end_reason": np.int8, "seg_impaired": np.bool_, "seg_source": np.int8,
}
_EV_FIELDS = {"ev_seg": np.int64, "ev_step": np.int32, "ev_kind": np.int8, "ev_striker": np.bool_}


class DemoFileError(ValueError):
    """A demonstrations file is unreadable or inconsistent; the message names the file and the field."""


@dataclass
class Demonstrations:
    """Agent segments of (observation, action) rows (see the module docstring for the fields)."""

    obs: np.ndarray
    actions: np.ndarray
    seg_row: np.ndarray
    seg_len: np.ndarray
    seg_scenario: np.ndarray
    seg_agent: np.ndarray
    seg_start_step: np.ndarray
    seg_end_reason: np.ndarray
    seg_impaired: np.ndarray
    seg_source: np.ndarray
    ev_seg: np.ndarray
    ev_step: np.ndarray
    ev_kind: np.ndarray
    ev_striker: np.ndarray
    scenario_ids: np.ndarray
    params: dict[str, Any]

    @property
    def n_rows(self) -> int:
        return int(self.obs.shape[0])

    @property
    def n_segments(self) -> int:
        return int(self.seg_row.shape[0])

    @property
    def obs_dim(self) -> int:
        return int(self.obs.shape[1])

    def validate(self, where: str = "demonstrations") -> None:
        """Raise `DemoFileError` naming ``where`` and the field when shapes, types or indices disagree."""
        if self.obs.ndim != 2 or self.obs.shape[0] != self.actions.shape[0]:
            raise DemoFileError(f"{where}: field 'obs' must be [M, D] with M = rows of 'actions', got "
                                f"{self.obs.shape} and {self.actions.shape}")
        if self.actions.ndim != 2 or self.actions.shape[1] != 2:
            raise DemoFileError(f"{where}: field 'actions' must be [M, 2], got {self.actions.shape}")
        n_seg = self.seg_row.shape[0]
        for name in _SEG_FIELDS:
            arr = getattr(self, name)
            if arr.shape != (n_seg,):
                raise DemoFileError(f"{where}: field {name!r} must have shape [{n_seg}], got {arr.shape}")
        if n_seg and (self.seg_len.min() < 1 or (self.seg_row < 0).any()
                      or (self.seg_row + self.seg_len > self.n_rows).any()):
            raise DemoFileError(f"{where}: fields 'seg_row'/'seg_len' point outside the {self.n_rows} rows")
        if n_seg and ((self.seg_end_reason < 0).any() or (self.seg_end_reason >= len(END_REASONS)).any()):
            raise DemoFileError(f"{where}: field 'seg_end_reason' holds codes outside 0..{len(END_REASONS) - 1}")
        if n_seg and ((self.seg_source < 0).any() or (self.seg_source >= len(SOURCES)).any()):
            raise DemoFileError(f"{where}: field 'seg_source' holds codes outside 0..{len(SOURCES) - 1}")
        n_ev = self.ev_seg.shape[0]
        for name in _EV_FIELDS:
            if getattr(self, name).shape != (n_ev,):
                raise DemoFileError(f"{where}: field {name!r} must have shape [{n_ev}], got "
                                    f"{getattr(self, name).shape}")
        if n_ev and ((self.ev_seg < 0).any() or (self.ev_seg >= n_seg).any()):
            raise DemoFileError(f"{where}: field 'ev_seg' indexes outside the {n_seg} segments")
        if n_ev and ((self.ev_kind < 0).any() or (self.ev_kind >= len(EVENT_KINDS)).any()):
            raise DemoFileError(f"{where}: field 'ev_kind' holds codes outside 0..{len(EVENT_KINDS) - 1}")
        if n_seg and ((self.seg_scenario < 0).any() or (self.seg_scenario >= len(self.scenario_ids)).any()):
            raise DemoFileError(f"{where}: field 'seg_scenario' indexes outside 'scenario_ids'")
        if not np.isfinite(self.actions).all() or not np.isfinite(self.obs).all():
            raise DemoFileError(f"{where}: fields 'obs'/'actions' hold NaN or inf")

    # ------------------------------------------------------------------------------------------------ I/O
    def save(self, path: str | os.PathLike[str], compress: bool = True) -> None:
        """Write atomically (``np.savez_compressed`` unless ``compress`` is False)."""
        arrays = {
            "format": np.array(FORMAT), "format_version": np.array(FORMAT_VERSION),
            "obs": self.obs.astype(np.float16, copy=False), "actions": self.actions.astype(np.float32, copy=False),
            **{name: getattr(self, name).astype(dtype, copy=False) for name, dtype in _SEG_FIELDS.items()},
            **{name: getattr(self, name).astype(dtype, copy=False) for name, dtype in _EV_FIELDS.items()},
            "scenario_ids": np.asarray(self.scenario_ids, dtype=str),
            "params": np.array(json.dumps(self.params, sort_keys=True)),
        }
        writer = np.savez_compressed if compress else np.savez
        atomic_write(path, lambda f: writer(f, **arrays))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Demonstrations:
        """Read a file written by `save` (``allow_pickle=False``) and validate it."""
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"demonstrations file {path} not found")
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except Exception as exc:  # zipfile / numpy raise several types for truncated or foreign files
            raise DemoFileError(f"demonstrations file {path} cannot be read ({type(exc).__name__}: {exc})") from None
        where = f"demonstrations file {path}"
        if str(data.get("format", "")) != FORMAT:
            raise DemoFileError(f"{where}: field 'format' is not {FORMAT!r}")
        if int(data.get("format_version", -1)) != FORMAT_VERSION:
            raise DemoFileError(f"{where}: field 'format_version' is {data.get('format_version')}; "
                                f"this seal reads {FORMAT_VERSION} (delete the file and re-run `seal fit skills`)")
        missing = [k for k in ("obs", "actions", "scenario_ids", "params", *_SEG_FIELDS, *_EV_FIELDS)
                   if k not in data]
        if missing:
            raise DemoFileError(f"{where}: missing field(s) {missing}")
        try:
            params = json.loads(str(data["params"]))
        except json.JSONDecodeError as exc:
            raise DemoFileError(f"{where}: field 'params' is not JSON ({exc})") from None
        demos = cls(
            obs=data["obs"], actions=data["actions"].astype(np.float32),
            **{name: data[name].astype(dtype) for name, dtype in _SEG_FIELDS.items()},
            **{name: data[name].astype(dtype) for name, dtype in _EV_FIELDS.items()},
            scenario_ids=data["scenario_ids"], params=params,
        )
        demos.validate(where)
        return demos

    @classmethod
    def concat(cls, parts: list[Demonstrations], params: dict[str, Any] | None = None) -> Demonstrations:
        """One set from several (rows, segments and scenario indices renumbered)."""
        if not parts:
            raise ValueError("Demonstrations.concat needs at least one part")
        row_off = np.cumsum([0] + [p.n_rows for p in parts[:-1]])
        seg_off = np.cumsum([0] + [p.n_segments for p in parts[:-1]])
        scen_off = np.cumsum([0] + [len(p.scenario_ids) for p in parts[:-1]])
        return cls(
            obs=np.concatenate([p.obs for p in parts]),
            actions=np.concatenate([p.actions for p in parts]),
            seg_row=np.concatenate([p.seg_row + o for p, o in zip(parts, row_off, strict=True)]),
            seg_len=np.concatenate([p.seg_len for p in parts]),
            seg_scenario=np.concatenate([p.seg_scenario + o for p, o in zip(parts, scen_off, strict=True)]),
            seg_agent=np.concatenate([p.seg_agent for p in parts]),
            seg_start_step=np.concatenate([p.seg_start_step for p in parts]),
            seg_end_reason=np.concatenate([p.seg_end_reason for p in parts]),
            seg_impaired=np.concatenate([p.seg_impaired for p in parts]),
            seg_source=np.concatenate([p.seg_source for p in parts]),
            ev_seg=np.concatenate([p.ev_seg + o for p, o in zip(parts, seg_off, strict=True)]),
            ev_step=np.concatenate([p.ev_step for p in parts]),
            ev_kind=np.concatenate([p.ev_kind for p in parts]),
            ev_striker=np.concatenate([p.ev_striker for p in parts]),
            scenario_ids=np.concatenate([np.asarray(p.scenario_ids, dtype=str) for p in parts]),
            params=dict(params if params is not None else parts[0].params),
        )

    # ------------------------------------------------------------------------------------------------ stats
    def windows(self, spec: WindowSpec | None = None) -> Windows:
        """`label_windows` of these demonstrations under ``spec``."""
        return label_windows(self, spec or WindowSpec())

    def stats(self, spec: WindowSpec | None = None) -> dict[str, Any]:
        """Counts: scenarios, agents and rows per source, end reasons, events (struck or not), windows per class."""
        reasons = {name: int((self.seg_end_reason == k).sum()) for k, name in enumerate(END_REASONS)}
        coll = self.seg_end_reason == COLLISION
        win = self.windows(spec)
        imp = self.seg_impaired
        rows_per_seg = self.seg_len.astype(np.int64)
        return {
            "scenarios": len(self.scenario_ids),
            "agents": self.n_segments,
            "agent_steps": self.n_rows,
            "agents_per_source": {n: int((self.seg_source == k).sum()) for k, n in enumerate(SOURCES)},
            "agent_steps_per_source": {n: int(rows_per_seg[self.seg_source == k].sum()) for k, n in enumerate(SOURCES)},
            "end_reasons": reasons,
            "collision_share_agents": round(float(coll.mean()) if coll.size else 0.0, 4),
            "collision_share_impaired": round(float(coll[imp].mean()) if imp.any() else 0.0, 4),
            "out_of_road_share_agents": round(reasons[END_REASONS[OUT_OF_ROAD]] / max(1, self.n_segments), 4),
            "events": {f"{kind}_{who}": int(((self.ev_kind == k) & (self.ev_striker == (who == "striker"))).sum())
                       for k, kind in enumerate(EVENT_KINDS) for who in ("striker", "struck")},
            "windows_benign": int((win.label == BENIGN).sum()),
            "windows_adversarial": int((win.label == ADVERSARIAL).sum()),
            "windows_adversarial_per_source": {
                n: int(((win.label == ADVERSARIAL) & (self.seg_source[win.segment] == k)).sum())
                for k, n in enumerate(SOURCES)},
            "windows_dropped": int(win.n_dropped),
            "windows_unused": int(win.n_unused),
        }


@dataclass(frozen=True)
class WindowSpec:
    """How agent segments are cut into windows and labelled (thesis 6.3.2; `seal.models.skills.events`).

    A window of ``horizon`` steps starting at scenario step ``s`` is **adversarial** when its agent struck a
    collision (or, with ``near_misses``, a near miss) at step ``t_e`` with ``t_e - lead_steps <= s < t_e``, and the
    window lies inside the agent's segment. Every other window is **benign** when its segment's source is one of
    ``benign_sources`` (clean driving: by default only the logged traffic's own drivers), else unused (the noisy
    heuristic and the closed-loop adversaries give adversarial windows only).

    With ``avoided_only`` the adversarial events are the struck near misses that the agent got out of: no collision of
    its segment within ``lead_steps`` after the near miss. Its collisions and the near misses that ended in one are
    left out, and so are the windows leading to them (neither adversarial nor benign). Why (issue 16): most struck
    collisions of the heuristic demonstrations are impaired drivers that hardly brake, so skills learned from them
    close in and do not brake; a driver who forced a near miss and broke it off closes in and then brakes or swerves.

    Attributes:
        horizon: window length (steps), the skill horizon (10 = 1 s).
        lead_steps: adversarial windows start at most this many steps before the struck event (None: 2 x horizon,
            the thesis' 2H).
        near_misses: near misses count as events (collisions always do).
        avoided_only: only the struck near misses not followed by a collision of the agent within ``lead_steps``
            count (see above); needs ``near_misses``.
        drop_steps: windows ending within this many steps of an out-of-road end are dropped (the demonstrator
            lost the road, not a skill).
        stride: step between window starts (1: every window).
        benign_sources: names in `SOURCES` whose non-adversarial windows are benign.
    """

    horizon: int = 10
    lead_steps: int | None = None
    near_misses: bool = True
    avoided_only: bool = False
    drop_steps: int = 20
    stride: int = 1
    benign_sources: tuple[str, ...] = ("log",)

    def __post_init__(self) -> None:
        for name in ("horizon", "stride"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"WindowSpec: {name} must be >= 1, got {getattr(self, name)}")
        if self.lead_steps is not None and int(self.lead_steps) < 1:
            raise ValueError(f"WindowSpec: lead_steps must be >= 1 or null, got {self.lead_steps}")
        if int(self.drop_steps) < 0:
            raise ValueError(f"WindowSpec: drop_steps must be >= 0, got {self.drop_steps}")
        if self.avoided_only and not self.near_misses:
            raise ValueError("WindowSpec: avoided_only needs near_misses (it keeps only avoided near misses)")
        bad = [s for s in self.benign_sources if s not in SOURCES]
        if bad:
            raise ValueError(f"WindowSpec: benign_sources {bad} are not among {SOURCES}")
        object.__setattr__(self, "benign_sources", tuple(self.benign_sources))

    @property
    def lead(self) -> int:
        """Steps before a struck event in which adversarial windows start."""
        return 2 * int(self.horizon) if self.lead_steps is None else int(self.lead_steps)

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["benign_sources"] = list(self.benign_sources)
        return d


@dataclass(frozen=True)
class Windows:
    """Labelled windows: first ``row`` into the demonstrations, ``segment`` index and ``label`` (`BENIGN` /
    `ADVERSARIAL`), all ``[W]``; ``n_dropped`` windows were left out near an out-of-road end, ``n_unused`` were
    neither adversarial nor from a benign source."""

    row: np.ndarray
    segment: np.ndarray
    label: np.ndarray
    n_dropped: int
    n_unused: int = 0

    def __len__(self) -> int:
        return int(self.row.shape[0])

    def subset(self, mask: np.ndarray) -> Windows:
        return Windows(self.row[mask], self.segment[mask], self.label[mask], 0, 0)


def label_windows(demos: Demonstrations, spec: WindowSpec) -> Windows:
    """All windows of all segments with their labels (see `WindowSpec`); vectorised over segments and events."""
    seg_row = np.asarray(demos.seg_row, dtype=np.int64)
    seg_len = np.asarray(demos.seg_len, dtype=np.int64)
    reason = np.asarray(demos.seg_end_reason, dtype=np.int64)
    h, stride = int(spec.horizon), int(spec.stride)
    counts = np.where(seg_len >= h, (seg_len - h) // stride + 1, 0)
    total = int(counts.sum())
    seg = np.repeat(np.arange(seg_row.shape[0]), counts)
    first = np.cumsum(counts) - counts
    local = (np.arange(total) - np.repeat(first, counts)) * stride
    start_step = np.asarray(demos.seg_start_step, dtype=np.int64)[seg] + local
    gap = seg_len[seg] - (local + h)
    adversarial = np.zeros(total, dtype=bool)
    left_out = np.zeros(total, dtype=bool)  # windows leading to a struck event that `avoided_only` leaves out
    struck = demos.ev_striker & ((demos.ev_kind != NEAR_MISS_EVENT) | spec.near_misses)
    counted = _avoided_near_misses(demos, spec.lead) if spec.avoided_only else np.ones_like(struck)
    # Per struck event, the windows of its segment: windows are grouped by segment, so a segment's windows are the
    # range first[s] .. first[s] + counts[s].
    for e in np.flatnonzero(struck).tolist():
        s = int(demos.ev_seg[e])
        sl = slice(int(first[s]), int(first[s] + counts[s]))
        before = adversarial_start_mask(start_step[sl], np.full(int(counts[s]), int(demos.ev_step[e])), h, spec.lead)
        target = adversarial if counted[e] else left_out
        target[sl] |= before
    left_out &= ~adversarial
    dropped = (reason[seg] == OUT_OF_ROAD) & (gap < spec.drop_steps) & ~adversarial
    benign_src = np.isin(np.asarray(demos.seg_source)[seg], [SOURCES.index(n) for n in spec.benign_sources])
    unused = ~adversarial & ~dropped & (~benign_src | left_out)
    keep = ~dropped & ~unused
    label = np.where(adversarial, ADVERSARIAL, BENIGN).astype(np.int8)
    return Windows(row=(seg_row[seg] + local)[keep], segment=seg[keep], label=label[keep],
                   n_dropped=int(dropped.sum()), n_unused=int(unused.sum()))


def gather_windows(obs: np.ndarray, actions: np.ndarray, rows: np.ndarray, horizon: int) -> tuple[np.ndarray,
                                                                                                    np.ndarray]:
    """Window arrays ``obs [B, horizon, D]`` float32 and ``actions [B, horizon, 2]`` float32 starting at ``rows``."""
    idx = np.asarray(rows, dtype=np.int64)[:, None] + np.arange(horizon)
    return obs[idx].astype(np.float32), actions[idx].astype(np.float32)


def split_by_scenario(
    windows: Windows, seg_scenario: np.ndarray, n_scenarios: int, val_fraction: float, seed: int
) -> tuple[Windows, Windows]:
    """Training and validation windows, held out by scenario (no window of a held-out scenario in training)."""
    if not 0.0 < val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction}")
    if n_scenarios < 2:
        raise ValueError(f"need at least 2 scenarios to hold out validation, got {n_scenarios}")
    perm = np.random.default_rng(seed).permutation(n_scenarios)
    n_val = min(n_scenarios - 1, max(1, round(val_fraction * n_scenarios)))
    is_val = np.zeros(n_scenarios, dtype=bool)
    is_val[perm[:n_val]] = True
    val = is_val[np.asarray(seg_scenario)[windows.segment]]
    return windows.subset(~val), windows.subset(val)


def _avoided_near_misses(demos: Demonstrations, lead_steps: int) -> np.ndarray:
    """``[E]`` bool: event ``e`` is a near miss and its segment has no collision in ``(step, step + lead_steps]``."""
    ev_seg = np.asarray(demos.ev_seg, dtype=np.int64)
    ev_step = np.asarray(demos.ev_step, dtype=np.int64)
    is_near = np.asarray(demos.ev_kind) == NEAR_MISS_EVENT
    # The first collision of the same segment after each event: collisions keyed by (segment, step), sorted.
    span = int(ev_step.max(initial=0)) + int(lead_steps) + 2
    coll_key = np.sort(ev_seg[~is_near] * span + ev_step[~is_near])
    nxt = np.searchsorted(coll_key, ev_seg * span + ev_step, side="right")
    nxt_key = coll_key[np.minimum(nxt, coll_key.size - 1)] if coll_key.size else np.full(ev_seg.shape, -1)
    followed = (nxt < coll_key.size) & (nxt_key // span == ev_seg) & (nxt_key % span - ev_step <= int(lead_steps))
    return is_near & ~followed
