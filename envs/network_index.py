"""Precomputed lane geometry of a highway-env road network: fast lane projections and the lane search of traffic
drivers (closest lane, leaders ahead up to `AHEAD_M`, followers behind up to `BEHIND_M`, side lanes)."""

from __future__ import annotations

import math

import numpy as np
from highway_env.road.lane import AbstractLane, CircularLane, SineLane, StraightLane
from highway_env.road.road import LaneIndex, RoadNetwork

from seal.core.geometry import wrap_angle_f
from seal.envs import lane_kernels as lk
from seal.envs.network_topology import lane_indices, predecessor_map, successor_map

AHEAD_M = 80.0
"""Leaders are searched along the lane and its successors up to this distance (m)."""
BEHIND_M = 40.0
"""Followers are searched along the lane and its predecessors up to this distance (m)."""

# ------------------------------------------------------------------------------------------ lane geometry
class FastLane:
    """Base of the scalar-maths twins of highway-env lanes: the attributes every fast lane copies from its
    highway-env lane, as plain Python scalars, and the lane interface (local coordinates, heading, positions)."""

    __slots__ = ("length", "width", "speed_limit", "priority", "forbidden")
    length: float
    """Arc length (m)."""
    width: float
    """Lane width (m)."""
    speed_limit: float
    """m/s."""
    priority: int
    """Right-of-way priority (higher goes first)."""
    forbidden: bool
    """Lane changes onto it are forbidden."""

    def __init__(self, lane: AbstractLane) -> None:
        self.length = float(lane.length)
        self.width = float(lane.width)
        self.speed_limit = float(lane.speed_limit)
        self.priority = int(lane.priority)
        self.forbidden = bool(lane.forbidden)

    def local(self, x: float, y: float) -> tuple[float, float]:
        """(longitudinal s, lateral r) in m of the point (x, y)."""
        raise NotImplementedError

    def heading_at(self, s: float) -> float:
        """Lane heading (rad) at arc length ``s``."""
        raise NotImplementedError

    def position(self, s: float, r: float) -> tuple[float, float]:
        """World position (m) of local coordinates (s, r)."""
        raise NotImplementedError

    def distance(self, x: float, y: float, heading: float) -> float:
        """highway-env `AbstractLane.distance_with_heading` (m + rad) of the pose (x, y, heading)."""
        return _lane_distance(self, x, y, heading)


class FastStraight(FastLane):
    """Scalar-maths twin of a highway-env `StraightLane` (same local coordinates, heading and positions)."""

    __slots__ = ("sx", "sy", "dx", "dy", "heading")

    def __init__(self, lane: StraightLane) -> None:
        self.sx, self.sy = (float(v) for v in lane.start)
        self.dx, self.dy = (float(v) for v in lane.direction)
        self.heading = float(lane.heading)
        super().__init__(lane)

    def local(self, x: float, y: float) -> tuple[float, float]:
        ex, ey = x - self.sx, y - self.sy
        return ex * self.dx + ey * self.dy, ey * self.dx - ex * self.dy

    def heading_at(self, s: float) -> float:
        return self.heading

    def position(self, s: float, r: float) -> tuple[float, float]:
        return self.sx + s * self.dx - r * self.dy, self.sy + s * self.dy + r * self.dx

    def distance(self, x: float, y: float, heading: float) -> float:
        # `_lane_distance` inlined (the closest-lane search calls it for every vehicle and step): same
        # operations in the same order, so the same bits.
        ex, ey = x - self.sx, y - self.sy
        s = ex * self.dx + ey * self.dy
        r = ey * self.dx - ex * self.dy
        angle = abs((heading - self.heading + math.pi) % (2 * math.pi) - math.pi)
        return abs(r) + max(s - self.length, 0.0) + max(-s, 0.0) + angle


class FastSine(FastStraight):
    """Scalar-maths twin of a highway-env `SineLane`."""

    __slots__ = ("amp", "puls", "phase")

    def __init__(self, lane: SineLane) -> None:
        super().__init__(lane)
        self.amp, self.puls, self.phase = float(lane.amplitude), float(lane.pulsation), float(lane.phase)

    def local(self, x: float, y: float) -> tuple[float, float]:
        s, r = FastStraight.local(self, x, y)
        return s, r - self.amp * math.sin(self.puls * s + self.phase)

    def heading_at(self, s: float) -> float:
        return self.heading + math.atan(self.amp * self.puls * math.cos(self.puls * s + self.phase))

    def position(self, s: float, r: float) -> tuple[float, float]:
        return FastStraight.position(self, s, r + self.amp * math.sin(self.puls * s + self.phase))

    distance = FastLane.distance  # not the straight shortcut: the heading varies along a sine lane


