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

FORMAT = "seal-skill-demos"
FORMAT_VERSION = 1
BENIGN, ADVERSARIAL = 0, 1
LABEL_NAMES = ("benign", "adversarial")

_SEG_FIELDS = {
    "seg_row": np.int64, "seg_len": np.int32, "seg_scenario": np.int32, "seg_agent": np.int64,
    "seg_start_step": np.int32, "seg_end_reason": np.int8, "seg_impaired": np.bool_,
}


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
                                f"this seal reads {FORMAT_VERSION}")
        missing = [k for k in ("obs", "actions", "scenario_ids", "params", *_SEG_FIELDS) if k not in data]
        if missing:
            raise DemoFileError(f"{where}: missing field(s) {missing}")
        try:
            params = json.loads(str(data["params"]))
        except json.JSONDecodeError as exc:
            raise DemoFileError(f"{where}: field 'params' is not JSON ({exc})") from None
        demos = cls(
            obs=data["obs"], actions=data["actions"].astype(np.float32),
            **{name: data[name].astype(dtype) for name, dtype in _SEG_FIELDS.items()},
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
            scenario_ids=np.concatenate([np.asarray(p.scenario_ids, dtype=str) for p in parts]),
            params=dict(params if params is not None else parts[0].params),
        )

    # ------------------------------------------------------------------------------------------------ stats
    def stats(self, spec: WindowSpec | None = None) -> dict[str, Any]:
        """Counts: scenarios, agents, rows, end reasons, collision shares and windows per class under ``spec``."""
        reasons = {name: int((self.seg_end_reason == k).sum()) for k, name in enumerate(END_REASONS)}
        coll = self.seg_end_reason == COLLISION
        scen_coll = np.unique(self.seg_scenario[coll]).size
        win = label_windows(self.seg_row, self.seg_len, self.seg_end_reason, spec or WindowSpec())
        imp = self.seg_impaired
        return {
            "scenarios": len(self.scenario_ids),
            "agents": self.n_segments,
            "agent_steps": self.n_rows,
            "end_reasons": reasons,
            "collision_share_agents": round(float(coll.mean()) if coll.size else 0.0, 4),
            "collision_share_scenarios": round(scen_coll / max(1, len(self.scenario_ids)), 4),
            "collision_share_impaired": round(float(coll[imp].mean()) if imp.any() else 0.0, 4),
            "collision_share_unimpaired": round(float(coll[~imp].mean()) if (~imp).any() else 0.0, 4),
            "out_of_road_share_agents": round(reasons[END_REASONS[OUT_OF_ROAD]] / max(1, self.n_segments), 4),
            "windows_benign": int((win.label == BENIGN).sum()),
            "windows_adversarial": int((win.label == ADVERSARIAL).sum()),
            "windows_dropped": int(win.n_dropped),
        }


@dataclass(frozen=True)
class WindowSpec:
    """How agent segments are cut into windows and labelled (thesis 6.3.2).

    A window starting at local row ``s`` of a segment of ``n`` rows covers rows ``s .. s + horizon - 1`` and
    ends ``gap = n - (s + horizon)`` steps before the segment's end event (gap 0: its last action led straight
    into the event).

    Attributes:
        horizon: window length (steps), the skill horizon (10 = 1 s).
        adversarial_steps: windows of a segment that ended in a collision with ``gap < adversarial_steps`` (i.e.
            ending within the last 20 steps before the collision) are adversarial.
        drop_steps: windows of a segment that ended out of road with ``gap < drop_steps`` are dropped.
        stride: step between window starts (1: every window).
    """

    horizon: int = 10
    adversarial_steps: int = 20
    drop_steps: int = 20
    stride: int = 1

    def __post_init__(self) -> None:
        for name in ("horizon", "adversarial_steps", "stride"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"WindowSpec: {name} must be >= 1, got {getattr(self, name)}")
        if int(self.drop_steps) < 0:
            raise ValueError(f"WindowSpec: drop_steps must be >= 0, got {self.drop_steps}")

    def to_dict(self) -> dict[str, int]:
        return asdict(self)


@dataclass(frozen=True)
class Windows:
    """Labelled windows: first ``row`` into the demonstrations, ``segment`` index and ``label`` (`BENIGN` /
    `ADVERSARIAL`), all ``[W]``; ``n_dropped`` windows were left out (near an out-of-road end)."""

    row: np.ndarray
    segment: np.ndarray
    label: np.ndarray
    n_dropped: int

    def __len__(self) -> int:
        return int(self.row.shape[0])

    def subset(self, mask: np.ndarray) -> Windows:
        return Windows(self.row[mask], self.segment[mask], self.label[mask], 0)


def label_windows(
    seg_row: np.ndarray, seg_len: np.ndarray, seg_end_reason: np.ndarray, spec: WindowSpec
) -> Windows:
    """All windows of all segments with their labels (see `WindowSpec`); vectorised over segments."""
    seg_row = np.asarray(seg_row, dtype=np.int64)
    seg_len = np.asarray(seg_len, dtype=np.int64)
    reason = np.asarray(seg_end_reason, dtype=np.int64)
    h, stride = int(spec.horizon), int(spec.stride)
    counts = np.where(seg_len >= h, (seg_len - h) // stride + 1, 0)
    total = int(counts.sum())
    seg = np.repeat(np.arange(seg_row.shape[0]), counts)
    first = np.cumsum(counts) - counts
    local = (np.arange(total) - np.repeat(first, counts)) * stride
    gap = seg_len[seg] - (local + h)
    r = reason[seg]
    adversarial = (r == COLLISION) & (gap < spec.adversarial_steps)
    dropped = (r == OUT_OF_ROAD) & (gap < spec.drop_steps)
    keep = ~dropped
    label = np.where(adversarial, ADVERSARIAL, BENIGN).astype(np.int8)
    return Windows(row=(seg_row[seg] + local)[keep], segment=seg[keep], label=label[keep],
                   n_dropped=int(dropped.sum()))


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
