"""Traffic simulation on a highway-env road: spawning, IDM + MOBIL drivers, road rules, 10 Hz logging.

`seal.envs.traffic_run.Simulation` runs one randomised simulation on one layout and returns a `RunLog` of every
vehicle at 10 Hz. It drives highway-env's `Road.act()` / `Road.step(dt)` loop itself (no gym env) with a `TrafficRoad`
that keeps highway-env's physics and NPC-NPC collision handling (crashed vehicles brake to a stop) but replaces the
slow parts: lane lookups and neighbour searches use precomputed lane geometry (`NetworkIndex`) and vehicles bucketed
per road, and collision pairs are prefiltered with numpy before highway-env's polygon test.

Vehicles enter at the road starts / intersection and roundabout entries (Poisson arrivals, only when the
entry is clear), the network starts populated, and vehicles are removed when they reach the end of an exit
road or 8 s after a crash. At intersections and roundabouts lanes carry priorities and, every 0.3 s, one
vehicle of each predicted conflict (boxes overlapping within 3 s at constant speed, after highway-env's
`RegulatedRoad`; see `TrafficRoad.enforce_road_rules`) is told to yield; aggressive and distracted drivers
sometimes do not.
"""


from __future__ import annotations

import math

import numpy as np
from highway_env.road.road import LaneIndex, Road, RoadNetwork

from seal.core.geometry import box_corners
from seal.envs.drivers import KP_HEADING_PER_S, KP_LATERAL_PER_S, MAX_STEERING_RAD, TAU_PURSUIT_S, Driver
from seal.envs.lane_kernels import closest_lanes, steering_commands
from seal.envs.network_index import NetworkIndex
from seal.envs.traffic_kernels import contact_pairs, first_overlaps

CRASH_REMOVE_STEPS = 80
"""Crashed vehicles stay (stopped) for 8 s, long enough for a window to show the crash and its aftermath."""
GO_SPEED = 3.0
"""Speed (m/s) at which the road rules assume a waiting vehicle would drive off."""
REGULATION_EVERY = 3
"""Road rules are re-evaluated every 3 steps (highway-env's RegulatedRoad: 2 Hz; faster reacts in time)."""
CONFLICT_MARGIN_S = 1.0
MAX_WAIT_S = 4.0
"""Two vehicles conflict when they would occupy the same place less than this many seconds apart."""



