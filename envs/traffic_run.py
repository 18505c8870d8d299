"""One traffic run on one layout: traffic plans (sources, sinks, initial population) and the `Simulation` loop
that spawns, steps (`seal.envs.traffic.TrafficRoad`), removes and logs every vehicle at 10 Hz (`RunLog`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from highway_env.road.road import LaneIndex, RoadNetwork

from seal.core.geometry import wrap_angle_f
from seal.core.scenario import DT_S
from seal.envs.drivers import DRIVER_KINDS, Driver, sample_profile
from seal.envs.layouts import make_network
from seal.envs.network_index import NetworkIndex
from seal.envs.network_topology import lane_indices
from seal.envs.traffic import CRASH_REMOVE_STEPS, TrafficRoad


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
    if layout in ("highway", "merge"):
        rate = rng.uniform(0.35, 0.7)
        lanes = int(params["lanes"])
        srcs = [Source(("a", "b", i), rate * rng.uniform(0.8, 1.2), ("d",)) for i in range(lanes)]
        if layout == "merge":  # the on-ramp feeds in at its own rate
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
        srcs = []
        pop: list[tuple[LaneIndex, tuple[str, ...]]] = []
        for k in range(4):
            # Destinations: right, straight, left (corner k-1, k+2, k+1).
            dests: tuple[str, ...] = (f"o{(k - 1) % 4}", f"o{(k + 2) % 4}", f"o{(k + 1) % 4}")
            srcs.append(Source((f"o{k}", f"ir{k}", 0), rate * rng.uniform(0.7, 1.3), dests, (0.3, 0.4, 0.3)))
            pop.append(((f"o{k}", f"ir{k}", 0), dests))
            pop.append(((f"il{k}", f"o{k}", 0), ()))
        sinks = tuple((f"il{k}", f"o{k}") for k in range(4))
        return _junction_plan(srcs, pop, sinks, rate, tuple(f"ir{k}" for k in range(4)))
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
    return _junction_plan(srcs, pop, sinks, rate, ("se", "ex", "ee", "nx", "ne", "wx", "we", "sx"))


def _junction_plan(sources: list[Source], populate: list[tuple[LaneIndex, tuple[str, ...]]],
                   sinks: tuple[tuple[str, str], ...], rate: float, junction_nodes: tuple[str, ...]) -> TrafficPlan:
    """An intersection's or roundabout's plan: road rules on, no trucks, initial headway 1 / arrival rate."""
    return TrafficPlan(sources=sources, populate=populate, sinks=sinks, regulated=True, trucks=0.0,
                       spacing_s=1.0 / rate, junction_nodes=junction_nodes)


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
            h = wrap_angle_f(v.heading)
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


