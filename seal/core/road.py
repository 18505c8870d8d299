"""Road description: enough geometry to rebuild a road without a simulator.

A road is a set of lanes. Each lane is a centre polyline in world metres with a constant width, the type of
line painted on its left and right borders (left/right as seen when driving along the lane), a speed limit
and the ids of the lanes it continues into. Generated roads also keep the highway-env layout name and its
parameters so the exact highway-env network can be rebuilt; imported roads use ``layout="polylines"``.

Everything here is plain data (numpy + JSON): `scoring` and the dataset store use it without highway-env.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

import numpy as np

LINE_TYPES = ("none", "striped", "continuous")
"""Allowed lane border line types. ``continuous`` borders are road edges / medians, ``striped`` are lane lines."""


class RoadError(ValueError):
    """A road description is malformed."""


@dataclass(frozen=True)
class LaneSpec:
    """One lane.

    Attributes:
        lane_id: unique id within the road, e.g. ``"a:b:0"`` (highway-env ``from:to:index``).
        centerline: ``[P, 2]`` float64 polyline of the lane centre in world metres, P >= 2, in driving order.
        width_m: lane width in metres (> 0).
        line_types: (left, right) border line types, each one of `LINE_TYPES`.
        speed_limit_mps: speed limit in m/s (> 0).
        successors: lane ids this lane continues into (may be empty).
    """

    lane_id: str
    centerline: np.ndarray
    width_m: float
    line_types: tuple[str, str] = ("striped", "striped")
    speed_limit_mps: float = 30.0
    successors: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        pts = np.asarray(self.centerline, dtype=np.float64)
        object.__setattr__(self, "centerline", pts)
        where = f"lane {self.lane_id!r}"
        if pts.ndim != 2 or pts.shape[0] < 2 or pts.shape[1] != 2:
            raise RoadError(f"{where}: field 'centerline' must have shape [P>=2, 2], got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            raise RoadError(f"{where}: field 'centerline' contains NaN or inf")
        if not (np.isfinite(self.width_m) and self.width_m > 0):
            raise RoadError(f"{where}: field 'width_m' must be a positive number, got {self.width_m}")
        if not (np.isfinite(self.speed_limit_mps) and self.speed_limit_mps > 0):
            raise RoadError(f"{where}: field 'speed_limit_mps' must be positive, got {self.speed_limit_mps}")
        if len(self.line_types) != 2 or any(t not in LINE_TYPES for t in self.line_types):
            raise RoadError(f"{where}: field 'line_types' must be two of {LINE_TYPES}, got {self.line_types}")
        object.__setattr__(self, "line_types", tuple(self.line_types))
        object.__setattr__(self, "successors", tuple(self.successors))

    @property
    def length_m(self) -> float:
        """Arc length of the centre polyline in metres."""
        return float(np.sum(np.linalg.norm(np.diff(self.centerline, axis=0), axis=1)))

    def to_dict(self) -> dict[str, Any]:
        return {
            "lane_id": self.lane_id,
            "centerline": np.round(self.centerline, 3).tolist(),
            "width_m": float(self.width_m),
            "line_types": list(self.line_types),
            "speed_limit_mps": float(self.speed_limit_mps),
            "successors": list(self.successors),
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LaneSpec:
        try:
            return cls(
                lane_id=str(d["lane_id"]),
                centerline=np.asarray(d["centerline"], dtype=np.float64),
                width_m=float(d["width_m"]),
                line_types=tuple(d["line_types"]),
                speed_limit_mps=float(d["speed_limit_mps"]),
                successors=tuple(d.get("successors", ())),
            )
        except KeyError as exc:
            raise RoadError(f"lane {d.get('lane_id', '?')!r}: missing field {exc.args[0]!r}") from None


@dataclass(frozen=True)
class RoadDescription:
    """A road: a layout name with its parameters plus the lanes as polylines.

    Attributes:
        layout: ``"highway"``, ``"merge"``, ``"intersection"``, ``"roundabout"`` (generated, rebuildable with
            ``seal.envs.layouts``) or ``"polylines"`` (imported: only the lanes are known).
        params: JSON-serialisable layout parameters (e.g. number of lanes, radius in metres).
        lanes: the lanes; ids must be unique and successors must exist.
    """

    layout: str
    lanes: tuple[LaneSpec, ...]
    params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "lanes", tuple(self.lanes))
        if not self.lanes:
            raise RoadError(f"road {self.layout!r}: field 'lanes' is empty")
        ids = [lane.lane_id for lane in self.lanes]
        if len(set(ids)) != len(ids):
            dup = sorted({i for i in ids if ids.count(i) > 1})
            raise RoadError(f"road {self.layout!r}: duplicate lane ids {dup}")
        known = set(ids)
        for lane in self.lanes:
            missing = [s for s in lane.successors if s not in known]
            if missing:
                raise RoadError(f"road {self.layout!r}: lane {lane.lane_id!r} has unknown successors {missing}")

    def lane(self, lane_id: str) -> LaneSpec:
        for lane in self.lanes:
            if lane.lane_id == lane_id:
                return lane
        raise KeyError(f"road {self.layout!r} has no lane {lane_id!r}")

    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of all lane centre lines, in metres."""
        pts = np.concatenate([lane.centerline for lane in self.lanes])
        return float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max())

    def to_dict(self) -> dict[str, Any]:
        return {"layout": self.layout, "params": self.params, "lanes": [lane.to_dict() for lane in self.lanes]}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), separators=(",", ":"), sort_keys=True)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> RoadDescription:
        if "layout" not in d or "lanes" not in d:
            raise RoadError("road description needs fields 'layout' and 'lanes'")
        return cls(
            layout=str(d["layout"]),
            lanes=tuple(LaneSpec.from_dict(x) for x in d["lanes"]),
            params=dict(d.get("params", {})),
        )

    @classmethod
    def from_json(cls, text: str) -> RoadDescription:
        return cls.from_dict(json.loads(text))
