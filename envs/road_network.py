"""highway-env `RoadNetwork` from a `RoadDescription` (for rendering with highway-env's lane graphics).

Every lane becomes a ``PolyLaneFixedWidth`` through its centre polyline, on its own edge
``(lane_id, lane_id + ">")``. highway-env draws ``line_types[0]`` at lateral ``-width/2`` and ``line_types[1]``
at ``+width/2``; in `seal.core.road` "left" is ``+width/2`` (counter-clockwise side), so the order is (right, left).

``mirror_y=True`` builds the network in ``(x, -y)`` coordinates (and swaps the sides, which mirroring
exchanges): highway-env's screen has y pointing down, so a mirrored network renders the world with y up,
i.e. a vehicle's left is drawn on its left.
"""

from __future__ import annotations

from highway_env.road.lane import LineType, PolyLaneFixedWidth
from highway_env.road.road import RoadNetwork

from seal.core.road import RoadDescription

LINE_TYPE = {"none": LineType.NONE, "striped": LineType.STRIPED, "continuous": LineType.CONTINUOUS}
"""`seal.core.road` line type -> highway-env ``LineType`` (``CONTINUOUS`` follows curves, ``CONTINUOUS_LINE`` would
draw one straight chord)."""


def build_road_network(road: RoadDescription, mirror_y: bool = False) -> RoadNetwork:
    """A highway-env network with one ``PolyLaneFixedWidth`` per lane of ``road``."""
    net = RoadNetwork()
    for lane in road.lanes:
        pts = lane.centerline.copy()
        left, right = (LINE_TYPE[t] for t in lane.line_types)
        line_types = (right, left)
        if mirror_y:
            pts[:, 1] = -pts[:, 1]
            line_types = (left, right)
        net.add_lane(
            lane.lane_id,
            lane.lane_id + ">",
            PolyLaneFixedWidth(
                [tuple(p) for p in pts], width=lane.width_m, line_types=line_types,
                speed_limit=lane.speed_limit_mps,
            ),
        )
    return net
