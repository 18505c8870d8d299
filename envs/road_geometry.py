"""Road geometry precomputed once per `RoadDescription`: borders, drivable area and segment grids.

Built from the lane polylines only (no highway-env objects), cached by road identity (`get_road_geometry`),
then queried every step:

* ``edges``: segments the road-edge rays see: every ``continuous`` lane border plus the boundary of the
  drivable area where no continuous border runs along it (so roads painted with ``none`` borders, e.g. inside
  intersections, and road ends still have edges).
* ``lines``: every painted lane border (``striped`` and ``continuous``) for the lane-line rays.
* ``continuous``: ``continuous`` borders only, for the "crossed a solid line" test.
* ``drivable``: the union of all lane polygons (shapely, prepared), for the "corner left the road" test.
* ``centres``: lane centre segments tagged with their lane index, for the lane speed-limit lookup.

Left / right follow `seal.core.road.LaneSpec`: seen when driving along the lane in the world frame (x right, y up,
headings counter-clockwise), the left border is at ``+width/2`` along the left normal ``(-sin h, cos h)``.

Segment queries use a uniform grid: each cell memoises (on first use) the segments within ``reach`` metres of
the cell, stored as contiguous arrays, so a step costs one dict lookup instead of a distance filter.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import shapely

from seal.core.road import RoadDescription
from seal.core.road_area import drivable_area, lane_borders
from seal.core.road_area import offset_polyline as offset_polyline  # re-exported: older callers import it here

CELL_M = 20.0
SIMPLIFY_M = 0.1
"""Border polylines are simplified with this tolerance (m): fewer segments, same rays to within 10 cm."""


@dataclass(frozen=True)
class Segments:
    """Segments relative to nothing (world frame): start ``a`` and vector ``e`` as separate ``[M]`` arrays."""

    ax: np.ndarray
    ay: np.ndarray
    ex: np.ndarray
    ey: np.ndarray
    tag: np.ndarray

    @property
    def size(self) -> int:
        return int(self.ax.shape[0])

    @cached_property
    def rows(self) -> list[tuple[float, float, float, float, int]]:
        """The segments as Python tuples ``(ax, ay, ex, ey, tag)`` (computed once; for loops over a few)."""
        return list(zip(*(v.tolist() for v in (self.ax, self.ay, self.ex, self.ey, self.tag)), strict=True))


_PY_MAX = 24
"""Up to this many segments, per-step segment tests run as a plain Python loop."""


def _segments(polylines: list[np.ndarray], tags: list[int] | None = None) -> Segments:
    a, e, tag = [], [], []
    for i, pl in enumerate(polylines):
        if len(pl) < 2:
            continue
        a.append(pl[:-1])
        e.append(np.diff(pl, axis=0))
        tag.append(np.full(len(pl) - 1, i if tags is None else tags[i], dtype=np.int64))
    if not a:
        z = np.zeros(0)
        return Segments(z, z, z, z, np.zeros(0, dtype=np.int64))
    a_, e_ = np.concatenate(a), np.concatenate(e)
    keep = np.hypot(e_[:, 0], e_[:, 1]) > 1e-9
    a_, e_, tag_ = a_[keep], e_[keep], np.concatenate(tag)[keep]
    return Segments(
        np.ascontiguousarray(a_[:, 0]), np.ascontiguousarray(a_[:, 1]),
        np.ascontiguousarray(e_[:, 0]), np.ascontiguousarray(e_[:, 1]), tag_,
    )


class SegmentGrid:
    """Uniform-grid lookup of the segments within ``reach`` metres of a point (a superset: by bounding box)."""

    def __init__(self, segments: Segments, reach: float, cell: float = CELL_M) -> None:
        self.segments = segments
        self.reach = float(reach)
        self.cell = float(cell)
        s = segments
        self._xmin = np.minimum(s.ax, s.ax + s.ex)
        self._xmax = np.maximum(s.ax, s.ax + s.ex)
        self._ymin = np.minimum(s.ay, s.ay + s.ey)
        self._ymax = np.maximum(s.ay, s.ay + s.ey)
        self._cells: dict[tuple[int, int], Segments] = {}

    def query(self, x: float, y: float) -> Segments:
        """Segments whose bounding box lies within ``reach`` of the grid cell holding (x, y)."""
        key = (math.floor(x / self.cell), math.floor(y / self.cell))
        hit = self._cells.get(key)
        if hit is None:
            x0, y0 = key[0] * self.cell - self.reach, key[1] * self.cell - self.reach
            x1, y1 = x0 + self.cell + 2 * self.reach, y0 + self.cell + 2 * self.reach
            m = (self._xmax >= x0) & (self._xmin <= x1) & (self._ymax >= y0) & (self._ymin <= y1)
            s = self.segments
            hit = Segments(
                np.ascontiguousarray(s.ax[m]), np.ascontiguousarray(s.ay[m]),
                np.ascontiguousarray(s.ex[m]), np.ascontiguousarray(s.ey[m]), s.tag[m],
            )
            self._cells[key] = hit
        return hit


def _simplify(pts: np.ndarray) -> np.ndarray:
    if len(pts) <= 2:
        return pts
    return np.asarray(shapely.simplify(shapely.LineString(pts), SIMPLIFY_M).coords)


class RoadGeometry:
    """Precomputed geometry of one road (see the module docstring).

    Args:
        road: the road description.
        ray_range_m: range of the road-edge rays (m); sets the reach of the edge grid.
        line_range_m: range of the lane-line rays (m).
    """

    def __init__(self, road: RoadDescription, ray_range_m: float = 50.0, line_range_m: float = 20.0) -> None:
        self.road = road
        lanes = road.lanes
        lefts, rights, polys = lane_borders(road)
        self.lane_left = lefts
        """Left border polyline of each lane ``[P, 2]`` (m)."""
        self.lane_right = rights
        self.speed_limits = np.array([lane.speed_limit_mps for lane in lanes], dtype=np.float64)

        area = drivable_area(polys)
        self.drivable = area
        """Union of the lane polygons (shapely geometry, prepared for fast point tests)."""
        self._grown_cache: dict[float, shapely.Geometry] = {}
        self._limit_cells: dict[tuple[int, int], float] = {}

        # Painted borders, each once: adjacent lanes share a border (left of one = right of the other).
        borders = [(lefts[i], lane.line_types[0]) for i, lane in enumerate(lanes)]
        borders += [(rights[i], lane.line_types[1]) for i, lane in enumerate(lanes)]
        painted = _dedupe([(b, t) for b, t in borders if t != "none"])
        continuous = [_simplify(b) for b, t in painted if t == "continuous"]
        # The drivable-area boundary, minus the stretches a continuous border already covers.
        rings = shapely.MultiLineString([np.asarray(r.coords) for r in _rings(area)])
        if continuous:
            rings = shapely.difference(rings, shapely.buffer(shapely.MultiLineString(continuous), 0.2))
        boundary = [_simplify(np.asarray(g.coords)) for g in _lines(rings)]
        self.boundary_polylines = boundary
        self.continuous_polylines = continuous
        self.painted_polylines = [_simplify(b) for b, _ in painted]

        self.edges = SegmentGrid(_segments(continuous + boundary), reach=ray_range_m)
        self.lines = SegmentGrid(_segments(self.painted_polylines), reach=line_range_m)
        # Tagged with their global index so callers can mask individual segments.
        cont = _segments(continuous)
        self.continuous_segments = Segments(cont.ax, cont.ay, cont.ex, cont.ey, np.arange(cont.size))
        self.continuous = SegmentGrid(self.continuous_segments, reach=9.0, cell=6.0)  # > half diagonal, 16 m truck
        self.centres = SegmentGrid(
            _segments([_simplify(lane.centerline) for lane in lanes], list(range(len(lanes)))),
            reach=max(lane.width_m for lane in lanes) * 2,
        )

    # ------------------------------------------------------------------------------------------ queries
    def on_road(self, xs: np.ndarray, ys: np.ndarray, tolerance_m: float = 0.0) -> bool:
        """True when every point (e.g. the 4 box corners) lies in the drivable area grown by ``tolerance_m``."""
        area = self.drivable if tolerance_m <= 0 else self._grown(tolerance_m)
        return bool(shapely.contains_xy(area, xs, ys).all())

    def _grown(self, tolerance_m: float) -> shapely.Geometry:
        area = self._grown_cache.get(tolerance_m)
        if area is None:
            area = shapely.buffer(self.drivable, tolerance_m)
            shapely.prepare(area)
            self._grown_cache[tolerance_m] = area
        return area

    def crosses_continuous(
        self, x: float, y: float, heading: float, length: float, width: float, ignore: np.ndarray | None = None
    ) -> bool:
        """True when a ``continuous`` border passes through the oriented box.

        Args:
            ignore: optional bool mask over `continuous_segments` (by global index) of segments not to count.
        """
        s = self.continuous.query(x, y)
        if s.size == 0:
            return False
        if s.size > _PY_MAX:
            hit = box_segment_hits(x, y, heading, length, width, s.ax, s.ay, s.ex, s.ey)
            if ignore is not None:
                hit &= ~ignore[s.tag]
            return bool(hit.any())
        # Few segments (the usual case): plain Python beats a dozen numpy calls.
        c, sn = math.cos(heading), math.sin(heading)
        hl, hw = 0.5 * length, 0.5 * width
        for ax, ay, ex, ey, tag in s.rows:
            if ignore is not None and ignore[tag]:
                continue
            rx, ry = ax - x, ay - y
            p0x, p0y = rx * c + ry * sn, ry * c - rx * sn
            dx, dy = ex * c + ey * sn, ey * c - ex * sn
            p1x, p1y = p0x + dx, p0y + dy
            if min(p0x, p1x) > hl or max(p0x, p1x) < -hl or min(p0y, p1y) > hw or max(p0y, p1y) < -hw:
                continue
            if abs(p0x * dy - p0y * dx) > hl * abs(dy) + hw * abs(dx):
                continue
            return True
        return False

    def continuous_hits_along(self, track_xyhlw: np.ndarray) -> np.ndarray:
        """Bool mask over `continuous_segments` of the segments any of the boxes ``[T, 5]`` (x, y, heading,
        length, width) passes through (used to find the solid lines a logged track crosses)."""
        s = self.continuous_segments
        if s.size == 0 or track_xyhlw.shape[0] == 0:
            return np.zeros(s.size, dtype=bool)
        b = track_xyhlw[:, :, None]
        hit = box_segment_hits(b[:, 0], b[:, 1], b[:, 2], b[:, 3], b[:, 4], s.ax, s.ay, s.ex, s.ey)
        return np.asarray(hit.any(axis=0))

    def speed_limit_at(self, x: float, y: float, default: float = 30.0) -> float:
        """Speed limit (m/s) of the lane whose centre line is closest to (x, y)."""
        key = (math.floor(x / self.centres.cell), math.floor(y / self.centres.cell))
        uniform = self._limit_cells.get(key)
        if uniform is None:
            # One limit for every lane near this cell (the usual case): remember it, skip the search next time.
            limits = self.speed_limits[self.centres.query(x, y).tag]
            uniform = float(limits[0]) if limits.size and (limits == limits[0]).all() else math.nan
            self._limit_cells[key] = uniform
        if not math.isnan(uniform):
            return uniform
        s = self.centres.query(x, y)
        if s.size == 0:
            return default
        px, py = x - s.ax, y - s.ay
        t = np.clip((px * s.ex + py * s.ey) / (s.ex * s.ex + s.ey * s.ey), 0.0, 1.0)
        dx, dy = px - t * s.ex, py - t * s.ey
        return float(self.speed_limits[s.tag[int(np.argmin(dx * dx + dy * dy))]])


def box_segment_hits(
    x: np.ndarray | float, y: np.ndarray | float, heading: np.ndarray | float, length: np.ndarray | float,
    width: np.ndarray | float, ax: np.ndarray, ay: np.ndarray, ex: np.ndarray, ey: np.ndarray,
) -> np.ndarray:
    """Whether each segment (world frame, start ``a``, vector ``e``) passes through the oriented box(es).

    Separating-axis test with the box's two axes and the segment's normal; box and segment arrays broadcast.
    """
    c, sn = np.cos(heading), np.sin(heading)
    rx, ry = ax - x, ay - y
    p0x, p0y = rx * c + ry * sn, ry * c - rx * sn  # segment start in the box frame
    dx, dy = ex * c + ey * sn, ey * c - ex * sn
    hl, hw = 0.5 * length, 0.5 * width
    p1x, p1y = p0x + dx, p0y + dy
    sep = (np.minimum(p0x, p1x) > hl) | (np.maximum(p0x, p1x) < -hl)
    sep |= (np.minimum(p0y, p1y) > hw) | (np.maximum(p0y, p1y) < -hw)
    # On the segment normal (scaled by the segment length): |p0 x d| vs the box's projection radius.
    sep |= np.abs(p0x * dy - p0y * dx) > hl * np.abs(dy) + hw * np.abs(dx)
    return ~sep


def _dedupe(borders: list[tuple[np.ndarray, str]], tol: float = 0.1) -> list[tuple[np.ndarray, str]]:
    """Borders without near-duplicates (Hausdorff distance < ``tol``); a duplicate painted ``continuous`` on
    either side stays ``continuous``."""
    kept: list[tuple[np.ndarray, str]] = []
    lines: list[shapely.LineString] = []
    boxes = np.zeros((0, 4))
    for pts, kind in borders:
        line = shapely.LineString(pts)
        b = np.asarray(line.bounds)
        near = np.flatnonzero(
            (boxes[:, 0] <= b[2] + tol) & (boxes[:, 2] >= b[0] - tol)
            & (boxes[:, 1] <= b[3] + tol) & (boxes[:, 3] >= b[1] - tol)
        )
        dup = next((int(k) for k in near if shapely.hausdorff_distance(line, lines[k]) < tol), None)
        if dup is None:
            kept.append((pts, kind))
            lines.append(line)
            boxes = np.vstack([boxes, b])
        elif kind == "continuous":
            kept[dup] = (kept[dup][0], "continuous")
    return kept


def _lines(geom: shapely.Geometry) -> list[shapely.LineString]:
    if geom.is_empty:
        return []
    if isinstance(geom, shapely.LineString):
        return [geom]
    return [g for g in getattr(geom, "geoms", []) if isinstance(g, shapely.LineString) and not g.is_empty]


def _rings(area: shapely.Geometry) -> list[shapely.LinearRing]:
    out = []
    for poly in getattr(area, "geoms", [area]):
        if isinstance(poly, shapely.Polygon):
            out.append(poly.exterior)
            out.extend(poly.interiors)
    return out


_CACHE: OrderedDict[int, tuple[RoadDescription, RoadGeometry]] = OrderedDict()
_CACHE_SIZE = 64


def reserve_road_cache(n_roads: int) -> None:
    """Keep at least ``n_roads`` geometries in `get_road_geometry`'s cache (about 0.07 MB each): a training env
    cycling through more distinct roads than the default 64 would otherwise rebuild one (~20 ms) on most resets."""
    global _CACHE_SIZE
    _CACHE_SIZE = max(_CACHE_SIZE, int(n_roads))


def get_road_geometry(road: RoadDescription) -> RoadGeometry:
    """`RoadGeometry` of ``road``, cached by object identity (scenarios of a dataset shard share road objects).

    The cache holds a reference to the road so an id is never reused while cached; least recently used roads
    are dropped beyond 64.
    """
    key = id(road)
    hit = _CACHE.get(key)
    if hit is not None and hit[0] is road:
        _CACHE.move_to_end(key)
        return hit[1]
    geom = RoadGeometry(road)
    _CACHE[key] = (road, geom)
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return geom
