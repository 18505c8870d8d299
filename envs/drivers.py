"""Randomised IDM + MOBIL drivers for base-scenario traffic.

Three kinds (`DRIVER_KINDS`):

* ``normal``: textbook IDM / MOBIL parameters with per-driver spread.
* ``aggressive``: short time gap, small jam distance, high desired speed (above the limit), low politeness,
  eager lane changes that accept hard braking of the new follower, ignores most yield decisions.
* ``inattentive``: normal parameters plus distraction episodes (every ~4-8 s, 1-3 s long) during which the
  driver keeps acting on the leader as seen at the onset (position extrapolated at the old speed), makes no
  lane-change decisions and does not notice that it has to yield; some lane changes overlook the blind spot.

`Driver` is a highway-env `IDMVehicle` whose decisions use the precomputed lane geometry and neighbour
search of `seal.envs.traffic.TrafficRoad` (``road.index`` / ``road.neighbours``) instead of highway-env's loops
over all lanes and vehicles; the kinematics are highway-env's bicycle model, reimplemented with scalar maths.
Units: m, s, m/s, m/s^2, rad.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from highway_env.road.road import LaneIndex, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle

from seal.core.scenario import DT_S
from seal.envs.network_index import NetworkIndex

DRIVER_KINDS = ("normal", "inattentive", "aggressive")

# highway-env's steering-controller gains, read once (class attribute lookups cost more than the arithmetic).
TAU_PURSUIT_S = IDMVehicle.TAU_PURSUIT
KP_LATERAL_PER_S = IDMVehicle.KP_LATERAL
KP_HEADING_PER_S = IDMVehicle.KP_HEADING
MAX_STEERING_RAD = IDMVehicle.MAX_STEERING_ANGLE


@dataclass(frozen=True, slots=True)
class DriverProfile:
    """Per-driver behaviour parameters.

    Attributes:
        kind: one of `DRIVER_KINDS`.
        speed_factor: desired speed / lane speed limit.
        time_gap: IDM desired time gap T (s).
        min_gap: IDM jam distance s0, bumper to bumper (m).
        acc: IDM maximum acceleration a (m/s^2).
        dec: IDM comfortable deceleration b (m/s^2).
        max_brake: physical braking limit (m/s^2).
        delta: IDM acceleration exponent.
        politeness: MOBIL politeness p.
        lc_gain: MOBIL incentive threshold (m/s^2).
        lc_max_brake: MOBIL safety limit: largest braking imposed on the new follower (m/s^2).
        lc_delay: seconds between lane-change decisions.
        yield_prob: probability to comply with a yield decision of the road rules.
        distraction_rate: distraction episodes per second (0 = never distracted).
        distraction_s: (min, max) episode duration (s).
        blind_spot_prob: probability that a lane-change decision overlooks the vehicle coming up behind in
            the target lane (no MOBIL safety check).
    """

    kind: str = "normal"
    speed_factor: float = 1.0
    time_gap: float = 1.5
    min_gap: float = 2.5
    acc: float = 1.5
    dec: float = 2.5
    max_brake: float = 7.0
    delta: float = 4.0
    politeness: float = 0.3
    lc_gain: float = 0.2
    lc_max_brake: float = 2.0
    lc_delay: float = 1.0
    yield_prob: float = 1.0
    distraction_rate: float = 0.0
    distraction_s: tuple[float, float] = (1.0, 3.0)
    blind_spot_prob: float = 0.0


def sample_profile(kind: str, rng: np.random.Generator) -> DriverProfile:
    """A random profile of ``kind`` (see the module docstring)."""
    u = rng.uniform
    if kind == "aggressive":
        return DriverProfile(
            kind=kind,
            speed_factor=u(1.1, 1.35),
            time_gap=u(0.4, 0.8),
            min_gap=u(1.0, 2.0),
            acc=u(2.5, 4.0),
            dec=u(3.5, 5.0),
            max_brake=u(6.0, 8.0),
            delta=u(3.5, 4.5),
            politeness=u(0.0, 0.1),
            lc_gain=u(0.0, 0.1),
            lc_max_brake=u(4.0, 6.0),
            lc_delay=u(0.4, 0.8),
            yield_prob=u(0.1, 0.5),
        )
    if kind not in ("normal", "inattentive"):
        raise ValueError(f"unknown driver kind {kind!r}; choose from {DRIVER_KINDS}")
    return DriverProfile(
        kind=kind,
        speed_factor=u(0.85, 1.05),
        time_gap=u(1.1, 2.0),
        min_gap=u(2.0, 4.0),
        acc=u(1.2, 2.2),
        dec=u(1.8, 3.0),
        max_brake=u(6.0, 8.0),
        delta=u(3.5, 4.5),
        politeness=u(0.2, 0.6),
        lc_gain=u(0.1, 0.3),
        lc_max_brake=u(1.5, 2.5),
        lc_delay=u(0.8, 1.5),
        yield_prob=1.0,
        distraction_rate=u(1 / 8, 1 / 4) if kind == "inattentive" else 0.0,
        distraction_s=(1.0, 3.0),
        blind_spot_prob=u(0.05, 0.15) if kind == "inattentive" else 0.0,
    )


def _not_zero(x: float, eps: float = 1e-2) -> float:
    if abs(x) > eps:
        return x
    return eps if x >= 0 else -eps


class TrafficRoad(Protocol):
    """What a `Driver` asks of its road (`seal.envs.traffic.TrafficRoad` provides it; a protocol here keeps the
    driver below the road in the import graph)."""

    network: RoadNetwork
    index: NetworkIndex

    def on_edge(self, edge: tuple[str, str]) -> list[Driver]:
        """The drivers on road ``edge`` (from node, to node)."""
        ...

    def neighbours(self, vehicle: Driver, lane_index: LaneIndex) -> tuple[Driver | None, float, Driver | None, float]:
        """(front, its distance ahead, rear, minus its distance behind) of ``vehicle`` along ``lane_index``."""
        ...


class Driver(IDMVehicle):
    """An IDM + MOBIL vehicle with a `DriverProfile`, driving on a `TrafficRoad`."""

    road: TrafficRoad
    # highway-env's vehicle state, declared for the type checker (highway-env sets them in its untyped code).
    timer: float
    """Seconds since the vehicle was created (s)."""
    action: dict[str, float]
    """The last ``steering`` (rad) and ``acceleration`` (m/s^2) command."""
    speed: float
    """m/s."""
    heading: float
    """rad."""
    impact: np.ndarray | None
    """Displacement (m) of a collision to apply at the next step."""
    target_lane_index: LaneIndex
    """The lane it is heading for (its own or the one of a lane change)."""
    lane_index: LaneIndex
    """The lane it is on (the closest, `seal.envs.network_index.NetworkIndex.closest_lane`)."""
    crashed: bool
    """It has hit another vehicle (it then brakes to a stop and decides nothing more)."""

    def __init__(
        self,
        road: TrafficRoad,
        position: Any,
        heading: float,
        speed: float,
        profile: DriverProfile,
        rng: np.random.Generator,
        vehicle_id: int,
        length: float = 5.0,
        width: float = 2.0,
        route: list[LaneIndex] | None = None,
    ) -> None:
        super().__init__(road, position, heading=heading, speed=speed, route=route)
        self.LENGTH, self.WIDTH = float(length), float(width)
        self.diagonal = math.hypot(self.LENGTH, self.WIDTH)
        self.p = profile
        self.rng = rng
        self.vehicle_id = vehicle_id
        self.xy: list[float] = self.position.tolist()  # position cached by the road for the decision step
        self.LANE_CHANGE_DELAY = profile.lc_delay
        self.yield_distance: float | None = None  # m to a conflict the road rules make us stop for
        self.wait_s = 0.0  # how long we have been standing while yielding
        self.crash_step: int | None = None
        self.route_edges: frozenset[tuple[str, str]] | None = None  # roads of the route (None: any road)
        self.route_path: list[tuple[str, str]] = []
        self.goal: str | None = None
        # Set when this lane does not continue where the route goes (e.g. an acceleration lane).
        self.exit_requested = False
        # Distraction state: remaining seconds, and the leader as perceived at the onset.
        self.distracted_s = 0.0
        # (centre gap at onset, leader speed along our heading, leader length, own travel since, time since)
        self._stale: tuple[float, float, float, float, float] | None = None

    # ----------------------------------------------------------------------------------- kinematics
    def step(self, dt: float) -> None:
        """highway-env's kinematic bicycle step (`Vehicle.step`): `move`, then the lane lookup (`TrafficRoad.step`
        moves all vehicles first and looks their lanes up in one compiled call)."""
        self.move(dt)
        road = self.road
        if road:
            x, y = self.position.tolist()
            self.lane_index = idx = road.index.closest_lane(x, y, self.heading, self.lane_index)
            self.lane = road.index.hw_lanes[idx]

    def move(self, dt: float) -> None:
        """highway-env's kinematic bicycle step with scalar maths, without the lane lookup.

        The position is read and written as Python floats (numpy scalar arithmetic is several times slower); the
        operations are those of highway-env's array update, so the bits are the same.
        """
        self.timer += dt
        # highway-env's `Vehicle.clip_actions`, inlined (its dict round trips cost more than the step).
        action = self.action
        if self.crashed:
            action["steering"] = 0
            action["acceleration"] = -1.0 * self.speed
        action["steering"] = steering = float(action["steering"])
        acc = float(action["acceleration"])
        if self.speed > self.MAX_SPEED:
            acc = min(acc, 1.0 * (self.MAX_SPEED - self.speed))
        elif self.speed < self.MIN_SPEED:
            acc = max(acc, 1.0 * (self.MIN_SPEED - self.speed))
        action["acceleration"] = acc
        beta = math.atan(0.5 * math.tan(steering))
        v, h = self.speed, self.heading
        pos = self.position
        x, y = pos.tolist()
        x += v * math.cos(h + beta) * dt
        y += v * math.sin(h + beta) * dt
        if self.impact is not None:
            ix, iy = self.impact.tolist()
            x += ix
            y += iy
            self.crashed = True
            self.impact = None
        pos[0] = x
        pos[1] = y
        self.heading = h + v * math.sin(beta) / (self.LENGTH / 2) * dt
        self.speed = max(0.0, v + acc * dt)  # IDM drivers never reverse
        if self.yield_distance is not None:
            self.yield_distance = max(0.0, self.yield_distance - v * dt)
            self.wait_s = self.wait_s + dt if v < 0.5 else 0.0
        else:
            self.wait_s = 0.0
        if self._stale is not None:
            g, vl, ll, travelled, elapsed = self._stale
            self._stale = (g, vl, ll, travelled + v * dt, elapsed + dt)

    def on_state_update(self) -> None:
        """Closest lane among the current road's lanes and the roads it leads to (not all lanes)."""
        if self.road:
            self.lane_index = self.road.index.closest_lane(
                self.position[0], self.position[1], self.heading, getattr(self, "lane_index", None)
            )
            self.lane = self.road.network.get_lane(self.lane_index)

    # ----------------------------------------------------------------------------------- decisions
    def act(self, action: dict | str | None = None) -> None:
        """Decide (`decide`), then steer towards the target lane. The steering reads only the vehicle's pose, speed
        and target lane, which nothing after the lane-change decision changes, so steering last gives the command
        of highway-env's order (steering, then acceleration)."""
        if self.crashed:
            return
        self.decide()
        self.action["steering"] = self._steering(self.target_lane_index)

    def decide(self) -> None:
        """`act` less the steering command: the lane decisions and the acceleration (``action["steering"]`` is
        left to the caller; `seal.envs.traffic.TrafficRoad.act` computes every vehicle's at once, compiled)."""
        if self.crashed:
            return
        self._follow_road()
        self._update_distraction()
        if not self.distracted_s:
            self._lane_change_policy()
        acc = self._longitudinal(self.lane_index)
        if self.lane_index != self.target_lane_index:
            acc = min(acc, self._longitudinal(self.target_lane_index))
        if self.yield_distance is not None and not self.distracted_s:
            # Yield: brake as for a standing obstacle where the predicted conflict starts.
            acc = min(
                acc,
                self.idm(self.speed, self.desired_speed(self.lane_index), self.yield_distance, self.speed),
            )
        acc = max(-self.p.max_brake, min(self.p.acc * 2.0, acc))
        self.action = {"steering": 0.0, "acceleration": acc}

    # ----------------------------------------------------------------------------------- routes
    def set_route(self, start: LaneIndex, destination: str | None) -> None:
        """Plan the shortest road sequence from lane ``start`` to node ``destination`` (None: this road)."""
        self.goal = destination
        edges = [start[:2]]
        if destination is not None and destination != start[1]:
            path = self.road.network.shortest_path(start[1], destination)
            edges += list(zip(path[:-1], path[1:], strict=True))
        self.route_path = edges
        self.route_edges = frozenset(edges)
        self.route = [start] + [(a, b, None) for a, b in edges[1:]]  # highway-env's route format

    def leads(self, lane_index: LaneIndex) -> bool:
        """Whether ``lane_index`` continues into the next road of the route (True when that is unknown)."""
        path = self.route_path
        edge = lane_index[:2]
        if edge not in path:
            return True
        k = path.index(edge)
        if k + 1 >= len(path):
            return True
        return any(x[:2] == path[k + 1] for x in self.road.index.succ[lane_index])

    def _follow_road(self) -> None:
        """At the end of the target lane, continue into its successor on the route (highway-env picks the
        closest lane of the next road, which lets vehicles cut across lanes, e.g. leave a roundabout from the
        inner lane). A vehicle that missed its road keeps going and plans again; a lane without successors
        (an acceleration lane) ends in the closest lane of the next road."""
        target = self.target_lane_index
        index = self.road.index
        lane = index.lanes[target]
        s, _ = lane.local(*self.xy)
        if s > lane.length - 2.5:
            succ = index.succ[target]
            if succ:
                nxt = next((x for x in succ if self.route_edges is None or x[:2] in self.route_edges), None)
                if nxt is None:
                    nxt = succ[0]
                    self.set_route(nxt, self.goal)
                self.target_lane_index = nxt
            else:
                self.target_lane_index = self.road.network.next_lane(target, position=self.position)
        # Mandatory lane change: this lane does not continue where the route goes, a neighbour does.
        self.exit_requested = not self.leads(self.lane_index) and any(
            self.leads(x) for x in index.side_lanes(self.lane_index)
        )

    def _update_distraction(self) -> None:
        if self.distracted_s > 0:
            self.distracted_s = max(0.0, self.distracted_s - DT_S)
            if not self.distracted_s:
                self._stale = None
            return
        rate = self.p.distraction_rate
        if rate > 0 and self.rng.random() < rate * DT_S:
            lo, hi = self.p.distraction_s
            self.distracted_s = float(self.rng.uniform(lo, hi))
            front, rel, _, _ = self.road.neighbours(self, self.lane_index)
            if front is not None:
                self._stale = (
                    rel,
                    front.speed * math.cos(front.heading - self.heading),
                    front.LENGTH,
                    0.0,
                    0.0,
                )
            else:
                self._stale = (math.inf, 0.0, 0.0, 0.0, 0.0)

    def _steering(self, target: LaneIndex) -> float:
        """highway-env `ControlledVehicle.steering_control` with scalar maths (on the floats of ``xy``, fixed
        while vehicles decide)."""
        lane = self.road.index.lanes[target]
        s, r = lane.local(*self.xy)
        v = self.speed
        nz = _not_zero(v)
        lane_heading = lane.heading_at(s + v * TAU_PURSUIT_S)
        heading_cmd = math.asin(max(-1.0, min(1.0, -KP_LATERAL_PER_S * r / nz)))
        heading_ref = lane_heading + max(-math.pi / 4, min(math.pi / 4, heading_cmd))
        rate_cmd = KP_HEADING_PER_S * ((heading_ref - self.heading + math.pi) % (2 * math.pi) - math.pi)
        slip = math.asin(max(-1.0, min(1.0, self.LENGTH / 2 / nz * rate_cmd)))
        steer = math.atan(2 * math.tan(slip))
        return max(-MAX_STEERING_RAD, min(MAX_STEERING_RAD, steer))

    def desired_speed(self, lane_index: LaneIndex) -> float:
        return self.p.speed_factor * self.road.index.lanes[lane_index].speed_limit

    def idm(self, speed: float, v0: float, gap: float, closing: float) -> float:
        """IDM acceleration for bumper gap ``gap`` (m, inf = free road) closing at ``closing`` m/s."""
        p = self.p
        acc = p.acc * (1.0 - (max(speed, 0.0) / max(v0, 0.1)) ** p.delta)
        if gap < math.inf:
            s_star = p.min_gap + max(
                0.0, speed * p.time_gap + speed * closing / (2 * math.sqrt(p.acc * p.dec))
            )
            acc -= p.acc * (s_star / max(gap, 0.1)) ** 2
        return acc

    def _longitudinal(self, lane_index: LaneIndex) -> float:
        v0 = self.desired_speed(lane_index)
        if self._stale is not None:
            # Stale perception: the leader seen at the onset, assumed to have kept its speed since.
            gap0, v_lead, lead_len, travelled, elapsed = self._stale
            if gap0 == math.inf:
                return self.idm(self.speed, v0, math.inf, 0.0)
            gap = gap0 + v_lead * elapsed - travelled - (self.LENGTH + lead_len) / 2
            return self.idm(self.speed, v0, gap, self.speed - v_lead)
        front, rel, _, _ = self.road.neighbours(self, lane_index)
        acc = self._follower_acc(self, front, rel)
        lane = self.road.index.lanes[lane_index]
        if lane.forbidden and not self.road.index.succ[lane_index]:
            # An acceleration lane that ends: its end is a standing obstacle until the driver has merged.
            s = lane.local(*self.xy)[0]
            acc = min(
                acc,
                self.idm(
                    self.speed, self.desired_speed(lane_index), lane.length - s - self.LENGTH / 2, self.speed
                ),
            )
        return acc

    def _follower_acc(self, follower: Driver | None, leader: Driver | None, gap_centre: float) -> float:
        """Acceleration ``follower`` would choose behind ``leader`` at centre distance ``gap_centre``."""
        if follower is None:
            return 0.0
        v0 = follower.desired_speed(follower.lane_index)
        if leader is None:
            return follower.idm(follower.speed, v0, math.inf, 0.0)
        gap = gap_centre - (follower.LENGTH + leader.LENGTH) / 2
        closing = follower.speed - leader.speed * math.cos(leader.heading - follower.heading)
        return follower.idm(follower.speed, v0, gap, closing)

    def _lane_change_policy(self) -> None:
        """highway-env `IDMVehicle.change_lane_policy` (abort / periodic MOBIL) on the bucketed neighbours."""
        if self.lane_index != self.target_lane_index:
            if self.lane_index[:2] == self.target_lane_index[:2]:
                for v in self.road.on_edge(self.lane_index[:2]):
                    if (
                        v is not self
                        and v.lane_index != self.target_lane_index
                        and getattr(v, "target_lane_index", None) == self.target_lane_index
                    ):
                        lane = self.road.index.lanes[self.lane_index]
                        d = lane.local(*v.xy)[0] - lane.local(*self.xy)[0]
                        d_star = self.p.min_gap + self.LENGTH + self.speed * self.p.time_gap
                        if 0 < d < d_star:
                            self.target_lane_index = self.lane_index
                            break
            return
        if self.timer <= self.LANE_CHANGE_DELAY:
            return
        self.timer = 0.0
        if self.speed < 1.0 and not self.exit_requested:
            return
        leads_now = self.leads(self.lane_index)
        for lane_index in self.road.index.side_lanes(self.lane_index):
            lane = self.road.index.lanes[lane_index]
            if lane.forbidden or ((self.exit_requested or leads_now) and not self.leads(lane_index)):
                continue
            s, r = lane.local(*self.xy)
            if not (abs(r) <= 2 * lane.width and 0 <= s < lane.length + 5.0):
                continue
            if self._mobil(lane_index):
                self.target_lane_index = lane_index

    def _mobil(self, lane_index: LaneIndex) -> bool:
        """MOBIL: safety for the new follower, then incentive with politeness (gaps are centre distances)."""
        p = self.p
        new_front, nf_rel, new_rear, nr_rel = self.road.neighbours(self, lane_index)
        if p.blind_spot_prob and self.rng.random() < p.blind_spot_prob:
            new_rear, nr_rel = None, -math.inf  # overlooked
        new_rear_pred = self._follower_acc(new_rear, self, -nr_rel)
        if new_rear is not None and new_rear_pred < -p.lc_max_brake:
            return False
        self_pred = self._follower_acc(self, new_front, nf_rel)
        if self.exit_requested:
            # The current lane ends: change as soon as it is safe for both.
            return self_pred >= -p.lc_max_brake
        old_front, of_rel, old_rear, or_rel = self.road.neighbours(self, self.lane_index)
        self_now = self._follower_acc(self, old_front, of_rel)
        new_rear_now = self._follower_acc(new_rear, new_front, nf_rel - nr_rel)
        old_rear_now = self._follower_acc(old_rear, self, -or_rel)
        old_rear_pred = self._follower_acc(old_rear, old_front, of_rel - or_rel)
        gain = (
            self_pred
            - self_now
            + p.politeness * (new_rear_pred - new_rear_now + old_rear_pred - old_rear_now)
        )
        return gain >= p.lc_gain
