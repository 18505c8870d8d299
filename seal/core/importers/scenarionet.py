"""ScenarioNet scenario pickles (the unified format of Waymo, nuScenes, nuPlan, Argoverse 2) -> seal scenarios.

Files are read with `seal.core.importers.safe_pickle` (numpy arrays and plain containers only). What is read:

* ``metadata``: ``sdc_id`` (the ego), ``objects_of_interest`` (adversary candidates, in order), ``ts`` (time
  stamps in s; 0.1 s steps when absent), ``dataset`` and ``coordinate`` (recorded; coordinates are used as
  given: x, y in metres in a right-handed frame, headings counter-clockwise, like `seal.core.scenario`);
* ``tracks``: per object ``type`` (``VEHICLE`` -> vehicle, ``PEDESTRIAN``, ``CYCLIST``, anything else ->
  other) and ``state`` arrays of one entry per time stamp: ``position`` ``[T, 2|3]``, ``heading`` ``[T]``,
  ``velocity`` ``[T, 2]`` (from the positions when absent), ``length`` / ``width`` ``[T]`` (defaults by type
  when absent) and ``valid`` ``[T]``. Invalid stretches of up to `MAX_BRIDGE_STEPS` are interpolated (brief
  occlusions); longer gaps split a track and the window keeps one piece (`seal.core.importers.windows`). A
  vehicle wider than long whose heading follows its motion has its length and width swapped back
  (`box_is_swapped`: ScenarioNet's nuScenes converter writes the ego's box that way), counted as
  ``repaired["swapped_boxes"]``; tracks never valid are dropped (``dropped["tracks_never_valid"]``).
  Pedestrians and cyclists stay in the scenario as replayed agents (their logged oriented boxes: the ego's
  sensors see them and overlapping one is a crash); only vehicles can be the ego or the adversary;
* ``map_features``: lane centre lines (``LANE_*`` types except bike lanes) with their width - the per-point
  ``width`` ``[P, 2]`` (distances to the left / right boundary, Waymo), else the lane ``polygon``, else
  `DEFAULT_LANE_WIDTH_M` -, ``exit_lanes`` as successors and ``speed_limit_kmh`` / ``speed_limit_mph``; the
  line type of each lane side comes from the nearest road line or road edge feature along that side
  (``ROAD_EDGE_*`` and solid lines -> ``continuous``, broken lines -> ``striped``, none -> ``none``; the
  drivable-area boundary still gives the road edge there). A lane or line feature whose polyline has fewer than
  2 distinct finite points (real Waymo maps hold single-point lanes) is dropped and counted
  (``dropped["degenerate_map_features"]``), never the whole scenario.

The ego is the SDC (a parked SDC, one that never gets `MIN_DISPLACEMENT_M` from its start, is reported as such
by `parked_ego`: there is nothing to drive); the adversary the first object of interest that is a vehicle with a
usable track, else the most interacting vehicle (`seal.core.importers.windows.find_windows` with a fixed ego).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from seal.core.importers.errors import ImportFormatError
from seal.core.importers.lanes import LaneGeometry, chunked_lines, lane_pieces, link_successors, sample_along
from seal.core.importers.safe_pickle import safe_load
from seal.core.importers.tracks import AgentLog, resample_states, speeds_from_positions
from seal.core.interaction import MIN_DISPLACEMENT_M
from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import DT_S, TRACK_FIELDS, VALID, X, Y

LANE_TYPES = ("LANE_SURFACE_STREET", "LANE_SURFACE_UNSTRUCTURE", "LANE_UNKNOWN", "LANE_FREEWAY")
AGENT_TYPE = {"VEHICLE": "vehicle", "PEDESTRIAN": "pedestrian", "CYCLIST": "cyclist"}
DEFAULT_SIZE_M = {"vehicle": (4.5, 1.9), "pedestrian": (0.6, 0.6), "cyclist": (1.8, 0.7), "other": (1.0, 1.0)}
"""(length, width) by agent type when a track has no size."""
DEFAULT_LANE_WIDTH_M = 3.7
DEFAULT_SPEED_LIMIT_MPS = 30.0
MAX_BRIDGE_STEPS = 5
"""Invalid stretches of at most this many steps between valid ones are interpolated (0.5 s at 10 Hz)."""
WIDTH_TOLERANCE_M = 0.5
"""Width variation within one lane piece (recorded per-point widths are noisier than CommonRoad bounds)."""
LINE_MATCH_M = 0.75
"""A road line within this distance (m) of a lane border is that border's paint."""
LINE_SAMPLE_M = 4.0
SWAP_MIN_SPEED_MPS = 1.0
"""Steps slower than this (m/s) tell nothing about the direction of travel (`box_is_swapped`)."""
SWAP_MIN_ALIGNMENT = math.cos(math.radians(30.0))
"""Heading within 30 degrees of the direction of travel (or of its reverse) counts as following the motion."""


