"""Topology of a highway-env road network: lane indices, successor / predecessor maps (lanes that continue into
each other within `SUCCESSOR_TOL_M`), and `describe_network`, which turns any network into a
`seal.core.road.RoadDescription` (lane centre polylines, widths, line types, speed limits, successors)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from highway_env.road.lane import AbstractLane, LineType, SineLane, StraightLane
from highway_env.road.road import LaneIndex, RoadNetwork

from seal.core.road import LaneSpec, RoadDescription

_LINE_NAMES = {
    LineType.NONE: "none",
    LineType.STRIPED: "striped",
    LineType.CONTINUOUS: "continuous",
    LineType.CONTINUOUS_LINE: "continuous",
}
_LINE_RANK = {"none": 0, "striped": 1, "continuous": 2}
SAMPLE_STEP_M = 1.0
"""Spacing (m) of the centre-line samples of curved lanes in `describe_network`."""
SUCCESSOR_TOL_M = 1.0
"""A lane continues into another when the other starts within this distance (m) of its end."""
S = LineType.STRIPED


def lane_indices(network: RoadNetwork) -> list[LaneIndex]:
    """All lane indices ``(from, to, id)`` in graph order."""
    return [
        (a, b, i) for a, tos in network.graph.items() for b, lanes in tos.items() for i in range(len(lanes))
    ]


def successor_map(network: RoadNetwork, tol: float = SUCCESSOR_TOL_M) -> dict[LaneIndex, list[LaneIndex]]:
    """Lanes each lane continues into: lanes leaving its end node that start within ``tol`` m of its end."""
    out: dict[LaneIndex, list[LaneIndex]] = {}
    for index in lane_indices(network):
        lane = network.get_lane(index)
        end = lane.position(lane.length, 0.0)
        succ = []
        for nxt, lanes in network.graph.get(index[1], {}).items():
            for j, other in enumerate(lanes):
                if np.linalg.norm(other.position(0.0, 0.0) - end) <= tol:
                    succ.append((index[1], nxt, j))
        out[index] = succ
    return out


def predecessor_map(successors: dict[LaneIndex, list[LaneIndex]]) -> dict[LaneIndex, list[LaneIndex]]:
    out: dict[LaneIndex, list[LaneIndex]] = {k: [] for k in successors}
    for k, succ in successors.items():
        for s in succ:
            out[s].append(k)
    return out


def lane_id(index: LaneIndex) -> str:
    return f"{index[0]}:{index[1]}:{index[2]}"


# ------------------------------------------------------------------------------------------ description
def _centerline(lane: AbstractLane, step: float = SAMPLE_STEP_M) -> np.ndarray:
    if isinstance(lane, StraightLane) and not isinstance(lane, SineLane):
        return np.array([lane.position(0.0, 0.0), lane.position(lane.length, 0.0)], dtype=np.float64)
    n = max(2, int(math.ceil(lane.length / step)) + 1)
    return np.array([lane.position(s, 0.0) for s in np.linspace(0.0, lane.length, n)], dtype=np.float64)


def _sides(network: RoadNetwork) -> dict[LaneIndex, list[str]]:
    """Left/right border names per lane, with borders shared by two lanes of one road merged.

    highway-env draws a border shared by neighbouring lanes only once (the other lane says NONE); a lane on
    its own must still know that a lane line is there, so the stronger of the two types is used on both sides.
    """
    sides: dict[LaneIndex, list[str]] = {}
    for index in lane_indices(network):
        lane = network.get_lane(index)
        lt = list(lane.line_types or [S, S])
        sides[index] = [_LINE_NAMES[lt[1]], _LINE_NAMES[lt[0]]]  # (left, right)
    for a, tos in network.graph.items():
        for b, lanes in tos.items():
            for i in range(len(lanes) - 1):
                lo, hi = lanes[i], lanes[i + 1]
                mid = lo.length / 2
                _, lat = lo.local_coordinates(
                    hi.position(hi.local_coordinates(lo.position(mid, 0.0))[0], 0.0)
                )
                if abs(lat - (lo.width_at(mid) + hi.width_at(0.0)) / 2) > 0.5:
                    continue  # not side by side (e.g. separate carriageways)
                left_of_lo, right_of_hi = sides[(a, b, i)][0], sides[(a, b, i + 1)][1]
                best = max(left_of_lo, right_of_hi, key=_LINE_RANK.__getitem__)
                sides[(a, b, i)][0] = sides[(a, b, i + 1)][1] = best
    return sides


def describe_network(network: RoadNetwork, layout: str, params: dict[str, Any]) -> RoadDescription:
    """Every lane of ``network`` as a `LaneSpec` (curved lanes sampled every ~1 m), plus layout and params.

    The description is in the map frame (x right, y up, angles counter-clockwise) while highway-env draws with
    y down: y is mirrored so that highway-env's right-hand traffic stays right-hand (the ramp of ``merge``
    joins from the right, as in real logs). Mirroring swaps each lane's left and right borders.
    """
    successors = successor_map(network)
    sides = _sides(network)
    default_limit = float(params.get("speed_limit", 30.0))
    lanes = []
    for index in lane_indices(network):
        lane = network.get_lane(index)
        limit = lane.speed_limit if lane.speed_limit is not None else default_limit
        lanes.append(
            LaneSpec(
                lane_id=lane_id(index),
                centerline=_centerline(lane) * np.array([1.0, -1.0]),
                width_m=float(lane.width_at(0.0)),
                line_types=(sides[index][1], sides[index][0]),  # mirrored: highway-env's left is our right
                speed_limit_mps=float(limit),
                successors=tuple(lane_id(s) for s in successors[index]),
            )
        )
    return RoadDescription(layout=layout, lanes=tuple(lanes), params=dict(params))
