"""CommonRoad XML scenarios (``commonRoadVersion`` 2018b and 2020a) -> seal scenarios.

What is read:

* the root's ``commonRoadVersion`` (one of `SUPPORTED_VERSIONS`), ``timeStepSize`` (s) and ``benchmarkID``;
* ``lanelet``: ``leftBound`` / ``rightBound`` polylines (left / right as seen driving along the lanelet, the
  same convention as `seal.core.road`) with their ``lineMarking`` (``solid`` / ``broad_solid`` -> ``continuous``,
  ``dashed`` / ``broad_dashed`` -> ``striped``, ``no_marking`` -> ``none``; missing or ``unknown``: ``striped``
  towards an adjacent lanelet driven the same way, ``continuous`` towards an oncoming one (a median), ``none``
  without an adjacent lanelet: unmarked, so crossing it is no "solid line"; the drivable area still ends the road),
  ``successor`` references, and the speed limit (2018b ``speedLimit``; 2020a ``trafficSignRef`` to a max-speed
  sign, ids 274 / R2-1); without one, `DEFAULT_SPEED_LIMIT_MPS`. Lanes become `seal.core.road.LaneSpec` pieces
  (`seal.core.importers.lanes`): centre line midway between the bounds, width from the bounds, on-ramps included;
* obstacles (2020a ``dynamicObstacle`` / ``staticObstacle``; 2018b ``obstacle`` with ``role``): ``type``, a
  ``rectangle`` (or ``circle``) shape, the ``initialState`` and the ``trajectory`` states (``time`` step,
  ``position`` of the shape centre, ``orientation``, ``velocity`` along the orientation; missing velocities
  come from the positions). Uncertain states (the format allows them; e.g. BMW-sourced files) are read as their
  middle: a ``position`` given as a ``rectangle`` / ``circle`` / ``polygon`` as the shape's centre, an
  ``orientation`` / ``velocity`` given as ``intervalStart`` / ``intervalEnd`` as the midpoint; they are counted
  (`CommonRoadRecording.uncertain_states`). Pedestrians and bicycles are kept as replayed agents (their
  rectangle or circle box), never as ego or adversary.
  Static obstacles stand still for the whole recording. Trajectories at another rate
  than 10 Hz are resampled (`seal.core.importers.tracks`).

Bad input raises `ImportFormatError` naming the file and the element: malformed XML, an unsupported version,
no lanelets, a lanelet without bounds, an obstacle without a usable shape or state, a trajectory with missing
time steps (a gap: CommonRoad trajectories have one state per time step), non-numeric values.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import shapely

from seal.core.importers.errors import ImportFormatError
from seal.core.importers.lanes import geometry_from_bounds, lane_pieces, link_successors
from seal.core.importers.tracks import (
    AgentLog,
    GridTrack,
    grid_step,
    resample_states,
    speeds_from_positions,
    stack_tracks,
)
from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import DT_S, TRACK_FIELDS

SUPPORTED_VERSIONS = ("2018b", "2020a")
DEFAULT_SPEED_LIMIT_MPS = 30.0
MARKINGS = {
    "solid": "continuous",
    "broad_solid": "continuous",
    "dashed": "striped",
    "broad_dashed": "striped",
    "no_marking": "none",
}
"""CommonRoad ``lineMarking`` -> `seal.core.road.LINE_TYPES`; ``unknown`` and missing markings are inferred."""
AGENT_TYPE = {
    "car": "vehicle", "truck": "vehicle", "bus": "vehicle", "taxi": "vehicle", "priorityVehicle": "vehicle",
    "parkedVehicle": "vehicle", "motorcycle": "vehicle", "bicycle": "cyclist", "pedestrian": "pedestrian",
}
"""CommonRoad obstacle ``type`` -> `seal.core.scenario.AGENT_TYPES` (anything else: ``other``)."""
SPEED_SIGNS = ("274", "R2-1")
"""Traffic sign ids of a maximum speed (Germany, USA); their ``additionalValue`` is in m/s."""


@dataclass(frozen=True)
class CommonRoadRecording:
    """A parsed CommonRoad file: its road and its agents on the 10 Hz grid."""

    path: Path
    version: str
    benchmark_id: str
    time_step_s: float
    road: RoadDescription
    log: AgentLog
    tags: tuple[str, ...]
    uncertain_states: int = 0
    """States whose position (a shape), orientation or velocity (an interval) was uncertain, read as the shape's
    centre / the interval's midpoint."""
    dropped: dict[str, int] = field(default_factory=dict)
    """``obstacles_between_grid_points``: dynamic obstacles logged only between two 0.1 s grid points."""