class FastCircle(FastLane):
    """Scalar-maths twin of a highway-env `CircularLane`."""

    __slots__ = ("cx", "cy", "radius", "start", "dir")

    def __init__(self, lane: CircularLane) -> None:
        self.cx, self.cy = (float(v) for v in lane.center)
        self.radius = float(lane.radius)
        self.start = float(lane.start_phase)
        self.dir = float(lane.direction)
        super().__init__(lane)

    def local(self, x: float, y: float) -> tuple[float, float]:
        ex, ey = x - self.cx, y - self.cy
        phi = math.atan2(ey, ex)
        phi = self.start + wrap_angle_f(phi - self.start)
        return self.dir * (phi - self.start) * self.radius, self.dir * (self.radius - math.hypot(ex, ey))

    def heading_at(self, s: float) -> float:
        return self.dir * s / self.radius + self.start + math.pi / 2 * self.dir

    def position(self, s: float, r: float) -> tuple[float, float]:
        phi = self.dir * s / self.radius + self.start
        rad = self.radius - r * self.dir
        return self.cx + rad * math.cos(phi), self.cy + rad * math.sin(phi)


def fast_lane(lane: AbstractLane) -> FastLane:
    if isinstance(lane, SineLane):
        return FastSine(lane)
    if isinstance(lane, StraightLane):
        return FastStraight(lane)
    if isinstance(lane, CircularLane):
        return FastCircle(lane)
    raise TypeError(f"unsupported lane type {type(lane).__name__}")


def _lane_distance(lane: FastLane, x: float, y: float, heading: float) -> float:
    """highway-env `AbstractLane.distance_with_heading` (m + rad)."""
    s, r = lane.local(x, y)
    angle = abs(wrap_angle_f(heading - lane.heading_at(s)))
    return abs(r) + max(s - lane.length, 0.0) + max(-s, 0.0) + angle


def lane_table(lanes: list[FastLane]) -> np.ndarray:
    """``[L, N_COLUMNS]`` rows of `seal.envs.lane_kernels` for the lanes (their attributes, copied exactly)."""
    table = np.zeros((len(lanes), lk.N_COLUMNS))
    for k, lane in enumerate(lanes):
        row = table[k]
        row[lk.LENGTH] = lane.length
        if isinstance(lane, FastCircle):
            row[lk.KIND] = lk.CIRCLE
            row[[lk.CX, lk.CY, lk.RADIUS, lk.START, lk.DIR]] = lane.cx, lane.cy, lane.radius, lane.start, lane.dir
            continue
        assert isinstance(lane, FastStraight)
        row[lk.KIND] = lk.SINE if isinstance(lane, FastSine) else lk.STRAIGHT
        row[[lk.SX, lk.SY, lk.DX, lk.DY, lk.HEADING]] = lane.sx, lane.sy, lane.dx, lane.dy, lane.heading
        if isinstance(lane, FastSine):
            row[[lk.AMP, lk.PULS, lk.PHASE]] = lane.amp, lane.puls, lane.phase
    return table


