"""Lane-centreline chunks: the map tokens of the trajectory prior, and the "on or near the road" test.

Every lane centreline of a `RoadDescription` is cut into chunks of at most ``chunk_length_m`` of arc length,
each resampled to ``n_points`` evenly spaced points (a lane shorter than a chunk gives one shorter chunk).
Chunks are plain numpy arrays in the world frame; the agent-frame transform happens per sample in
`seal.models.prior.features`.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from seal.core.road import LINE_TYPES, LaneSpec, RoadDescription

#: Per-chunk attributes, in order: lane width (m), speed limit (m/s), then one-hot left and right line types.
CHUNK_ATTRS = ("width_m", "speed_limit_mps", *(f"left_{t}" for t in LINE_TYPES), *(f"right_{t}" for t in LINE_TYPES))


@dataclass(frozen=True)
class LaneChunks:
    """Lane-centreline chunks of one road, world frame.

    Attributes:
        points: ``[C, P, 2]`` float64 chunk points (m), in driving order.
        direction: ``[C, P]`` float64 driving direction at each point (rad, world frame).
        attrs: ``[C, len(CHUNK_ATTRS)]`` float64 attributes (see `CHUNK_ATTRS`).
    """

    points: np.ndarray
    direction: np.ndarray
    attrs: np.ndarray

    @property
    def n_chunks(self) -> int:
        return int(self.points.shape[0])


def _lane_chunks(centerline: np.ndarray, chunk_length_m: float, n_points: int) -> tuple[np.ndarray, np.ndarray]:
    """Chunks ``[n, P, 2]`` and directions ``[n, P]`` of one polyline."""
    seg = np.diff(centerline, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    keep = seg_len > 1e-9  # repeated points would make a zero-length segment with no direction
    seg, seg_len = seg[keep], seg_len[keep]
    pts = np.concatenate([centerline[:1], centerline[1:][keep]])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    total = float(cum[-1])
    n_chunks = max(1, int(np.ceil(total / chunk_length_m - 1e-9)))
    starts = np.arange(n_chunks) * chunk_length_m
    ends = np.minimum(starts + chunk_length_m, total)
    s = starts[:, None] + (ends - starts)[:, None] * np.linspace(0.0, 1.0, n_points)[None, :]  # [n, P]
    xy = np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], axis=-1)
    seg_heading = np.arctan2(seg[:, 1], seg[:, 0])
    # Direction of the segment each sample lies on (a sample on a vertex takes the following segment).
    seg_index = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg_heading) - 1)
    return xy, seg_heading[seg_index]


def chunk_road(road: RoadDescription, chunk_length_m: float = 20.0, n_points: int = 9) -> LaneChunks:
    """Cut every lane of ``road`` into chunks (see the module docstring)."""
    if chunk_length_m <= 0 or n_points < 2:
        raise ValueError(f"chunk_road: need chunk_length_m > 0 and n_points >= 2, got {chunk_length_m}, {n_points}")
    points, directions, attrs = [], [], []
    for lane in road.lanes:
        xy, heading = _lane_chunks(lane.centerline, chunk_length_m, n_points)
        row = np.zeros(len(CHUNK_ATTRS))
        row[0], row[1] = lane.width_m, lane.speed_limit_mps
        row[2 + LINE_TYPES.index(lane.line_types[0])] = 1.0
        row[2 + len(LINE_TYPES) + LINE_TYPES.index(lane.line_types[1])] = 1.0
        points.append(xy)
        directions.append(heading)
        attrs.append(np.broadcast_to(row, (xy.shape[0], row.size)))
    return LaneChunks(points=np.concatenate(points), direction=np.concatenate(directions), attrs=np.concatenate(attrs))


class ChunkCache:
    """Small LRU cache of `chunk_road` results keyed by the road object.

    Scenarios of one dataset share few roads and a generator calls the prior many times on one scenario, so
    chunking once per road keeps featurisation off the latency budget. Keys are object ids; the cache holds a
    reference to each road so an id cannot be reused while its entry lives.
    """

    def __init__(self, chunk_length_m: float, n_points: int, max_roads: int = 256, open_edges: bool = False) -> None:
        self.chunk_length_m = chunk_length_m
        self.n_points = n_points
        self.max_roads = max_roads
        self.open_edges = open_edges  # chunk `open_map_edges(road)` instead of the road itself
        self._entries: OrderedDict[int, tuple[RoadDescription, LaneChunks]] = OrderedDict()

    def get(self, road: RoadDescription) -> LaneChunks:
        key = id(road)
        hit = self._entries.get(key)
        if hit is not None and hit[0] is road:
            self._entries.move_to_end(key)
            return hit[1]
        chunks = chunk_road(open_map_edges(road) if self.open_edges else road, self.chunk_length_m, self.n_points)
        self._entries[key] = (road, chunks)
        if len(self._entries) > self.max_roads:
            self._entries.popitem(last=False)
        return chunks


def open_map_edges(road: RoadDescription, length_m: float = 100.0, tol_m: float = 2.0) -> RoadDescription:
    """``road`` with every lane that runs off the edge of the map continued straight for ``length_m``.

    A scenario's map is a crop: lanes that leave it end, although the road goes on, and an agent that is fast or
    near the edge has futures past that end. A lane is taken to leave the map when it has no successor and no
    lane point lies more than ``tol_m`` beyond its end along its final direction; a lane that ends inside the
    map (e.g. a merge lane) is left as it is.
    """
    all_pts = np.concatenate([lane.centerline for lane in road.lanes])
    lanes = []
    for lane in road.lanes:
        pts = lane.centerline
        d = pts[-1] - pts[-2]
        norm = float(np.linalg.norm(d))
        if not lane.successors and norm > 1e-9 and np.max((all_pts - pts[-1]) @ (d / norm)) <= tol_m:
            pts = np.vstack([pts, pts[-1] + d / norm * length_m])
            lane = LaneSpec(lane.lane_id, pts, lane.width_m, lane.line_types, lane.speed_limit_mps, lane.successors)
        lanes.append(lane)
    return RoadDescription(road.layout, tuple(lanes), road.params)


def distance_to_lanes(road: RoadDescription, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance from points to the nearest lane centreline, and that lane's width.

    Args:
        road: the road.
        xy: ``[..., 2]`` points (m, world frame).

    Returns:
        ``(distance_m, width_m)``, each of shape ``[...]``.
    """
    import shapely  # lazy: only the evaluation needs it

    pts = np.asarray(xy, dtype=np.float64)
    flat = pts.reshape(-1, 2)
    lines = [shapely.LineString(lane.centerline) for lane in road.lanes]
    widths = np.array([lane.width_m for lane in road.lanes])
    nearest, dist = shapely.STRtree(lines).query_nearest(
        shapely.points(flat), return_distance=True, all_matches=False
    )
    out_d = np.full(flat.shape[0], np.inf)
    out_w = np.zeros(flat.shape[0])
    out_d[nearest[0]] = dist
    out_w[nearest[0]] = widths[nearest[1]]
    return out_d.reshape(pts.shape[:-1]), out_w.reshape(pts.shape[:-1])
