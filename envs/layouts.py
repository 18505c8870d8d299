"""Road layouts for base-scenario generation: build highway-env road networks from JSON parameters.

Four layouts (`LAYOUTS`): a multi-lane ``highway`` (straight - arc - straight), an on-ramp ``merge``, a 4-way
``intersection`` and a ``roundabout``. `sample_params` draws randomised parameters, `make_network` rebuilds
the exact network from them (`seal.envs.network_topology.describe_network` turns any highway-env network into a
`seal.core.road.RoadDescription`).

Frame: highway-env world coordinates in metres. A lane's positive lateral offset is to the left of the
driving direction (counter-clockwise in the math frame), so highway-env ``line_types[1]`` is the left border
and ``line_types[0]`` the right one. Lane priorities (used by `seal.envs.traffic` to decide who yields) are set on
the lanes: higher priority keeps going.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from highway_env.road.lane import AbstractLane, CircularLane, LineType, SineLane, StraightLane
from highway_env.road.road import RoadNetwork

LAYOUTS = ("highway", "merge", "intersection", "roundabout")

C, S, N = LineType.CONTINUOUS_LINE, LineType.STRIPED, LineType.NONE


def _r(x: float, nd: int = 2) -> float:
    """Round sampled parameters so the JSON we store is short and rebuilds bit-identical networks."""
    return float(round(float(x), nd))


# ------------------------------------------------------------------------------------------ parameters
def sample_params(layout: str, rng: np.random.Generator) -> dict[str, Any]:
    """Randomised, JSON-serialisable parameters of ``layout`` (lengths in m, speeds in m/s, angles in deg)."""
    check_layout(layout)
    if layout == "highway":
        return {
            "lanes": int(rng.integers(2, 5)),
            "lane_width": _r(rng.uniform(3.5, 4.2)),
            "length_in": _r(rng.uniform(120.0, 200.0)),
            "arc_length": _r(rng.uniform(120.0, 220.0)),
            "curve_deg": _r(rng.uniform(-25.0, 25.0)),
            "length_out": _r(rng.uniform(120.0, 200.0)),
            "speed_limit": _r(rng.uniform(22.0, 33.0)),
        }
    if layout == "merge":
        return {
            "lanes": int(rng.integers(2, 4)),
            "lane_width": _r(rng.uniform(3.5, 4.2)),
            "before": _r(rng.uniform(100.0, 160.0)),
            "converge": _r(rng.uniform(60.0, 100.0)),
            "parallel": _r(rng.uniform(60.0, 130.0)),
            "after": _r(rng.uniform(150.0, 220.0)),
            "ramp_offset": _r(rng.uniform(5.0, 9.0)),
            "speed_limit": _r(rng.uniform(20.0, 30.0)),
        }
    if layout == "intersection":
        width = _r(rng.uniform(3.5, 4.2))
        return {
            "lane_width": width,
            "access_length": _r(rng.uniform(70.0, 110.0)),
            "right_turn_radius": _r(width + rng.uniform(3.0, 8.0)),
            "speed_limit": _r(rng.uniform(8.0, 13.0)),
            "priority_axis": int(rng.integers(0, 2)),
        }
    # roundabout
    return {
        "radius": _r(rng.uniform(15.0, 30.0)),
        "lanes": int(rng.integers(1, 3)),
        "access_length": _r(rng.uniform(50.0, 80.0)),
        "speed_limit": _r(rng.uniform(8.0, 13.0)),
    }


def check_layout(layout: str) -> None:
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; choose from {', '.join(LAYOUTS)}")


# ------------------------------------------------------------------------------------------ networks
def make_network(layout: str, params: dict[str, Any]) -> RoadNetwork:
    """Build the highway-env road network of ``layout`` from ``params`` (as returned by `sample_params`)."""
    check_layout(layout)
    builders: dict[str, Callable[[dict[str, Any]], RoadNetwork]] = {
        "highway": _highway,
        "merge": _merge,
        "intersection": _intersection,
        "roundabout": _roundabout,
    }
    try:
        return builders[layout](params)
    except KeyError as exc:
        raise ValueError(f"layout {layout!r}: missing parameter {exc.args[0]!r}") from None


def _edge_lines(i: int, lanes: int, left_edge: int = C) -> list[int]:
    """highway-env [right, left] borders of lane ``i`` of a ``lanes``-lane road (inner borders drawn once)."""
    return [C if i == 0 else S, left_edge if i == lanes - 1 else N]


def _highway(p: dict[str, Any]) -> RoadNetwork:
    net = RoadNetwork()
    lanes, w, v = int(p["lanes"]), float(p["lane_width"]), float(p["speed_limit"])
    l_in, arc, l_out = float(p["length_in"]), float(p["arc_length"]), float(p["length_out"])
    theta = math.radians(float(p["curve_deg"]))
    for i in range(lanes):
        lt = _edge_lines(i, lanes)
        o = i * w  # lateral offset of lane i (to the left)
        net.add_lane("a", "b", StraightLane([0.0, o], [l_in, o], w, lt, speed_limit=v))
        if abs(theta) < math.radians(2.0):
            # Nearly straight: a circle of several km radius is numerically poor, use a straight lane.
            mid: AbstractLane = StraightLane([l_in, o], [l_in + arc, o], w, lt, speed_limit=v)
            heading = 0.0
        else:
            radius = arc / abs(theta)
            if theta > 0:  # left turn: centre on the left, inner (left) lanes have the smaller radius
                mid = CircularLane(
                    [l_in, radius], radius - o, -math.pi / 2, -math.pi / 2 + theta, True, w, lt, speed_limit=v
                )
            else:
                mid = CircularLane(
                    [l_in, -radius], radius + o, math.pi / 2, math.pi / 2 + theta, False, w, lt, speed_limit=v
                )
            heading = theta
        net.add_lane("b", "c", mid)
        start = mid.position(mid.length, 0.0)
        end = start + l_out * np.array([math.cos(heading), math.sin(heading)])
        net.add_lane("c", "d", StraightLane(start, end, w, lt, speed_limit=v))
    return net


def _merge(p: dict[str, Any]) -> RoadNetwork:
    """Main road a-b-c-d with ``lanes`` lanes; the ramp j-k-b joins on the left (+y) as lane ``lanes`` of
    b-c (an acceleration lane that ends at c)."""
    net = RoadNetwork()
    lanes, w, v = int(p["lanes"]), float(p["lane_width"]), float(p["speed_limit"])
    before, converge, parallel, after = (float(p[k]) for k in ("before", "converge", "parallel", "after"))
    x = [0.0, before + converge, before + converge + parallel, before + converge + parallel + after]
    for i in range(lanes):
        y = i * w
        net.add_lane("a", "b", StraightLane([x[0], y], [x[1], y], w, _edge_lines(i, lanes), speed_limit=v))
        # Along the acceleration lane the left edge of the last main lane is a lane line, not a road edge.
        net.add_lane(
            "b", "c", StraightLane([x[1], y], [x[2], y], w, _edge_lines(i, lanes, left_edge=N), speed_limit=v)
        )
        net.add_lane("c", "d", StraightLane([x[2], y], [x[3], y], w, _edge_lines(i, lanes), speed_limit=v))
    amplitude = float(p["ramp_offset"]) / 2
    y_parallel = lanes * w
    y_approach = y_parallel + 2 * amplitude
    net.add_lane(
        "j",
        "k",
        StraightLane([0.0, y_approach], [before, y_approach], w, [C, C], forbidden=True, speed_limit=v),
    )
    net.add_lane(
        "k",
        "b",
        SineLane(
            [before, y_parallel + amplitude],
            [x[1], y_parallel + amplitude],
            amplitude,
            math.pi / converge,
            math.pi / 2,
            w,
            [C, C],
            forbidden=True,
            speed_limit=v,
        ),
    )
    net.add_lane(
        "b",
        "c",
        StraightLane([x[1], y_parallel], [x[2], y_parallel], w, [S, C], forbidden=True, speed_limit=v),
    )
    return net


def _intersection(p: dict[str, Any]) -> RoadNetwork:
    """4-way intersection (highway-env ``IntersectionEnv`` geometry). Nodes: o<k> outer, ir<k>/il<k> inner.

    Corner k = 0..3 is the approach rotated by k * 90 deg. The axis ``priority_axis`` (0: corners 0/2,
    1: corners 1/3) has right of way; left turns have one priority level less than going straight or turning
    right.
    """
    net = RoadNetwork()
    w, v = float(p["lane_width"]), float(p["speed_limit"])
    right_r = float(p["right_turn_radius"])
    left_r = right_r + w
    outer = right_r + w / 2
    access = float(p["access_length"])
    axis = int(p["priority_axis"])
    for corner in range(4):
        angle = math.radians(90 * corner)
        prio = 3 if corner % 2 == axis else 1
        rot = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
        k, right, left, straight = (
            str(corner),
            str((corner - 1) % 4),
            str((corner + 1) % 4),
            str((corner + 2) % 4),
        )
        net.add_lane(
            "o" + k,
            "ir" + k,
            StraightLane(
                rot @ [w / 2, access + outer], rot @ [w / 2, outer], w, [S, C], speed_limit=v, priority=prio
            ),
        )
        net.add_lane(
            "ir" + k,
            "il" + right,
            CircularLane(
                rot @ [outer, outer],
                right_r,
                angle + math.pi,
                angle + 1.5 * math.pi,
                True,
                w,
                [N, C],
                speed_limit=v,
                priority=prio,
            ),
        )
        net.add_lane(
            "ir" + k,
            "il" + left,
            CircularLane(
                rot @ [-left_r + w / 2, left_r - w / 2],
                left_r,
                angle,
                angle - math.pi / 2,
                False,
                w,
                [N, N],
                speed_limit=v,
                priority=prio - 1,
            ),
        )
        net.add_lane(
            "ir" + k,
            "il" + straight,
            StraightLane(
                rot @ [w / 2, outer], rot @ [w / 2, -outer], w, [S, N], speed_limit=v, priority=prio
            ),
        )
        # Exit towards corner "right" (the exit lane of corner k-1 is added here, as in highway-env).
        net.add_lane(
            "il" + right,
            "o" + right,
            StraightLane(
                rot @ [outer, w / 2], rot @ [access + outer, w / 2], w, [N, C], speed_limit=v, priority=prio
            ),
        )
    return net


_RB_NODES = ("se", "ex", "ee", "nx", "ne", "wx", "we", "sx", "se")


def _roundabout(p: dict[str, Any]) -> RoadNetwork:
    """Roundabout (highway-env ``RoundaboutGenericEnv`` geometry) with 4 two-way access roads.

    Ring lanes have priority 1, entries priority 0 (entering vehicles yield), exits priority 1.
    """
    net = RoadNetwork()
    radius, n_lanes, v = float(p["radius"]), int(p["lanes"]), float(p["speed_limit"])
    alpha = 24.0
    w = AbstractLane.DEFAULT_WIDTH  # the access geometry below assumes 4 m lanes (offsets of +-2 m)
    radii = [radius + w * i for i in range(n_lanes)]
    _roundabout_ring(net, radii, alpha, v)
    _roundabout_access(net, radii[-1], alpha, float(p["access_length"]), v)
    return net


def _roundabout_ring(net: RoadNetwork, radii: list[float], alpha: float, v: float) -> None:
    """The ring: 8 arcs per lane between `_RB_NODES` (``radii`` in m, ``alpha`` in degrees, speed limit ``v``)."""
    n_lanes = len(radii)
    w = AbstractLane.DEFAULT_WIDTH
    angles = [
        (90 - alpha, alpha),
        (alpha, -alpha),
        (-alpha, -90 + alpha),
        (-90 + alpha, -90 - alpha),
        (-90 - alpha, -180 + alpha),
        (-180 + alpha, -180 - alpha),
        (180 - alpha, 90 + alpha),
        (90 + alpha, 90 - alpha),
    ]
    for lane in range(n_lanes):
        if n_lanes == 1:
            lt = [C, C]
        elif lane == 0:
            lt = [C, S]
        elif lane == n_lanes - 1:
            lt = [N, C]
        else:
            lt = [N, S]
        for i in range(8):
            arc = CircularLane(
                [0.0, 0.0], radii[lane], math.radians(angles[i][0]), math.radians(angles[i][1]), False, w, lt,
                speed_limit=v, priority=1,
            )
            net.add_lane(_RB_NODES[i], _RB_NODES[i + 1], arc)


def _roundabout_access(net: RoadNetwork, r_out: float, alpha: float, access_length: float, v: float) -> None:
    """The 4 two-way access roads (south, east, north, west): a straight and a sine-shaped entry (priority 0) and
    exit each, meeting the outer ring lane (radius ``r_out`` in m) at ``alpha`` degrees from the axes."""

    def pt(deg: float) -> tuple[float, float]:
        return r_out * math.cos(math.radians(deg)), r_out * math.sin(math.radians(deg))

    p_se, p_ex, p_ee, p_nx = pt(90 - alpha), pt(alpha), pt(-alpha), pt(-90 + alpha)
    p_ne, p_wx, p_we, p_sx = pt(-90 - alpha), pt(-180 + alpha), pt(180 - alpha), pt(90 + alpha)
    dev = max(100.0, 2 * r_out + 40.0)
    access = dev / 2 + access_length
    h = dev / 2
    phase = -math.pi / 2  # every sine lane starts at a trough

    def add(a: str, b: str, lane: AbstractLane, entry: bool = False) -> None:
        lane.speed_limit = v
        if entry:
            lane.priority = 0
        net.add_lane(a, b, lane)

    # South
    a = (p_se[0] - 2) / 2
    add("ser", "ses", StraightLane([2, access], [2, h], line_types=(S, C)), entry=True)
    add("ses", "se", SineLane([2 + a, h], [2 + a, p_se[1]], a, math.pi / (h - p_se[1]), phase, line_types=(C, C)),
        entry=True)
    a = (p_sx[0] + 2) / 2
    add("sx", "sxs", SineLane([p_sx[0] - a, p_sx[1]], [p_sx[0] - a, h], a, math.pi / (h - p_sx[1]), phase,
                              line_types=(C, C)))
    add("sxs", "sxr", StraightLane([-2, h], [-2, access], line_types=(N, C)))
    # East
    a = (-2 - p_ee[1]) / 2
    add("eer", "ees", StraightLane([access, -2], [h, -2], line_types=(S, C)), entry=True)
    add("ees", "ee", SineLane([h, -2 - a], [p_ee[0], -2 - a], a, math.pi / (h - p_ee[0]), phase,
                              line_types=(C, C)), entry=True)
    a = (2 - p_ex[1]) / 2
    add("ex", "exs", SineLane([p_ex[0], p_ex[1] + a], [h, p_ex[1] + a], a, math.pi / (h - p_ex[0]), phase,
                              line_types=(C, C)))
    add("exs", "exr", StraightLane([h, 2], [access, 2], line_types=(N, C)))
    # North
    a = (-2 - p_ne[0]) / 2
    add("ner", "nes", StraightLane([-2, -access], [-2, -h], line_types=(S, C)), entry=True)
    add("nes", "ne", SineLane([-2 - a, -h], [-2 - a, p_ne[1]], a, math.pi / (p_ne[1] + h), phase,
                              line_types=(C, C)), entry=True)
    a = (2 - p_nx[0]) / 2
    add("nx", "nxs", SineLane([p_nx[0] + a, p_nx[1]], [p_nx[0] + a, -h], a, math.pi / (p_nx[1] + h), phase,
                              line_types=(C, C)))
    add("nxs", "nxr", StraightLane([2, -h], [2, -access], line_types=(N, C)))
    # West
    a = (p_we[1] - 2) / 2
    add("wer", "wes", StraightLane([-access, 2], [-h, 2], line_types=(S, C)), entry=True)
    add("wes", "we", SineLane([-h, 2 + a], [p_we[0], 2 + a], a, math.pi / (p_we[0] + h), phase,
                              line_types=(C, C)), entry=True)
    a = (p_wx[1] + 2) / 2
    add("wx", "wxs", SineLane([p_wx[0], p_wx[1] - a], [-h, p_wx[1] - a], a, math.pi / (p_wx[0] + h), phase,
                              line_types=(C, C)))
    add("wxs", "wxr", StraightLane([-h, -2], [-access, -2], line_types=(N, C)))