def _csr(lists: list[list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """(pointers ``[len + 1]``, values) of a list of int lists."""
    ptr = np.zeros(len(lists) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(x) for x in lists])
    return ptr, np.array([v for x in lists for v in x], dtype=np.int64)


class NetworkIndex:
    """Precomputed topology and scalar lane geometry of a `RoadNetwork`."""

    def __init__(self, network: RoadNetwork) -> None:
        self.network = network
        self.indices = lane_indices(network)
        self.hw_lanes: dict[LaneIndex, AbstractLane] = {i: network.get_lane(i) for i in self.indices}
        """highway-env's lane objects (``network.get_lane`` without its per-call checks)."""
        self.lanes: dict[LaneIndex, FastLane] = {i: fast_lane(self.hw_lanes[i]) for i in self.indices}
        self.succ = successor_map(network)
        self.pred = predecessor_map(self.succ)
        self.edges: dict[tuple[str, str], list[LaneIndex]] = {}
        for i in self.indices:
            self.edges.setdefault(i[:2], []).append(i)
        # A vehicle moves at most one road per step: its lane leaves the same node as its current lane
        # (same road, or a branch that overlaps it near the node) or the node its current lane ends at.
        from_node: dict[str, list[tuple[LaneIndex, FastLane]]] = {}
        for i in self.indices:
            from_node.setdefault(i[0], []).append((i, self.lanes[i]))
        self.siblings = {i: from_node[i[0]] for i in self.indices}
        self.next_lanes = {i: from_node.get(i[1], []) for i in self.indices}
        self.all = [(j, self.lanes[j]) for j in self.indices]
        self.ahead = {i: self._chain(i, self.succ, AHEAD_M, forward=True) for i in self.indices}
        self.behind = {i: self._chain(i, self.pred, BEHIND_M, forward=False) for i in self.indices}
        self.row = {i: k for k, i in enumerate(self.indices)}
        """Row of each lane in `table` (and of `indices`)."""
        self.table = lane_table([self.lanes[i] for i in self.indices])
        """``[L, N_COLUMNS]`` the lanes for the compiled closest-lane lookup (`seal.envs.lane_kernels`)."""
        self.sib_ptr, self.sib = _csr([[self.row[j] for j, _ in self.siblings[i]] for i in self.indices])
        self.nxt_ptr, self.nxt = _csr([[self.row[j] for j, _ in self.next_lanes[i]] for i in self.indices])
        self.search: dict[LaneIndex, list[tuple[LaneIndex, tuple[str, str], float, bool]]] = {
            i: [(j, j[:2], off, k > 0) for k, (j, off, _) in enumerate(self.ahead[i])]
            + [(j, j[:2], off, False) for j, off, _ in self.behind[i][1:]]
            for i in self.indices
        }
        """The lanes a neighbour search from each lane visits, in order: ``(lane, its road, offset (m) of its
        origin along the searched lane, searched only when on the searcher's route)``: the lane itself, the lanes
        ahead (`ahead`, only those of the route), then the lanes behind (`behind`, without the lane itself)."""

    def _chain(
        self, start: LaneIndex, links: dict[LaneIndex, list[LaneIndex]], reach: float, forward: bool
    ) -> list[tuple[LaneIndex, float, FastLane]]:
        """Lanes reachable from ``start`` within ``reach`` m, with the offset (m) of their origin along it."""
        out = [(start, 0.0, self.lanes[start])]
        seen = {start}
        frontier = [(start, 0.0)]
        while frontier:
            lane, off = frontier.pop(0)
            for nxt in links[lane]:
                if nxt in seen:
                    continue
                # Reach is counted from the far end of the start lane (the vehicle may be anywhere on it).
                # Forward: the next lane starts at o. Backward: the previous lane ends where this one starts.
                o = off + self.lanes[lane].length if forward else off - self.lanes[nxt].length
                if (o - self.lanes[start].length if forward else -off) >= reach:
                    continue
                seen.add(nxt)
                out.append((nxt, o, self.lanes[nxt]))
                frontier.append((nxt, o))
        return out

    def side_lanes(self, index: LaneIndex) -> list[LaneIndex]:
        n = len(self.edges[index[:2]])
        return [(index[0], index[1], j) for j in (index[2] - 1, index[2] + 1) if 0 <= j < n]

    def closest_lane(self, x: float, y: float, heading: float, current: LaneIndex | None) -> LaneIndex:
        """highway-env's closest lane (position + heading distance), searched near ``current`` only: lanes
        leaving its start node, and lanes leaving its end node when the vehicle is near that end."""
        x, y = float(x), float(y)
        if current is None:
            return min(self.all, key=lambda c: c[1].distance(x, y, heading))[0]
        best, best_d = current, math.inf
        for idx, lane in self.siblings[current]:
            d = lane.distance(x, y, heading)
            if d < best_d:
                best, best_d = idx, d
        lane = self.lanes[current]
        if lane.local(x, y)[0] > lane.length - 6.0:
            for idx, nxt in self.next_lanes[current]:
                d = nxt.distance(x, y, heading)
                if d < best_d:
                    best, best_d = idx, d
        if best_d > 4.0:  # pushed off its roads (e.g. by a crash): search everything
            return self.closest_lane(x, y, heading, None)
        return best