_RuleRow = tuple[Driver, float, bool]
"""(vehicle, predicted speed in m/s, inside the junction) of one road-rule prediction."""


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
        index = self.index
        s = index.lanes[lane_index].local(*vehicle.xy)[0]
        route_edges = vehicle.route_edges
        front = rear = None
        s_front, s_rear = math.inf, -math.inf
        seen: set[int] = {vehicle.vehicle_id}
        cache = self._occupants
        for li, edge, off, on_route_only in index.search[lane_index]:
            if on_route_only and route_edges is not None and edge not in route_edges:
                continue
            occ = cache.get(li)
            if occ is None:
                occ = self.occupants(li)
            for sv, v in occ:
                vid = v.vehicle_id
                if vid in seen:
                    continue
                seen.add(vid)
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
        movers = [v for v in self.vehicles if not v.crashed]  # wrecks keep their last action
        for v in movers:
            v.decide()
        if movers:
            # Every mover's steering in one compiled call (`Driver._steering`, the same operations).
            index = self.index
            x, y, heading, speed, length = np.array(
                [(*v.xy, v.heading, v.speed, v.LENGTH) for v in movers]
            ).T.copy()
            target = np.array([index.row[v.target_lane_index] for v in movers], dtype=np.int64)
            steer = steering_commands(
                index.table, target, x, y, heading, speed, length, TAU_PURSUIT_S, KP_LATERAL_PER_S, KP_HEADING_PER_S,
                MAX_STEERING_RAD,
            )
            for v, sa in zip(movers, steer.tolist(), strict=True):
                v.action["steering"] = sa

    def step(self, dt: float) -> None:
        """Step all vehicles, then highway-env's collision handling on the pairs that can touch."""
        vs = self.vehicles
        for vehicle in vs:
            vehicle.move(dt)
        if not vs:
            self.steps += 1
            return
        state = np.array([(*v.position.tolist(), v.heading, v.LENGTH, v.WIDTH, v.speed) for v in vs])
        # Each vehicle's closest lane (`Driver.step`'s lookup depends on its own pose only, so all at once).
        index = self.index
        x, y, heading = np.ascontiguousarray(state[:, :3].T)
        rows = closest_lanes(
            index.table, index.sib_ptr, index.sib, index.nxt_ptr, index.nxt, x, y, heading,
            np.array([index.row[v.lane_index] for v in vs], dtype=np.int64),
        )
        for v, k in zip(vs, rows.tolist(), strict=True):
            v.lane_index = idx = index.indices[k]
            v.lane = index.hw_lanes[idx]
        if len(vs) > 1:
            # A superset of highway-env's spherical pre-check and of its polygon test (boxes separated by more
            # than their relative displacement in a step can neither intersect nor "will intersect"), so the
            # outcome is highway-env's; compiled (`contact_pairs`), it costs a few microseconds a step.
            ii, jj = contact_pairs(state, dt)
            for i, j in zip(ii.tolist(), jj.tolist(), strict=True):
                self._collide(vs[i], vs[j], dt)
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
        s0 = lane.local(*v.xy)[0]
        pos: list[tuple[float, float]] = []
        head: list[float] = []
        offset = 0.0
        for t in times.tolist():  # Python floats and lists: the loop runs ~10^5 times a run
            s = s0 + speed * t - offset
            while s > lane.length:
                nxt = self._next_on_route(v, lane_idx)
                if nxt is None:
                    break
                s -= lane.length
                offset += lane.length
                lane_idx, lane = nxt, self.index.lanes[nxt]
            pos.append(lane.position(s, 0.0))
            head.append(lane.heading_at(s))
        return np.array(pos), np.array(head)

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
        rows = self._rule_rows()
        times = np.arange(0.25, 3.0, 0.25)
        found = self._close_pairs(rows, times)
        if found is None:
            return
        ii, jj, close, corners = found
        entry: dict[int, float | None] = {}
        # When each one first enters the conflict (-1: the boxes never overlap), one compiled pass over the pairs.
        first_a, first_b = first_overlaps(corners, ii, jj, close)
        for i, j, ka, kb in zip(ii.tolist(), jj.tolist(), first_a.tolist(), first_b.tolist(), strict=True):
            if ka >= 0:
                self._resolve(rows[i], rows[j], float(times[ka]), float(times[kb]), entry)

    def _rule_rows(self) -> list[_RuleRow]:
        """(vehicle, predicted speed, inside the junction) per prediction: wrecks standing, slow vehicles twice
        (standing and driving off at `GO_SPEED`), others at their speed (at least `GO_SPEED`)."""
        rows: list[_RuleRow] = []
        for v in self.vehicles:
            inside = v.lane_index[0] in self.junction_nodes
            if v.crashed:
                rows.append((v, 0.0, inside))
                continue
            rows.append((v, max(v.speed, GO_SPEED), inside))
            if v.speed < GO_SPEED:
                rows.append((v, v.speed, inside))
        return rows

    def _close_pairs(
        self, rows: list[_RuleRow], times: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Predicted paths of ``rows`` at ``times`` (s) and the pairs that may conflict: ``(ii [P], jj [P], close
        [P, K, K] (samples close enough in space and within `CONFLICT_MARGIN_S`), corners [n, K, 4, 2] of the
        enlarged boxes)``; None when no pair may."""
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
            return None
        ii, jj = ii[keep], jj[keep]
        d2 = ((pos[ii][:, :, None] - pos[jj][:, None]) ** 2).sum(-1)  # [P, K, K]
        reach = (lengths[ii] + lengths[jj]) * 0.75 + 1.0
        close = (d2 < (reach**2)[:, None, None]) & window
        corners = box_corners(pos[..., 0], pos[..., 1], head, 1.5 * lengths[:, None], 0.9 * widths[:, None])
        return ii, jj, close, corners

    @staticmethod
    def _right_of_way(a: Driver, ina: bool, b: Driver, inb: bool, static_a: bool, static_b: bool) -> int:
        """Which of ``(a, b)`` should yield (0 or 1): the moving one if the other stands, else the one outside the
        junction if the other is inside, else the one on the lower-priority lane, else the one behind."""
        if static_a or static_b:
            return 1 if static_a else 0  # a standing vehicle (or wreck) is an obstacle: the moving one yields
        if ina != inb:
            return 1 if ina else 0
        return -1

    def _resolve(
        self, row_a: _RuleRow, row_b: _RuleRow, t_a: float, t_b: float, entry: dict[int, float | None]
    ) -> None:
        """Make one of a conflicting pair yield (see `enforce_road_rules`); ``t_a``, ``t_b``: when each one first
        enters the conflict (s); ``entry``: junction-entry distances found so far, by vehicle id."""
        (a, sa, ina), (b, sb, inb) = row_a, row_b
        static_a, static_b = sa < 0.5 or a.crashed, sb < 0.5 or b.crashed
        if static_a and static_b:
            return
        n = self._right_of_way(a, ina, b, inb, static_a, static_b)
        if n < 0:
            pa, pb = self.index.lanes[a.lane_index].priority, self.index.lanes[b.lane_index].priority
            if pa != pb:
                n = 0 if pa < pb else 1
            else:  # the vehicle behind yields
                n = 0 if a.direction.dot(b.position - a.position) > b.direction.dot(a.position - b.position) else 1
        pair = (a, b)
        # Each one's distance to where it first enters the conflict.
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
            return
        if not (static_a or static_b) and y.p.yield_prob < 1.0 and self.rng.random() >= y.p.yield_prob:
            return  # an aggressive driver takes the right of way (but never drives into a standing car)
        if (
            y.wait_s > MAX_WAIT_S
            and other.speed < 0.5
            and not other.crashed
            and (y.wait_s, -y.vehicle_id) > (other.wait_s, -other.vehicle_id)
        ):
            return  # two standing vehicles waiting for each other: the one waiting longest goes
        self._yield_before(y, dist[n], entry)

    def _yield_before(self, y: Driver, stop: float, entry: dict[int, float | None]) -> None:
        """Have ``y`` stop ``stop`` m ahead, or at its junction entry when that comes first and it can still
        brake for it (``entry``: a cache of `_entry_distance` by vehicle id)."""
        if y.vehicle_id not in entry:
            entry[y.vehicle_id] = self._entry_distance(y)
        line = entry[y.vehicle_id]
        if line is not None and 0.0 <= line <= stop + 1e-9 and line >= y.speed**2 / (2 * y.p.dec):
            stop = line - 1.0  # wait at the junction entry rather than inside it
        if y.yield_distance is None or stop < y.yield_distance:
            y.yield_distance = max(0.0, stop)


# ------------------------------------------------------------------------------------------ traffic plans