class _Reader:
    """Element accessors that raise `ImportFormatError` naming the file and the element."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, element: str, problem: str) -> ImportFormatError:
        return ImportFormatError(self.path, element, problem)

    def child(self, elem: ET.Element, tag: str, where: str) -> ET.Element:
        found = elem.find(tag)
        if found is None:
            raise self.fail(where, f"missing <{tag}>")
        return found

    def number(self, elem: ET.Element, tag: str, where: str) -> float:
        node = self.child(elem, tag, where)
        try:
            value = float((node.text or "").strip())
        except ValueError:
            raise self.fail(where, f"<{tag}> is not a number: {node.text!r}") from None
        if not math.isfinite(value):
            raise self.fail(where, f"<{tag}> is not finite: {node.text!r}")
        return value

    def exact(self, elem: ET.Element, tag: str, where: str) -> float:
        """Value of ``<tag><exact>v</exact></tag>`` (time steps of a trajectory must be exact)."""
        node = self.child(elem, tag, where)
        if node.find("exact") is None:
            raise self.fail(where, f"<{tag}> must hold an <exact> value (got {[c.tag for c in node]})")
        return self.number(node, "exact", f"{where} <{tag}>")

    def value(self, elem: ET.Element, tag: str, where: str) -> tuple[float, bool]:
        """(value, uncertain) of ``<tag>``: its ``<exact>`` value, or the midpoint of an uncertain
        ``<intervalStart>`` / ``<intervalEnd>`` (then ``uncertain`` is True)."""
        node = self.child(elem, tag, where)
        if node.find("exact") is not None:
            return self.number(node, "exact", f"{where} <{tag}>"), False
        if node.find("intervalStart") is not None and node.find("intervalEnd") is not None:
            lo = self.number(node, "intervalStart", f"{where} <{tag}>")
            hi = self.number(node, "intervalEnd", f"{where} <{tag}>")
            if hi < lo:
                raise self.fail(f"{where} <{tag}>", f"interval end {hi} is below its start {lo}")
            return 0.5 * (lo + hi), True
        got = [c.tag for c in node]
        raise self.fail(where, f"<{tag}> must hold <exact> or <intervalStart>/<intervalEnd> (got {got})")

    def position(self, state: ET.Element, where: str) -> tuple[float, float, bool]:
        """(x, y, uncertain) of a state's ``<position>``: its ``<point>``, or the centre of the shape(s) the
        position is uncertain within (``<rectangle>`` / ``<circle>`` centre, ``<polygon>`` centroid; the mean
        centre of several shapes)."""
        pos = self.child(state, "position", where)
        w = f"{where} <position>"
        point = pos.find("point")
        if point is not None:
            return self.number(point, "x", w), self.number(point, "y", w), False
        centres = []
        for shape in pos:
            if shape.tag in ("rectangle", "circle"):
                c = self.child(shape, "center", f"{w} <{shape.tag}>")
                centres.append((self.number(c, "x", w), self.number(c, "y", w)))
            elif shape.tag == "polygon":
                ring = self.points(shape, f"{w} <polygon>")
                mid = shapely.Polygon(ring).centroid if len(ring) >= 3 else shapely.Point(ring.mean(axis=0))
                if mid.is_empty:  # a degenerate (zero-area) polygon: the mean of its vertices
                    mid = shapely.Point(ring.mean(axis=0))
                centres.append((mid.x, mid.y))
        if not centres:
            raise self.fail(w, f"needs a <point> or a <rectangle> / <circle> / <polygon> (got {[c.tag for c in pos]})")
        x, y = np.mean(np.array(centres, dtype=np.float64), axis=0)
        return float(x), float(y), True

    def points(self, elem: ET.Element, where: str) -> np.ndarray:
        pts = elem.findall("point")
        if len(pts) < 2:
            raise self.fail(where, f"needs at least 2 <point>s, got {len(pts)}")
        return np.array([[self.number(p, "x", where), self.number(p, "y", where)] for p in pts])


# ------------------------------------------------------------------------------------------------ road
def _speed_signs(root: ET.Element, rd: _Reader) -> dict[str, float]:
    """Traffic sign id -> maximum speed (m/s) for the max-speed signs of a 2020a file."""
    out = {}
    for sign in root.findall("trafficSign"):
        for el in sign.findall("trafficSignElement"):
            sid = (el.findtext("trafficSignID") or "").strip()
            value = el.find("additionalValue")
            if sid in SPEED_SIGNS and value is not None:
                where = f"trafficSign {sign.get('id')}"
                try:
                    out[str(sign.get("id"))] = float((value.text or "").strip())
                except ValueError:
                    raise rd.fail(where, f"<additionalValue> is not a number: {value.text!r}") from None
    return out


def _line_type(bound: ET.Element, adjacent: ET.Element | None) -> str:
    """Line type of a lanelet border: its marking, else inferred from the neighbour across it.

    Without a marking: ``striped`` towards a neighbour driven the same way, ``continuous`` towards oncoming
    traffic (a median), and ``none`` without a neighbour. An unmarked border without a neighbour is not a solid
    line: inside junctions lanelets overlap and cross without declared neighbours, and where such a border is the
    road's edge the drivable-area boundary already ends the road there.
    """
    marking = (bound.findtext("lineMarking") or "").strip()
    if marking in MARKINGS:
        return MARKINGS[marking]
    if adjacent is None:
        return "none"
    return "striped" if adjacent.get("drivingDir", "same") == "same" else "continuous"


def read_road(root: ET.Element, rd: _Reader) -> RoadDescription:
    """The lanelets of a CommonRoad document as a ``polylines`` `RoadDescription`."""
    lanelets = root.findall("lanelet")
    if not lanelets:
        raise rd.fail("lanelet", "the file has no <lanelet> elements; a scenario needs a road")
    signs = _speed_signs(root, rd)
    pieces: dict[str, list[LaneSpec]] = {}
    successors: dict[str, list[str]] = {}
    for ll in lanelets:
        lid = ll.get("id")
        where = f"lanelet {lid}"
        if not lid:
            raise rd.fail("lanelet", "a <lanelet> has no id attribute")
        if lid in pieces:
            raise rd.fail(where, "duplicate lanelet id")
        left_b, right_b = rd.child(ll, "leftBound", where), rd.child(ll, "rightBound", where)
        left = rd.points(left_b, f"{where} <leftBound>")
        right = rd.points(right_b, f"{where} <rightBound>")
        lines = (_line_type(left_b, ll.find("adjacentLeft")), _line_type(right_b, ll.find("adjacentRight")))
        speed = DEFAULT_SPEED_LIMIT_MPS
        if ll.find("speedLimit") is not None:
            speed = rd.number(ll, "speedLimit", where)
        limits = [signs[r.get("ref", "")] for r in ll.findall("trafficSignRef") if r.get("ref", "") in signs]
        if limits:
            speed = min(limits)
        if not speed > 0:
            raise rd.fail(where, f"speed limit must be positive, got {speed}")
        try:
            pieces[lid] = lane_pieces(lid, geometry_from_bounds(left, right), lines, speed)
        except ValueError as exc:
            raise rd.fail(where, str(exc)) from None
        successors[lid] = [s.get("ref", "") for s in ll.findall("successor")]
    lanes = link_successors(pieces, successors)
    if not lanes:
        raise rd.fail("lanelet", "every lanelet is shorter than 1 m; a scenario needs a road")
    return RoadDescription(layout="polylines", lanes=tuple(lanes), params={})


# ------------------------------------------------------------------------------------------------ agents
@dataclass(frozen=True)
class _Obstacle:
    agent_id: int
    agent_type: str
    dynamic: bool
    length_m: float
    width_m: float
    center_offset: tuple[float, float]
    steps: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray | None
    lateral_speed: np.ndarray | None
    uncertain_states: int


def _shape(obs: ET.Element, rd: _Reader, where: str) -> tuple[float, float, tuple[float, float]]:
    """(length, width, centre offset in the obstacle frame) in metres."""
    shape = rd.child(obs, "shape", where)
    kinds = [c.tag for c in shape]
    if len(kinds) != 1:
        raise rd.fail(f"{where} <shape>", f"needs exactly one rectangle or circle, got {kinds or 'nothing'}")
    el = shape[0]
    w = f"{where} <shape>"
    offset = (0.0, 0.0)
    c = el.find("center")
    if c is not None:
        offset = (rd.number(c, "x", w), rd.number(c, "y", w))
    if el.tag == "rectangle":
        length, width = rd.number(el, "length", w), rd.number(el, "width", w)
        if el.find("orientation") is not None and abs(rd.number(el, "orientation", w)) > 1e-6:
            raise rd.fail(w, "rotated rectangles (an <orientation> other than 0) are not supported")
    elif el.tag == "circle":
        length = width = 2.0 * rd.number(el, "radius", w)
    else:
        raise rd.fail(w, f"unsupported shape <{el.tag}>; dynamic obstacles need a <rectangle> (or <circle>)")
    if not (length > 0 and width > 0):
        raise rd.fail(w, f"size must be positive, got length {length}, width {width}")
    return length, width, offset


_State = tuple[int, float, float, float, float | None, float | None, bool]


def _state(state: ET.Element, rd: _Reader, where: str) -> _State:
    """(time step, x, y, orientation, velocity or None, lateral velocity or None, uncertain) of one state;
    ``uncertain``: some value was an interval or a shape and was read as its midpoint / centre."""
    step = rd.exact(state, "time", where)
    if step != int(step):
        raise rd.fail(where, f"<time> must be an integer time step, got {step}")
    x, y, unsure = rd.position(state, where)
    heading, u_h = rd.value(state, "orientation", where)
    v = vy = None
    u_v = u_vy = False
    if state.find("velocity") is not None:
        v, u_v = rd.value(state, "velocity", where)
    if state.find("velocityY") is not None:
        vy, u_vy = rd.value(state, "velocityY", where)
    return int(step), x, y, heading, v, vy, unsure or u_h or u_v or u_vy


def _read_obstacle(obs: ET.Element, rd: _Reader, dynamic: bool) -> _Obstacle:
    where = f"{obs.tag} {obs.get('id')}"
    try:
        agent_id = int(obs.get("id", ""))
    except ValueError:
        raise rd.fail(where, f"id must be an integer, got {obs.get('id')!r}") from None
    kind = (obs.findtext("type") or "unknown").strip()
    length, width, offset = _shape(obs, rd, where)
    states = [_state(rd.child(obs, "initialState", where), rd, f"{where} <initialState>")]
    if dynamic:
        traj = obs.find("trajectory")
        if traj is not None:
            for k, st in enumerate(traj.findall("state")):
                states.append(_state(st, rd, f"{where} <trajectory> state {k}"))
    steps = np.array([s[0] for s in states], dtype=np.int64)
    d = np.diff(steps)
    if (d <= 0).any():
        k = int(np.flatnonzero(d <= 0)[0])
        raise rd.fail(where, f"time steps must increase, got {steps[k]} then {steps[k + 1]}")
    if (d > 1).any():
        k = int(np.flatnonzero(d > 1)[0])
        raise rd.fail(
            where,
            f"the trajectory has a gap: time steps {steps[k] + 1}..{steps[k + 1] - 1} are missing "
            "(a CommonRoad trajectory needs one state per time step)",
        )
    speeds = [s[4] for s in states]
    lateral = [s[5] for s in states]
    return _Obstacle(
        agent_id=agent_id,
        agent_type=AGENT_TYPE.get(kind, "other"),
        dynamic=dynamic,
        length_m=length,
        width_m=width,
        center_offset=offset,
        steps=steps,
        x=np.array([s[1] for s in states]),
        y=np.array([s[2] for s in states]),
        heading=np.array([s[3] for s in states]),
        speed=None if any(v is None for v in speeds) else np.array(speeds, dtype=np.float64),
        lateral_speed=None if any(v is None for v in lateral) else np.array(lateral, dtype=np.float64),
        uncertain_states=sum(1 for s in states if s[6]),
    )


def _obstacles(root: ET.Element, version: str, rd: _Reader) -> list[_Obstacle]:
    out = []
    if version == "2018b":
        for obs in root.findall("obstacle"):
            role = (obs.findtext("role") or "").strip()
            if role not in ("static", "dynamic"):
                raise rd.fail(f"obstacle {obs.get('id')}", f"<role> must be static or dynamic, got {role!r}")
            out.append(_read_obstacle(obs, rd, dynamic=role == "dynamic"))
    else:
        out += [_read_obstacle(o, rd, dynamic=True) for o in root.findall("dynamicObstacle")]
        out += [_read_obstacle(o, rd, dynamic=False) for o in root.findall("staticObstacle")]
    ids = [o.agent_id for o in out]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise rd.fail("obstacles", f"duplicate obstacle ids {dup}")
    if not any(o.dynamic for o in out):
        raise rd.fail("dynamicObstacle", "the file has no dynamic obstacles; nothing to replay")
    return out


def _grid_track(o: _Obstacle, dt_s: float, n_steps: int) -> GridTrack | None:
    t = o.steps * dt_s
    c, s = np.cos(o.heading), np.sin(o.heading)
    # Positions are of the state's reference point; the box centre sits at the shape's centre offset from it.
    x = o.x + c * o.center_offset[0] - s * o.center_offset[1]
    y = o.y + s * o.center_offset[0] + c * o.center_offset[1]
    if not o.dynamic:
        return GridTrack(0, np.tile([x[0], y[0], o.heading[0], 0.0, 0.0, o.length_m, o.width_m, 1.0], (n_steps, 1)))
    v = o.speed if o.speed is not None else speeds_from_positions(t, x, y)
    vl = o.lateral_speed if o.lateral_speed is not None else np.zeros_like(v)
    vx, vy = v * c - vl * s, v * s + vl * c
    return resample_states(t, x, y, o.heading, vx, vy, o.length_m, o.width_m)


# ------------------------------------------------------------------------------------------------ entry
def read_commonroad(path: str | Path) -> CommonRoadRecording:
    """Parse a CommonRoad XML file (module docstring); raises `ImportFormatError` on bad input."""
    path = Path(path)
    rd = _Reader(path)
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise rd.fail("", f"malformed XML ({exc})") from None
    if root.tag != "commonRoad":
        raise rd.fail(f"<{root.tag}>", "the root element must be <commonRoad>; not a CommonRoad scenario")
    version = root.get("commonRoadVersion")
    if version not in SUPPORTED_VERSIONS:
        raise rd.fail(
            "commonRoad commonRoadVersion",
            f"unsupported CommonRoad version {version!r}; supported: {', '.join(SUPPORTED_VERSIONS)}",
        )
    try:
        dt_s = float(root.get("timeStepSize", ""))
    except ValueError:
        raise rd.fail("commonRoad timeStepSize", f"must be a number, got {root.get('timeStepSize')!r}") from None
    if not (math.isfinite(dt_s) and dt_s > 0):
        raise rd.fail("commonRoad timeStepSize", f"must be positive, got {dt_s}")
    road = read_road(root, rd)
    obstacles = _obstacles(root, version, rd)
    n_steps = max(grid_step(float(o.steps[-1]) * dt_s) + 1 for o in obstacles)
    grid: list[GridTrack] = []
    keep: list[_Obstacle] = []
    for o in obstacles:
        g = _grid_track(o, dt_s, n_steps)
        if g is not None:  # a dynamic obstacle logged between two 0.1 s grid points only
            grid.append(g)
            keep.append(o)
    tracks = stack_tracks(grid)
    if tracks.shape[1] < n_steps:
        tracks = np.concatenate([tracks, np.zeros((len(keep), n_steps - tracks.shape[1], len(TRACK_FIELDS)))], 1)
    log = AgentLog(
        tracks=tracks,
        agent_ids=np.array([o.agent_id for o in keep], dtype=np.int64),
        agent_types=tuple(o.agent_type for o in keep),
        source_ids=tuple(str(o.agent_id) for o in keep),
    )
    tag_el = root.find("scenarioTags")  # 2020a: child elements; 2018b: a "tags" attribute
    tags = tuple(t.tag for t in tag_el) if tag_el is not None else tuple((root.get("tags") or "").split())
    benchmark = root.get("benchmarkID") or path.stem
    road = RoadDescription(
        layout="polylines", lanes=road.lanes,
        params={"source": "commonroad", "benchmark_id": benchmark, "version": version},
    )
    uncertain = sum(o.uncertain_states for o in keep)
    dropped = {"obstacles_between_grid_points": len(obstacles) - len(keep)}
    return CommonRoadRecording(path, version, benchmark, dt_s, road, log, tags, uncertain, dropped)


HIGHWAY_TAGS = ("highway", "interstate")
URBAN_TAGS = ("urban", "intersection")


def recording_layout(benchmark_id: str) -> str:
    """The location of a CommonRoad benchmark ID (``COUNTRY_SCENE-CONFIG_PREDICTION``): ``USA_US101-26_1_T-1`` ->
    ``USA_US101``, ``USA_Lanker-1_1_T-1`` -> ``USA_Lanker``; so recordings of different roads keep apart."""
    return benchmark_id.split("-", 1)[0] or "commonroad"


def road_type(tags: tuple[str, ...]) -> str | None:
    """``highway`` or ``urban`` from a recording's scenario tags, None when they name neither."""
    if set(tags) & set(HIGHWAY_TAGS):
        return "highway"
    if set(tags) & set(URBAN_TAGS):
        return "urban"
    return None


def describe(rec: CommonRoadRecording) -> dict[str, object]:
    """Provenance of a recording for scenario metadata (JSON-serialisable); ``layout`` is the recording's location
    (`recording_layout`), ``source`` the format."""
    return {
        "layout": recording_layout(rec.benchmark_id),
        "source": "commonroad",
        "road_type": road_type(rec.tags),
        "source_file": rec.path.name,
        "benchmark_id": rec.benchmark_id,
        "commonroad_version": rec.version,
        "time_step_s": rec.time_step_s,
        "resampled": abs(rec.time_step_s - DT_S) > 1e-9,
        "tags": list(rec.tags),
    }
