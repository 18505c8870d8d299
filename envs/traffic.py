"""Traffic simulation on a highway-env road: spawning, IDM + MOBIL drivers, road rules, 10 Hz logging.

`simulate` runs one randomised simulation on one layout and returns a `RunLog` of every vehicle at 10 Hz. It
drives highway-env's `Road.act()` / `Road.step(dt)` loop itself (no gym env) with a `TrafficRoad` that keeps
highway-env's physics and NPC-NPC collision handling (crashed vehicles brake to a stop) but replaces the slow
parts: lane lookups and neighbour searches use precomputed lane geometry (`NetworkIndex`) and vehicles
bucketed per road, and collision pairs are prefiltered with numpy before highway-env's polygon test.

Vehicles enter at the road starts / intersection and roundabout entries (Poisson arrivals, only when the
entry is clear), the network starts populated, and vehicles are removed when they reach the end of an exit
road or 8 s after a crash. At intersections and roundabouts lanes carry priorities and, every 0.3 s, one
vehicle of each predicted conflict (boxes overlapping within 3 s at constant speed, after highway-env's
`RegulatedRoad`; see `TrafficRoad.enforce_road_rules`) is told to yield; aggressive and distracted drivers
sometimes do not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from highway_env.road.lane import AbstractLane, CircularLane, SineLane, StraightLane
from highway_env.road.road import LaneIndex, Road, RoadNetwork

from envs.drivers import DRIVER_KINDS, Driver, sample_profile
from envs.layouts import lane_indices, make_network, predecessor_map, successor_map
from seal.geometry import box_corners, boxes_overlap
from seal.scenario import DT_S

AHEAD_M = 80.0
"""Leaders are searched along the lane and its successors up to this distance (m)."""
BEHIND_M = 40.0
"""Followers are searched along the lane and its predecessors up to this distance (m)."""
CRASH_REMOVE_STEPS = 80
"""Crashed vehicles stay (stopped) for 8 s, long enough for a window to show the crash and its aftermath."""
GO_SPEED = 3.0
"""Speed (m/s) at which the road rules assume a waiting vehicle would drive off."""
REGULATION_EVERY = 3
"""Road rules are re-evaluated every 3 steps (highway-env's RegulatedRoad: 2 Hz; faster reacts in time)."""
CONFLICT_MARGIN_S = 1.0
MAX_WAIT_S = 4.0
"""Two vehicles conflict when they would occupy the same place less than this many seconds apart."""


# ------------------------------------------------------------------------------------------ lane geometry
def _copy_lane_attributes(fast: FastStraight | FastCircle, lane: AbstractLane) -> None:
    """The attributes every fast lane copies from its highway-env lane, as plain Python scalars."""
    fast.length = float(lane.length)
    fast.width = float(lane.width)
    fast.speed_limit = float(lane.speed_limit)
    fast.priority = int(lane.priority)
    fast.forbidden = bool(lane.forbidden)


class FastStraight:
    """Scalar-maths twin of a highway-env `StraightLane` (same local coordinates, heading and positions)."""

    __slots__ = ("sx", "sy", "dx", "dy", "length", "width", "heading", "speed_limit", "priority", "forbidden")

    def __init__(self, lane: StraightLane) -> None:
        self.sx, self.sy = (float(v) for v in lane.start)
        self.dx, self.dy = (float(v) for v in lane.direction)
        self.heading = float(lane.heading)
        _copy_lane_attributes(self, lane)

    def local(self, x: float, y: float) -> tuple[float, float]:
        ex, ey = x - self.sx, y - self.sy
        return ex * self.dx + ey * self.dy, ey * self.dx - ex * self.dy

    def heading_at(self, s: float) -> float:
        return self.heading

    def position(self, s: float, r: float) -> tuple[float, float]:
        return self.sx + s * self.dx - r * self.dy, self.sy + s * self.dy + r * self.dx


class FastSine(FastStraight):
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


class FastCircle:
    __slots__ = (
        "cx",
        "cy",
        "radius",
        "start",
        "dir",
        "length",
        "width",
        "speed_limit",
        "priority",
        "forbidden",
    )

    def __init__(self, lane: CircularLane) -> None:
        self.cx, self.cy = (float(v) for v in lane.center)
        self.radius = float(lane.radius)
        self.start = float(lane.start_phase)
        self.dir = float(lane.direction)
        _copy_lane_attributes(self, lane)

    def local(self, x: float, y: float) -> tuple[float, float]:
        ex, ey = x - self.cx, y - self.cy
        phi = math.atan2(ey, ex)
        phi = self.start + ((phi - self.start + math.pi) % (2 * math.pi) - math.pi)
        return self.dir * (phi - self.start) * self.radius, self.dir * (self.radius - math.hypot(ex, ey))

    def heading_at(self, s: float) -> float:
        return self.dir * s / self.radius + self.start + math.pi / 2 * self.dir

    def position(self, s: float, r: float) -> tuple[float, float]:
        phi = self.dir * s / self.radius + self.start
        rad = self.radius - r * self.dir
        return self.cx + rad * math.cos(phi), self.cy + rad * math.sin(phi)


FastLane = FastStraight | FastCircle


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
    angle = abs((heading - lane.heading_at(s) + math.pi) % (2 * math.pi) - math.pi)
    return abs(r) + max(s - lane.length, 0.0) + max(-s, 0.0) + angle


class NetworkIndex:
    """Precomputed topology and scalar lane geometry of a `RoadNetwork`."""

    def __init__(self, network: RoadNetwork) -> None:
        self.network = network
        self.indices = lane_indices(network)
        self.lanes: dict[LaneIndex, FastLane] = {i: fast_lane(network.get_lane(i)) for i in self.indices}
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
            return min(self.all, key=lambda c: _lane_distance(c[1], x, y, heading))[0]
        best, best_d = current, math.inf
        for idx, lane in self.siblings[current]:
            d = _lane_distance(lane, x, y, heading)
            if d < best_d:
                best, best_d = idx, d
        lane = self.lanes[current]
        if lane.local(x, y)[0] > lane.length - 6.0:
            for idx, nxt in self.next_lanes[current]:
                d = _lane_distance(nxt, x, y, heading)
                if d < best_d:
                    best, best_d = idx, d
        if best_d > 4.0:  # pushed off its roads (e.g. by a crash): search everything
            return self.closest_lane(x, y, heading, None)
        return best


def _separation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Largest gap (m) between the projections of rectangles ``[..., 4, 2]`` on their edge normals: a lower
    bound of their distance (<= 0 when they overlap)."""
    axes = np.concatenate([a[..., 1:3, :] - a[..., 0:2, :], b[..., 1:3, :] - b[..., 0:2, :]], axis=-2)
    axes = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
    pa = np.einsum("...kd,...cd->...kc", axes, a)
    pb = np.einsum("...kd,...cd->...kc", axes, b)
    return np.maximum(pb.min(-1) - pa.max(-1), pa.min(-1) - pb.max(-1)).max(-1)


# ------------------------------------------------------------------------------------------ road
class TrafficRoad(Road):
    """A highway-env `Road` with bucketed neighbour search, prefiltered collisions and optional road rules."""

    def __init__(
        self, network: RoadNetwork, index: NetworkIndex, rng: np.random.Generator, regulated: bool
    ) -> None:
        super().__init__(network=network, np_random=rng)
        self.index = index
        self.rng = rng
        self.regulated = regulated
        self.steps = 0
        self.collisions: list[tuple[int, int, int]] = []  # (step, vehicle id, vehicle id), first contact only
        self._collided: set[tuple[int, int]] = set()
        self._buckets: dict[str, list[Driver]] = {}
        self.junction_nodes: frozenset[str] = frozenset()  # lanes leaving these nodes are inside a junction

    # ------------------------------------------------------------------- neighbours
    def rebuild_buckets(self) -> None:
        """Vehicles per start node of their lane: lanes leaving one node overlap near it, so a vehicle on a
        branch the searcher does not take is still tested against the searcher's lanes."""
        buckets: dict[str, list[Driver]] = {}
        for v in self.vehicles:
            buckets.setdefault(v.lane_index[0], []).append(v)
            v.xy = v.position.tolist()  # positions are fixed while vehicles decide
        self._buckets = buckets
        self._occupants: dict[LaneIndex, list[tuple[float, Driver]]] = {}

    def occupants(self, lane_index: LaneIndex) -> list[tuple[float, Driver]]:
        """(longitudinal position, vehicle) of the vehicles on a lane (highway-env's ``on_lane``, 1 m margin),
        computed once per decision step."""
        occ = self._occupants.get(lane_index)
        if occ is None:
            lane = self.index.lanes[lane_index]
            half, end = lane.width / 2 + 1.0, lane.length + 5.0
            occ = []
            for v in self._buckets.get(lane_index[0], ()):
                sv, rv = lane.local(*v.xy)
                if abs(rv) <= half and -5.0 <= sv < end:
                    occ.append((sv, v))
            self._occupants[lane_index] = occ
        return occ

    def on_edge(self, edge: tuple[str, str]) -> list[Driver]:
        return [v for v in self._buckets.get(edge[0], ()) if v.lane_index[1] == edge[1]]

    def neighbours(
        self, vehicle: Driver, lane_index: LaneIndex
    ) -> tuple[Driver | None, float, Driver | None, float]:
        """(front, its centre distance ahead, rear, minus its centre distance behind) of ``vehicle`` along the
        lane ``lane_index``, its successors on the vehicle's route (up to `AHEAD_M`) and predecessors."""
        s = self.index.lanes[lane_index].local(*vehicle.xy)[0]
        route_edges = vehicle.route_edges
        front = rear = None
        s_front, s_rear = math.inf, -math.inf
        seen: set[int] = {vehicle.vehicle_id}
        for chain, forward in ((self.index.ahead[lane_index], True), (self.index.behind[lane_index], False)):
            for k, (li, off, _) in enumerate(chain):
                if k == 0 and not forward:
                    continue  # the lane itself was searched with the forward chain
                if forward and k and route_edges is not None and li[:2] not in route_edges:
                    continue
                for sv, v in self.occupants(li):
                    if v.vehicle_id in seen:
                        continue
                    seen.add(v.vehicle_id)
                    sv += off
                    if sv >= s:
                        if sv < s_front:
                            front, s_front = v, sv
                    elif sv > s_rear:
                        rear, s_rear = v, sv
        return front, s_front - s, rear, s_rear - s

    # ------------------------------------------------------------------- act / step
    def act(self) -> None:
        self.rebuild_buckets()
        if self.regulated and self.steps % REGULATION_EVERY == 0:
            self.enforce_road_rules()
        for vehicle in self.vehicles:
            vehicle.act()

    def step(self, dt: float) -> None:
        """Step all vehicles, then highway-env's collision handling on the pairs that can touch."""
        for vehicle in self.vehicles:
            vehicle.step(dt)
        vs = self.vehicles
        if len(vs) > 1:
            state = np.array([(*v.position, v.heading, v.LENGTH, v.WIDTH, v.speed) for v in vs])
            reach = np.hypot(state[:, 3], state[:, 4]) / 2 + np.abs(state[:, 5]) * dt
            d = np.linalg.norm(state[:, None, :2] - state[None, :, :2], axis=-1)
            # Superset of highway-env's own spherical pre-check, so the outcome is unchanged ...
            ii, jj = np.nonzero(np.triu(d <= reach[:, None] + reach[None] + 0.5, 1))
            if ii.size:
                # ... and of its polygon test: boxes separated by more than their relative displacement in a
                # step can neither intersect nor "will intersect".
                corners = box_corners(state[:, 0], state[:, 1], state[:, 2], state[:, 3], state[:, 4])
                vel = state[:, 5:6] * np.stack([np.cos(state[:, 2]), np.sin(state[:, 2])], axis=1)
                rel = np.linalg.norm(vel[ii] - vel[jj], axis=1) * dt
                touch = _separation(corners[ii], corners[jj]) <= rel + 0.1
                for i, j in zip(ii[touch], jj[touch], strict=True):
                    self._collide(vs[int(i)], vs[int(j)], dt)
        self.steps += 1

    def _collide(self, a: Driver, b: Driver, dt: float) -> None:
        """highway-env `RoadObject.handle_collisions` for two solid vehicles, recording who hit whom."""
        intersecting, will_intersect, transition = a._is_colliding(b, dt)
        if will_intersect:
            a.impact = transition / 2
            b.impact = -transition / 2
        if intersecting:
            a.crashed = b.crashed = True
        if intersecting or will_intersect:
            key = (min(a.vehicle_id, b.vehicle_id), max(a.vehicle_id, b.vehicle_id))
            if key not in self._collided:
                self._collided.add(key)
                self.collisions.append((self.steps + 1, key[0], key[1]))
            for v in (a, b):
                if v.crash_step is None:
                    v.crash_step = self.steps + 1

    # ------------------------------------------------------------------- road rules
    def _predict(self, v: Driver, times: np.ndarray, speed: float) -> tuple[np.ndarray, np.ndarray]:
        """Positions [K, 2] and headings [K] along the vehicle's route lanes at constant ``speed``."""
        lane_idx = v.lane_index
        lane = self.index.lanes[lane_idx]
        s0 = lane.local(*v.position.tolist())[0]
        pos = np.empty((len(times), 2))
        head = np.empty(len(times))
        offset = 0.0
        for k, t in enumerate(times):
            s = s0 + speed * float(t) - offset
            while s > lane.length:
                nxt = self._next_on_route(v, lane_idx)
                if nxt is None:
                    break
                s -= lane.length
                offset += lane.length
                lane_idx, lane = nxt, self.index.lanes[nxt]
            pos[k] = lane.position(s, 0.0)
            head[k] = lane.heading_at(s)
        return pos, head

    @staticmethod
    def _predict_wreck(v: Driver, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A crashed vehicle slides straight on, braking with a = -speed (highway-env): x = v (1 - e^-t)."""
        travel = v.speed * (1.0 - np.exp(-times))
        pos = v.position[None] + travel[:, None] * v.direction[None]
        return pos, np.full(len(times), v.heading)

    def _next_on_route(self, v: Driver, lane_idx: LaneIndex) -> LaneIndex | None:
        succ = self.index.succ[lane_idx]
        if not succ:
            return None
        if v.route_edges is not None:
            for nxt in succ:
                if nxt[:2] in v.route_edges:
                    return nxt
        return succ[0]

    def _entry_distance(self, v: Driver) -> float | None:
        """Distance (m) from the front bumper to where the vehicle's route enters the junction.

        None when it is inside or its route never enters.
        """
        lane_idx = v.lane_index
        if lane_idx[0] in self.junction_nodes:
            return None
        lane = self.index.lanes[lane_idx]
        d = lane.length - lane.local(*v.position.tolist())[0]
        for _ in range(4):
            if lane_idx[1] in self.junction_nodes:
                return d - v.LENGTH / 2
            nxt = self._next_on_route(v, lane_idx)
            if nxt is None:
                return None
            lane_idx, lane = nxt, self.index.lanes[nxt]
            d += lane.length
        return None

    def _may_conflict(self, a: Driver, b: Driver) -> bool:
        if a is b or (a.crashed and b.crashed):
            return False
        la, lb = a.lane_index, b.lane_index
        # Car following on one lane or consecutive lanes is IDM's business.
        return not (la == lb or lb in self.index.succ[la] or la in self.index.succ[lb])

    def enforce_road_rules(self) -> None:
        """Road rules after highway-env's `RegulatedRoad`.

        Predict 3 s at constant speed along the routes. When two vehicles would occupy the same place (boxes
        enlarged as in highway-env) less than `CONFLICT_MARGIN_S` apart, one yields: the moving one if the
        other stands, else the one outside the junction if the other is inside, else the one on the
        lower-priority lane, else the one behind. Whoever can no longer stop before the conflict keeps going
        and the other one yields. A yielding driver brakes (IDM) for a standing obstacle at the junction
        entry, or where the conflict starts when it is too late for that.

        Slow vehicles are predicted twice, standing and driving off at `GO_SPEED`, so that they only start
        into a big enough gap and others stop for them while they stand. Wrecks stand still and never yield.
        Of two standing vehicles waiting for each other, the one that has waited longest (over `MAX_WAIT_S`)
        goes.
        """
        for v in self.vehicles:
            v.yield_distance = None
        if len(self.vehicles) < 2:
            return
        rows: list[tuple[Driver, float, bool]] = []  # (vehicle, predicted speed, inside the junction)
        for v in self.vehicles:
            inside = v.lane_index[0] in self.junction_nodes
            if v.crashed:
                rows.append((v, 0.0, inside))
                continue
            rows.append((v, max(v.speed, GO_SPEED), inside))
            if v.speed < GO_SPEED:
                rows.append((v, v.speed, inside))
        times = np.arange(0.25, 3.0, 0.25)
        preds = [
            self._predict_wreck(v, times) if v.crashed else self._predict(v, times, sp) for v, sp, _ in rows
        ]
        pos = np.stack([p for p, _ in preds])  # [n, K, 2]
        head = np.stack([h for _, h in preds])
        lengths = np.array([v.LENGTH for v, _, _ in rows])
        widths = np.array([v.WIDTH for v, _, _ in rows])
        n_k = pos.shape[1]
        # Time shifts allowed between the two passages (in prediction samples).
        shift = int(round(CONFLICT_MARGIN_S / (times[1] - times[0])))
        window = np.abs(np.arange(n_k)[:, None] - np.arange(n_k)[None]) <= shift  # [K, K]
        # Cheap prefilter: bounding circles of the predicted paths.
        centre = pos.mean(axis=1)
        radius = np.linalg.norm(pos - centre[:, None], axis=-1).max(axis=1) + 0.75 * np.hypot(lengths, widths)
        cd = np.linalg.norm(centre[:, None] - centre[None], axis=-1)
        ii, jj = np.nonzero(np.triu(cd < radius[:, None] + radius[None], 1))
        keep = [
            k
            for k, (i, j) in enumerate(zip(ii, jj, strict=True))
            if self._may_conflict(rows[i][0], rows[j][0])
        ]
        if not keep:
            return
        ii, jj = ii[keep], jj[keep]
        d2 = ((pos[ii][:, :, None] - pos[jj][:, None]) ** 2).sum(-1)  # [P, K, K]
        reach = (lengths[ii] + lengths[jj]) * 0.75 + 1.0
        close = (d2 < (reach**2)[:, None, None]) & window
        corners = box_corners(pos[..., 0], pos[..., 1], head, 1.5 * lengths[:, None], 0.9 * widths[:, None])
        entry: dict[int, float | None] = {}
        for p in np.flatnonzero(close.any(axis=(1, 2))):
            i, j = int(ii[p]), int(jj[p])
            (a, sa, ina), (b, sb, inb) = rows[i], rows[j]
            ka, kb = np.nonzero(close[p])
            overlap = boxes_overlap(corners[i][ka], corners[j][kb])
            if not overlap.any():
                continue
            ka, kb = ka[overlap], kb[overlap]
            la, lb = a.lane_index, b.lane_index
            static_a, static_b = sa < 0.5 or a.crashed, sb < 0.5 or b.crashed
            if static_a and static_b:
                continue
            if static_a or static_b:
                n = (
                    1 if static_a else 0
                )  # a standing vehicle (or wreck) is an obstacle: the moving one yields
            elif ina != inb:
                n = 1 if ina else 0
            else:
                pa, pb = self.index.lanes[la].priority, self.index.lanes[lb].priority
                if pa != pb:
                    n = 0 if pa < pb else 1
                else:  # the vehicle behind yields
                    n = (
                        0
                        if a.direction.dot(b.position - a.position) > b.direction.dot(a.position - b.position)
                        else 1
                    )
            pair = (a, b)
            # Each one's distance to where it first enters the conflict.
            t_a, t_b = float(times[ka.min()]), float(times[kb.min()])
            dist = (sa * t_a - 0.75 * a.LENGTH, sb * t_b - 0.75 * b.LENGTH)
            # A standing vehicle can always stay where it is.
            can_stop = [
                not v.crashed and (v.speed < 0.5 or dist[m] >= v.speed**2 / (2 * v.p.max_brake))
                for m, v in enumerate(pair)
            ]
            if not (static_a or static_b) and not can_stop[n] and can_stop[1 - n]:
                n = 1 - n  # (if neither can stop any more, the one without right of way brakes hard)
            y, other = pair[n], pair[1 - n]
            if y.crashed:
                continue
            if not (static_a or static_b) and y.p.yield_prob < 1.0 and self.rng.random() >= y.p.yield_prob:
                continue  # an aggressive driver takes the right of way (but never drives into a standing car)
            if (
                y.wait_s > MAX_WAIT_S
                and other.speed < 0.5
                and not other.crashed
                and (y.wait_s, -y.vehicle_id) > (other.wait_s, -other.vehicle_id)
            ):
                continue  # two standing vehicles waiting for each other: the one waiting longest goes
            stop = dist[n]
            if y.vehicle_id not in entry:
                entry[y.vehicle_id] = self._entry_distance(y)
            line = entry[y.vehicle_id]
            if line is not None and 0.0 <= line <= stop + 1e-9 and line >= y.speed**2 / (2 * y.p.dec):
                stop = line - 1.0  # wait at the junction entry rather than inside it
            if y.yield_distance is None or stop < y.yield_distance:
                y.yield_distance = max(0.0, stop)


# ------------------------------------------------------------------------------------------ traffic plans
@dataclass(frozen=True)
class Source:
    """Vehicles enter at the start of ``lane`` at ``rate`` vehicles/s, heading to one of ``destinations``."""

    lane: LaneIndex
    rate: float
    destinations: tuple[str, ...]
    weights: tuple[float, ...] | None = None


@dataclass
class TrafficPlan:
    sources: list[Source]
    populate: list[tuple[LaneIndex, tuple[str, ...]]]  # lanes filled at t = 0, with their destinations
    sinks: tuple[tuple[str, str], ...]  # roads whose end is where vehicles leave the network
    regulated: bool
    trucks: float  # share of long vehicles
    spacing_s: float  # mean initial time headway per lane (s)
    junction_nodes: tuple[str, ...] = ()  # lanes leaving these nodes are inside the junction / on the ring


def traffic_plan(layout: str, params: dict, network: RoadNetwork, rng: np.random.Generator) -> TrafficPlan:
    """Sources, initially populated lanes and density of one run (rates in vehicles/s per entry lane)."""
    if layout == "highway":
        rate = rng.uniform(0.35, 0.7)
        lanes = int(params["lanes"])
        return TrafficPlan(
            sources=[Source(("a", "b", i), rate * rng.uniform(0.8, 1.2), ("d",)) for i in range(lanes)],
            populate=[(i, ("d",)) for i in lane_indices(network)],
            sinks=(("c", "d"),),
            regulated=False,
            trucks=0.08,
            spacing_s=1.0 / rate,
        )
    if layout == "merge":
        rate = rng.uniform(0.35, 0.7)
        lanes = int(params["lanes"])
        srcs = [Source(("a", "b", i), rate * rng.uniform(0.8, 1.2), ("d",)) for i in range(lanes)]
        srcs.append(Source(("j", "k", 0), rng.uniform(0.25, 0.5), ("d",)))
        return TrafficPlan(
            sources=srcs,
            populate=[(i, ("d",)) for i in lane_indices(network)],
            sinks=(("c", "d"),),
            regulated=False,
            trucks=0.08,
            spacing_s=1.0 / rate,
        )
    if layout == "intersection":
        rate = rng.uniform(0.2, 0.4)
        srcs, pop = [], []
        for k in range(4):
            # Destinations: right, straight, left (corner k-1, k+2, k+1).
            dests = (f"o{(k - 1) % 4}", f"o{(k + 2) % 4}", f"o{(k + 1) % 4}")
            srcs.append(Source((f"o{k}", f"ir{k}", 0), rate * rng.uniform(0.7, 1.3), dests, (0.3, 0.4, 0.3)))
            pop.append(((f"o{k}", f"ir{k}", 0), dests))
            pop.append(((f"il{k}", f"o{k}", 0), ()))
        sinks = tuple((f"il{k}", f"o{k}") for k in range(4))
        return TrafficPlan(
            sources=srcs,
            populate=pop,
            sinks=sinks,
            regulated=True,
            trucks=0.0,
            spacing_s=1.0 / rate,
            junction_nodes=tuple(f"ir{k}" for k in range(4)),
        )
    # roundabout
    rate = rng.uniform(0.3, 0.5)
    exits = ("sxr", "exr", "nxr", "wxr")
    srcs, pop = [], []
    for d in "senw":
        dests = tuple(e for e in exits if not e.startswith(d))
        srcs.append(Source((f"{d}er", f"{d}es", 0), rate * rng.uniform(0.7, 1.3), dests))
        pop.append(((f"{d}er", f"{d}es", 0), dests))
        pop.append(((f"{d}xs", f"{d}xr", 0), ()))
    for i in lane_indices(network):
        if len(i[0]) == 2 and len(i[1]) == 2:  # ring lanes (nodes "se", "ex", ...)
            pop.append((i, exits))
    sinks = tuple((f"{d}xs", f"{d}xr") for d in "senw")
    return TrafficPlan(
        sources=srcs,
        populate=pop,
        sinks=sinks,
        regulated=True,
        trucks=0.0,
        spacing_s=1.0 / rate,
        junction_nodes=("se", "ex", "ee", "nx", "ne", "wx", "we", "sx"),
    )


# ------------------------------------------------------------------------------------------ simulation
@dataclass
class RunLog:
    """Every vehicle of one run at 10 Hz.

    Attributes:
        states: ``[N, T, 6]`` float64: x, y (m), heading (rad, wrapped), speed (m/s), length, width (m);
            NaN where the vehicle does not exist.
        valid: ``[N, T]`` bool; each row is one contiguous block (vehicles enter once and leave once).
        kinds: driver kind per vehicle (`DRIVER_KINDS`).
        collisions: ``(step, id_a, id_b)`` of each first contact between two vehicles (ids = row indices).
    """

    states: np.ndarray
    valid: np.ndarray
    kinds: list[str]
    collisions: list[tuple[int, int, int]] = field(default_factory=list)


class Simulation:
    """One traffic run on one layout (see the module docstring)."""

    def __init__(
        self, layout: str, params: dict, rng: np.random.Generator, kind_shares: Sequence[float]
    ) -> None:
        self.layout = layout
        self.rng = rng
        self.network = make_network(layout, params)
        self.index = NetworkIndex(self.network)
        self.plan = traffic_plan(layout, params, self.network, rng)
        self.road = TrafficRoad(self.network, self.index, rng, self.plan.regulated)
        self.road.junction_nodes = frozenset(self.plan.junction_nodes)
        self.kind_p = np.asarray(kind_shares, dtype=np.float64)
        self.kinds: list[str] = []
        self.rows: list[list[tuple[float, ...]]] = []
        self.first_step: list[int] = []
        self.next_arrival = [float(rng.exponential(1.0 / s.rate)) for s in self.plan.sources]

    # ------------------------------------------------------------------- spawning
    def _new_vehicle(
        self,
        lane_idx: LaneIndex,
        s: float,
        speed: float,
        destinations: tuple[str, ...],
        weights: tuple[float, ...] | None = None,
    ) -> Driver:
        rng = self.rng
        lane = self.network.get_lane(lane_idx)
        kind = DRIVER_KINDS[int(rng.choice(len(DRIVER_KINDS), p=self.kind_p))]
        profile = sample_profile(kind, rng)
        if rng.random() < self.plan.trucks:
            length, width = rng.uniform(6.5, 10.0), rng.uniform(2.2, 2.5)
        else:
            length, width = rng.uniform(4.2, 5.2), rng.uniform(1.75, 2.05)
        vid = len(self.kinds)
        v = Driver(
            self.road, lane.position(s, 0.0), lane.heading_at(s), speed, profile, rng, vid, length, width
        )
        v.lane_index = v.target_lane_index = lane_idx
        v.lane = lane
        dest: str | None = None
        if destinations:
            p = None if weights is None else np.asarray(weights) / np.sum(weights)
            reachable = [
                d for d in destinations if self.network.shortest_path(lane_idx[1], d) or d == lane_idx[1]
            ]
            if reachable:
                if p is not None:
                    p = np.array([p[destinations.index(d)] for d in reachable])
                    p = p / p.sum()
                dest = reachable[int(rng.choice(len(reachable), p=p))]
        v.set_route(lane_idx, dest)
        self.kinds.append(kind)
        self.rows.append([])
        self.first_step.append(self.road.steps)
        self.road.vehicles.append(v)
        return v

    def _clearance(self, lane_idx: LaneIndex, s: float) -> tuple[float, float]:
        """(gap to the nearest vehicle ahead, its speed) around ``s`` on the lane and what follows it."""
        best, speed = math.inf, math.inf
        for li, off, lane in self.index.ahead[lane_idx]:
            for v in self.road.vehicles:
                if v.lane_index[:2] != li[:2]:
                    continue
                sv, rv = lane.local(*v.position.tolist())
                if abs(rv) > lane.width / 2 + 1.0:
                    continue
                gap = sv + off - s
                if -10.0 < gap < best:
                    best, speed = gap, v.speed
        return best, speed

    def populate(self) -> None:
        """Fill the populated lanes with vehicles at random headways around the plan's spacing."""
        placed: list[tuple[float, float]] = []
        for lane_idx, dests in self.plan.populate:
            lane = self.index.lanes[lane_idx]
            limit = lane.speed_limit
            s = self.rng.uniform(0.0, 20.0)
            # Keep the first seconds free of conflicts the road rules have had no time to sort out.
            end = lane.length - (25.0 if lane_idx[1] in self.plan.junction_nodes else 5.0)
            while s < end:
                speed = limit * self.rng.uniform(0.75, 0.95)
                x, y = lane.position(s, 0.0)
                if all((x - px) ** 2 + (y - py) ** 2 > 12.0**2 for px, py in placed):
                    self._new_vehicle(lane_idx, s, speed, dests)
                    placed.append((x, y))
                s += max(12.0, speed * self.plan.spacing_s * self.rng.uniform(0.4, 1.6) / 1.5)

    def spawn(self) -> None:
        t = self.road.steps * DT_S
        for k, src in enumerate(self.plan.sources):
            if t < self.next_arrival[k]:
                continue
            lane = self.index.lanes[src.lane]
            speed = lane.speed_limit * self.rng.uniform(0.75, 0.95)
            gap, lead_speed = self._clearance(src.lane, 0.0)
            if gap < 12.0 + 0.8 * speed:
                if gap < 12.0:
                    continue  # entry blocked: retry next step
                speed = min(speed, lead_speed + 1.0)
            self._new_vehicle(src.lane, 0.0, speed, src.destinations, src.weights)
            self.next_arrival[k] = t + float(self.rng.exponential(1.0 / src.rate))

    def remove(self) -> None:
        keep = []
        for v in self.road.vehicles:
            lane = self.index.lanes[v.lane_index]
            s, r = lane.local(*v.position.tolist())
            # Leave before `Driver._follow_road` would look for a road beyond the exit (2.5 m before its end).
            gone = v.lane_index[:2] in self.plan.sinks and s > lane.length - 3.0
            off_road = abs(r) > 3 * lane.width
            wreck = v.crash_step is not None and self.road.steps - v.crash_step >= CRASH_REMOVE_STEPS
            if not (gone or off_road or wreck):
                keep.append(v)
        self.road.vehicles = keep

    # ------------------------------------------------------------------- loop
    def log(self) -> None:
        for v in self.road.vehicles:
            x, y = v.position.tolist()
            h = (v.heading + math.pi) % (2 * math.pi) - math.pi
            self.rows[v.vehicle_id].append((x, y, h, max(v.speed, 0.0), v.LENGTH, v.WIDTH))

    def run(self, n_steps: int) -> RunLog:
        self.populate()
        self.log()
        for _ in range(n_steps - 1):
            self.road.act()
            self.road.step(DT_S)
            self.remove()
            self.spawn()
            self.log()
        n = len(self.kinds)
        states = np.full((n, n_steps, 6), np.nan)
        valid = np.zeros((n, n_steps), dtype=bool)
        for i, rows in enumerate(self.rows):
            if rows:
                t0 = self.first_step[i]
                states[i, t0 : t0 + len(rows)] = rows
                valid[i, t0 : t0 + len(rows)] = True
        return RunLog(
            states=states, valid=valid, kinds=list(self.kinds), collisions=list(self.road.collisions)
        )