@dataclass(frozen=True)
class ScenarioNetRecording:
    """A parsed ScenarioNet scenario: road, agents on the 10 Hz grid, ego and adversary candidates (rows)."""

    path: Path
    scenario_id: str
    dataset: str
    coordinate: str
    road: RoadDescription
    log: AgentLog
    sdc_row: int
    interest_rows: tuple[int, ...]
    repaired: dict[str, int] = field(default_factory=dict)
    """``swapped_boxes``: vehicles whose length and width were swapped back (`box_is_swapped`)."""
    dropped: dict[str, int] = field(default_factory=dict)
    """``degenerate_map_features`` (fewer than 2 distinct points), ``tracks_never_valid``."""


def _fail(path: Path, element: str, problem: str) -> ImportFormatError:
    return ImportFormatError(path, element, problem)


def _array(path: Path, value: Any, element: str, shape_tail: tuple[int, ...] | None, length: int) -> np.ndarray:
    """``value`` as float64 ``[length, *tail]`` (a ``[length, 1]`` column is accepted for ``tail == ()``)."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(path, element, f"must be a numeric array, got {type(value).__name__}") from None
    if shape_tail == () and arr.ndim == 2 and arr.shape[1] == 1:
        arr = arr[:, 0]
    if arr.shape[0:1] != (length,) or (shape_tail is not None and arr.shape[1:] != shape_tail):
        want = f"[{length}{''.join(f', {d}' for d in shape_tail)}]" if shape_tail is not None else f"[{length}, ...]"
        raise _fail(path, element, f"must have shape {want}, got {list(arr.shape)}")
    return arr


def _mapping(path: Path, value: Any, element: str) -> dict:
    if not isinstance(value, dict):
        raise _fail(path, element, f"must be a dict, got {type(value).__name__}")
    return value


# ------------------------------------------------------------------------------------------------ tracks
def bridge_gaps(valid: np.ndarray, max_steps: int = MAX_BRIDGE_STEPS) -> np.ndarray:
    """``valid`` ``[T]`` with invalid stretches of at most ``max_steps`` between two valid steps filled in."""
    out = valid.copy()
    idx = np.flatnonzero(valid)
    for a, b in zip(idx[:-1], idx[1:], strict=True):
        if 1 < b - a <= max_steps + 1:
            out[a:b] = True
    return out


def box_is_swapped(
    kind: str, times: np.ndarray, pos: np.ndarray, heading: np.ndarray, length: np.ndarray, width: np.ndarray,
    valid: np.ndarray,
) -> bool:
    """A vehicle's box has length and width swapped: wider than long (medians over its ``valid`` steps) while its
    heading follows its motion (median ``|cos|`` of the angle between heading and the direction of travel above
    `SWAP_MIN_ALIGNMENT`, over steps faster than `SWAP_MIN_SPEED_MPS`). Then the box, not the heading, is wrong
    (ScenarioNet's nuScenes converter swaps the ego's size). Without such motion nothing is decided: False.

    Args: ``times [T]`` (s), ``pos [T, >=2]`` (m), ``heading [T]`` (rad), ``length`` / ``width [T]`` (m),
    ``valid [T]`` bool (only finite steps should be valid).
    """
    idx = np.flatnonzero(valid)
    if kind != "vehicle" or idx.size < 2 or not np.median(width[idx]) > np.median(length[idx]):
        return False
    step = np.diff(pos[idx, :2], axis=0)
    dist = np.hypot(step[:, 0], step[:, 1])
    moving = dist > SWAP_MIN_SPEED_MPS * np.diff(times[idx])
    if moving.sum() < 2:
        return False
    travel = np.arctan2(step[moving, 1], step[moving, 0])
    return bool(np.median(np.abs(np.cos(travel - heading[idx[:-1]][moving]))) > SWAP_MIN_ALIGNMENT)


def _track_rows(
    path: Path, tid: str, obj: Any, times: np.ndarray, n_grid: int
) -> tuple[np.ndarray, str, bool] | None:
    """``[n_grid, 8]`` grid rows of one track, its agent type and whether its box was swapped back
    (`box_is_swapped`); None when it is never valid."""
    where = f"tracks[{tid!r}]"
    obj = _mapping(path, obj, where)
    state = _mapping(path, obj.get("state"), f"{where}.state")
    kind = AGENT_TYPE.get(str(obj.get("type", "")).upper(), "other")
    t = len(times)
    for key in ("position", "heading", "valid"):
        if key not in state:
            raise _fail(path, f"{where}.state", f"missing array {key!r}")
    valid = _array(path, state["valid"], f"{where}.state.valid", (), t) > 0.5
    if not valid.any():
        return None
    pos = _array(path, state["position"], f"{where}.state.position", None, t)
    if pos.ndim != 2 or pos.shape[1] not in (2, 3):
        raise _fail(path, f"{where}.state.position", f"must have shape [{t}, 2 or 3], got {list(pos.shape)}")
    heading = _array(path, state["heading"], f"{where}.state.heading", (), t)
    size = []
    for key, default in zip(("length", "width"), DEFAULT_SIZE_M[kind], strict=True):
        if key in state:
            v = _array(path, state[key], f"{where}.state.{key}", (), t)
            v = np.where(v > 0, v, default)
        else:
            v = np.full(t, default)
        size.append(v)
    vel = _array(path, state["velocity"], f"{where}.state.velocity", (2,), t) if "velocity" in state else None
    usable = valid & np.isfinite(pos[:, :2]).all(1) & np.isfinite(heading)
    swapped = box_is_swapped(kind, times, pos, heading, size[0], size[1], usable)
    if swapped:
        size.reverse()
    bridged = bridge_gaps(valid)
    rows = np.zeros((n_grid, len(TRACK_FIELDS)))
    idx = np.flatnonzero(bridged)
    breaks = np.flatnonzero(np.diff(idx) > 1)
    for block in np.split(idx, breaks + 1):
        real = block[valid[block]]  # interpolate across the bridged steps from the real ones
        finite = np.isfinite(pos[real, :2]).all(1) & np.isfinite(heading[real])
        real = real[finite]
        if real.size == 0:
            continue
        tt = times[real]
        if vel is not None and np.isfinite(vel[real]).all():
            vx, vy = vel[real, 0], vel[real, 1]
        else:
            sp = speeds_from_positions(tt, pos[real, 0], pos[real, 1])
            vx, vy = sp * np.cos(heading[real]), sp * np.sin(heading[real])
        g = resample_states(tt, pos[real, 0], pos[real, 1], heading[real], vx, vy, size[0][real], size[1][real])
        if g is not None:
            end = min(n_grid, g.first + len(g.rows))
            rows[g.first : end] = g.rows[: end - g.first]
    if not (rows[:, -1] > 0.5).any():
        return None
    return rows, kind, swapped


def _times(path: Path, data: dict, meta: dict) -> np.ndarray:
    tracks = data["tracks"]
    length = data.get("length")
    if length is None:
        first = next(iter(tracks.values()), None)
        state = first.get("state", {}) if isinstance(first, dict) else {}
        length = len(state.get("valid", ())) if isinstance(state, dict) else 0
    if "ts" in meta:
        ts = np.asarray(meta["ts"], dtype=np.float64).reshape(-1)
        if ts.shape[0] != int(length):
            raise _fail(path, "metadata.ts", f"has {ts.shape[0]} time stamps, the scenario has {length} steps")
        if ts.shape[0] > 1 and not (np.diff(ts) > 0).all():
            raise _fail(path, "metadata.ts", "time stamps must increase")
        return ts - ts[0]
    return np.arange(int(length)) * DT_S


# ------------------------------------------------------------------------------------------------ map
def _line_kind(feature_type: str) -> str | None:
    t = feature_type.upper()
    if t.startswith("ROAD_EDGE") or t == "UNKNOWN":
        return "continuous"
    if t.startswith("ROAD_LINE") or t == "UNKNOWN_LINE":
        return "continuous" if "SOLID" in t else "striped"
    return None


def _lane_width(path: Path, fid: str, feat: dict, centre: np.ndarray, n_raw: int) -> np.ndarray:
    """Full width (m) at each centre point."""
    where = f"map_features[{fid!r}]"
    if "width" in feat:
        w = np.asarray(feat["width"], dtype=np.float64)
        if w.ndim == 2 and w.shape == (n_raw, 2):
            left, right = w[:, 0], w[:, 1]
            left = np.where(left > 0, left, right)
            right = np.where(right > 0, right, left)
            full = left + right
            known = full > 0.5
            if known.any():
                return np.where(known, full, np.median(full[known]))
        elif w.ndim == 0 and float(w) > 0:
            return np.full(n_raw, float(w))
        else:
            raise _fail(path, f"{where}.width", f"must have shape [{n_raw}, 2], got {list(w.shape)}")
    if "polygon" in feat:
        poly = np.asarray(feat["polygon"], dtype=np.float64)
        if poly.ndim == 2 and poly.shape[0] >= 3 and poly.shape[1] >= 2:
            line = shapely.LineString(centre)
            d = shapely.distance(shapely.points(poly[:, :2]), line)
            half = float(np.median(d))
            if half > 0.25:
                return np.full(n_raw, 2 * half)
    return np.full(n_raw, DEFAULT_LANE_WIDTH_M)


def _side_types(lanes: list[LaneSpec], lines: list[tuple[np.ndarray, str]]) -> list[LaneSpec]:
    """Lanes with each side's line type from the nearest road line / edge along it (module docstring).

    All lane borders are sampled every `LINE_SAMPLE_M` and matched in one spatial query against short pieces of
    the road lines; a side takes the majority type of its matched samples when at least half of them match.
    """
    if not lines:
        return [LaneSpec(p.lane_id, p.centerline, p.width_m, ("none", "none"), p.speed_limit_mps, p.successors)
                for p in lanes]
    geoms, owner = chunked_lines([pts for pts, _ in lines])
    solid = np.array([kind == "continuous" for _, kind in lines])[owner]
    pts, side_of = [], []
    for k, lane in enumerate(lanes):
        centre, normal = sample_along(lane.centerline, LINE_SAMPLE_M)
        for side, sign in enumerate((1.0, -1.0)):
            pts.append(centre + sign * 0.5 * lane.width_m * normal)
            side_of.append(np.full(len(centre), 2 * k + side))
    samples = shapely.points(np.concatenate(pts))
    owner_side = np.concatenate(side_of)
    hit_s, hit_g = shapely.STRtree(geoms).query(samples, predicate="dwithin", distance=LINE_MATCH_M)
    n_sides = 2 * len(lanes)
    n_samples = np.bincount(owner_side, minlength=n_sides)
    n_matched: np.ndarray  # [2 * lanes] sampled points with a line nearby (counts; zeros as floats when none)
    n_solid: np.ndarray
    if hit_s.size:
        dist = shapely.distance(samples[hit_s], np.asarray(geoms, dtype=object)[hit_g])
        order = np.lexsort((dist, hit_s))  # the nearest line piece of each matched sample
        first = order[np.unique(hit_s[order], return_index=True)[1]]
        matched_side = owner_side[hit_s[first]]
        n_matched = np.bincount(matched_side, minlength=n_sides)
        n_solid = np.bincount(matched_side, weights=solid[hit_g[first]], minlength=n_sides)
    else:
        n_matched = n_solid = np.zeros(n_sides)
    kinds = np.where(n_matched < 0.5 * n_samples, "none", np.where(n_solid >= 0.5 * n_matched, "continuous", "striped"))
    return [
        LaneSpec(p.lane_id, p.centerline, p.width_m, (str(kinds[2 * k]), str(kinds[2 * k + 1])), p.speed_limit_mps,
                 p.successors)
        for k, p in enumerate(lanes)
    ]


def read_road(path: Path, features: dict) -> tuple[RoadDescription, int]:
    """Lanes of ``map_features`` as a ``polylines`` `RoadDescription` (module docstring), and the number of lane
    and line features dropped because their polyline has fewer than 2 distinct finite points."""
    degenerate = 0
    pieces: dict[str, list[LaneSpec]] = {}
    successors: dict[str, list[str]] = {}
    lines: list[tuple[np.ndarray, str]] = []
    for raw_id, feat in features.items():
        fid = str(raw_id)
        where = f"map_features[{fid!r}]"
        if not isinstance(feat, dict):
            raise _fail(path, where, f"must be a dict, got {type(feat).__name__}")
        ftype = str(feat.get("type", ""))
        kind = _line_kind(ftype)
        if ftype not in LANE_TYPES and kind is None:
            continue
        if "polyline" not in feat:
            raise _fail(path, where, f"{ftype} feature has no 'polyline'")
        try:
            pts = np.asarray(feat["polyline"], dtype=np.float64)
        except (TypeError, ValueError):
            raise _fail(path, f"{where}.polyline", "must be a numeric array") from None
        if pts.size == 0:
            pts = pts.reshape(0, 2)
        if pts.ndim != 2 or pts.shape[1] < 2:
            raise _fail(path, f"{where}.polyline", f"must be a [P, 2 or 3] array, got {list(pts.shape)}")
        finite = np.isfinite(pts[:, :2]).all(1)
        pts = pts[:, :2]
        # Consecutive duplicates and non-finite points carry no shape; fewer than 2 distinct points: no line.
        keep = finite & np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-6])
        if keep.sum() < 2:
            degenerate += 1
            continue
        if kind is not None:
            lines.append((pts[finite], kind))
            continue
        width = _lane_width(path, fid, feat, pts, len(pts))
        limit = DEFAULT_SPEED_LIMIT_MPS
        if float(feat.get("speed_limit_kmh", 0) or 0) > 0:
            limit = float(feat["speed_limit_kmh"]) / 3.6
        elif float(feat.get("speed_limit_mph", 0) or 0) > 0:
            limit = float(feat["speed_limit_mph"]) * 0.44704
        pieces[fid] = lane_pieces(fid, LaneGeometry(pts[keep], width[keep]), ("none", "none"), limit,
                                  tolerance_m=WIDTH_TOLERANCE_M)
        successors[fid] = [str(s) for s in feat.get("exit_lanes", []) or []]
    lanes = link_successors(pieces, successors)
    if not lanes:
        extra = f"; {degenerate} degenerate feature(s) with fewer than 2 distinct points dropped" if degenerate else ""
        raise _fail(path, "map_features", f"no lane centre lines (features of type {', '.join(LANE_TYPES)}){extra}")
    return RoadDescription(layout="polylines", lanes=tuple(_side_types(lanes, lines)), params={}), degenerate


# ------------------------------------------------------------------------------------------------ entry
def read_scenarionet(path: str | Path) -> ScenarioNetRecording:
    """Parse a ScenarioNet pickle (module docstring); raises `ImportFormatError` on bad input."""
    path = Path(path)
    data = _mapping(path, safe_load(path), "scenario")
    for key in ("tracks", "map_features", "metadata"):
        if key not in data:
            raise _fail(path, "scenario", f"missing key {key!r}; not a ScenarioNet scenario")
    tracks = _mapping(path, data["tracks"], "tracks")
    meta = _mapping(path, data["metadata"], "metadata")
    features = _mapping(path, data["map_features"], "map_features")
    if "sdc_id" not in meta:
        raise _fail(path, "metadata.sdc_id", "missing; the SDC is the ego")
    sdc = str(meta["sdc_id"])
    if sdc not in {str(k) for k in tracks}:
        raise _fail(path, "metadata.sdc_id", f"{sdc!r} is not among the tracks")
    times = _times(path, data, meta)
    n_grid = int(math.floor(times[-1] / DT_S + 1e-6)) + 1 if len(times) else 0
    rows, kinds, sids = [], [], []
    swapped = never_valid = 0
    for raw_id, obj in tracks.items():
        got = _track_rows(path, str(raw_id), obj, times, n_grid)
        if got is None:
            never_valid += 1
            continue
        rows.append(got[0])
        kinds.append(got[1])
        sids.append(str(raw_id))
        swapped += got[2]
    if sdc not in sids:
        raise _fail(path, f"tracks[{sdc!r}]", "the SDC track is never valid")
    numeric = all(s.lstrip("-").isdigit() for s in sids) and len({int(s) for s in sids}) == len(sids)
    ids = np.array([int(s) for s in sids] if numeric else range(len(sids)), dtype=np.int64)
    log = AgentLog(np.stack(rows), ids, tuple(kinds), tuple(sids))
    interest = [str(o) for o in (meta.get("objects_of_interest") or [])]
    interest_rows = tuple(sids.index(o) for o in interest if o in sids and o != sdc)
    road, degenerate = read_road(path, features)
    dataset = str(meta.get("dataset", "unknown"))
    road = RoadDescription(layout="polylines", lanes=road.lanes, params={"source": "scenarionet", "dataset": dataset})
    scenario_id = str(data.get("id", meta.get("scenario_id", path.stem)))
    return ScenarioNetRecording(
        path, scenario_id, dataset, str(meta.get("coordinate", "unknown")), road, log, sids.index(sdc), interest_rows,
        repaired={"swapped_boxes": swapped},
        dropped={"degenerate_map_features": degenerate, "tracks_never_valid": never_valid},
    )


def parked_ego(rec: ScenarioNetRecording) -> str | None:
    """Why the SDC cannot be an ego when it is parked (it never gets `MIN_DISPLACEMENT_M` from where it is first
    logged), else None: a parked ego gives no scenario to drive."""
    row = rec.log.tracks[rec.sdc_row]
    xy = row[row[:, VALID] > 0.5][:, [X, Y]]
    reach = float(np.hypot(*(xy - xy[0]).T).max()) if len(xy) else 0.0
    if reach >= MIN_DISPLACEMENT_M:
        return None
    return (
        f"the self-driving car (the ego) is parked: it stays within {reach:.1f} m of where it starts over the "
        f"{len(xy) * DT_S:.1f} s it is logged (an ego must travel at least {MIN_DISPLACEMENT_M:.0f} m); "
        "nothing to drive"
    )


def describe(rec: ScenarioNetRecording) -> dict[str, object]:
    """Provenance of a recording for scenario metadata (JSON-serialisable)."""
    return {
        # the source dataset (waymo, nuplan, ...) keeps recordings of different origins apart
        "layout": rec.dataset if rec.dataset not in ("", "unknown") else "scenarionet",
        "source": "scenarionet",
        "source_file": rec.path.name,
        "dataset": rec.dataset,
        "source_scenario_id": rec.scenario_id,
        "coordinate": rec.coordinate,
        "objects_of_interest": [rec.log.source_ids[r] for r in rec.interest_rows],
    }
