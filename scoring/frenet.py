"""Lane projection (Frenet s, d) and lane chains on a `seal.core.road.RoadDescription`, vectorised with numpy.

`RoadIndex` flattens all lane centre polylines into one array of segments so that many points are projected at
once: for every point the closest segment among the lanes whose direction is compatible with the agent's heading
gives the lane, the arc length ``s`` along that lane and the signed lateral offset ``d`` (m, left of the driving
direction positive).

Projection uses polylines simplified to 5 cm (the dense arcs of generated roads have ~1 m spacing; simplifying
cuts the point x segment matrix several-fold at a lateral error below 5 cm). Lane chains for the
future-extrapolated tracks use the original polylines.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from seal.core.geometry import wrap_angle
from seal.core.road import RoadDescription
from seal.scoring.conflict_points import lane_conflict_points
from seal.scoring.kernels import cell_keys, project_points

SIMPLIFY_TOL_M = 0.05
MAX_HEADING_DIFF_RAD = np.pi / 3
"""A lane is a candidate for an agent only if its direction is within 60 deg of the agent's heading, so that
opposite or crossing lanes that overlap in space (intersections, roundabouts) are not picked."""
MAX_LANE_DIST_WIDTHS = 1.0
"""Points farther than one lane width from every compatible lane get no lane (-1)."""
_SAMPLE_SPACING_M = 4.0


@dataclass(frozen=True)
class Projection:
    """Result of `RoadIndex.project` for ``N`` points (all arrays ``[N]``).

    Attributes:
        lane: lane index into `RoadIndex.lane_ids`, -1 where no compatible lane is close enough.
        s: arc length (m) along the lane's (simplified) centre line; NaN where ``lane == -1``.
        d: signed lateral offset (m), left positive; NaN where ``lane == -1``.
        in_lane: the point lies within half a lane width of the centre line of its lane.
    """

    lane: np.ndarray
    s: np.ndarray
    d: np.ndarray
    in_lane: np.ndarray


class RoadIndex:
    """Segment arrays, lane attributes and connectivity of one road (build once per road, reuse per agent)."""

    def __init__(self, road: RoadDescription) -> None:
        self.road = road
        self.lane_ids: tuple[str, ...] = tuple(lane.lane_id for lane in road.lanes)
        index = {lid: k for k, lid in enumerate(self.lane_ids)}
        self.centerlines: list[np.ndarray] = [lane.centerline for lane in road.lanes]
        self.widths = np.array([lane.width_m for lane in road.lanes], dtype=np.float64)
        self.lane_lengths = np.array([_polyline_length(c) for c in self.centerlines])
        self.speed_limits = np.array([lane.speed_limit_mps for lane in road.lanes], dtype=np.float64)
        self.successors: list[list[int]] = [[index[s] for s in lane.successors] for lane in road.lanes]
        n = len(self.lane_ids)
        # connected[a, b]: same lane or one continues into the other (used for "same lane" in THW / TTC / DRAC).
        # Row / column n stands for "no lane" and is never connected.
        conn = np.zeros((n + 1, n + 1), dtype=bool)
        conn[np.arange(n), np.arange(n)] = True
        for a, succ in enumerate(self.successors):
            for b in succ:
                conn[a, b] = conn[b, a] = True
        self.connected = conn

        a_list, b_list, lane_list, s0_list = [], [], [], []
        for k, pts in enumerate(self.centerlines):
            simple = np.asarray(shapely.simplify(shapely.LineString(pts), SIMPLIFY_TOL_M).coords)
            if simple.shape[0] < 2:  # degenerate (zero-length) lane: keep the raw polyline
                simple = pts
            seg = np.diff(simple, axis=0)
            seg_len = np.linalg.norm(seg, axis=1)
            keep = seg_len > 1e-9
            a_list.append(simple[:-1][keep])
            b_list.append(simple[1:][keep])
            lane_list.append(np.full(int(keep.sum()), k))
            s0_list.append((np.concatenate([[0.0], np.cumsum(seg_len)[:-1]]))[keep])
        self.seg_a = np.concatenate(a_list)
        self.seg_d = np.concatenate(b_list) - self.seg_a
        self.seg_len2 = np.maximum((self.seg_d**2).sum(1), 1e-12)
        self.seg_len = np.sqrt(self.seg_len2)
        self.seg_lane = np.concatenate(lane_list)
        self.seg_s0 = np.concatenate(s0_list)
        self.seg_heading = np.arctan2(self.seg_d[:, 1], self.seg_d[:, 0])
        self._seg_cos, self._seg_sin = self.seg_d[:, 0] / self.seg_len, self.seg_d[:, 1] / self.seg_len
        n_samples = np.ceil(self.seg_len / _SAMPLE_SPACING_M).astype(np.int64) + 1
        self._sample_seg = np.repeat(np.arange(self.seg_len.size), n_samples)
        frac = (np.arange(self._sample_seg.size) - np.repeat(np.cumsum(n_samples) - n_samples, n_samples)) / np.repeat(
            n_samples - 1, n_samples
        )
        self._samples = self.seg_a[self._sample_seg] + frac[:, None] * self.seg_d[self._sample_seg]
        self._search_radius = MAX_LANE_DIST_WIDTHS * float(self.widths.max()) + 0.5 * _SAMPLE_SPACING_M + 1e-6
        # The compiled projection's grid: sample points by cell (side = the search radius), sorted by cell key.
        self._grid_origin = self._samples.min(axis=0) if self._samples.size else np.zeros(2)
        keys = cell_keys(self._samples, self._grid_origin, self._search_radius)
        order = np.argsort(keys, kind="stable")
        sorted_keys = keys[order]
        starts = np.flatnonzero(np.concatenate([[True], sorted_keys[1:] != sorted_keys[:-1]]))
        self._grid_cells = np.ascontiguousarray(sorted_keys[starts])
        self._grid_start = np.concatenate([starts, [sorted_keys.size]]).astype(np.int64)
        self._grid_seg = np.ascontiguousarray(self._sample_seg[order], dtype=np.int64)
        self.seg_lane = np.ascontiguousarray(self.seg_lane, dtype=np.int64)
        self._conflict_points: np.ndarray | None = None
        self._chains: dict[tuple[int, tuple[int, ...]], LaneChain] = {}

    @property
    def n_lanes(self) -> int:
        return len(self.lane_ids)

    @property
    def conflict_points(self) -> np.ndarray:
        """``[C, 2]`` lane conflict points (m), see `seal.scoring.conflict_points` (computed on first use)."""
        if self._conflict_points is None:
            self._conflict_points = lane_conflict_points(self)
        return self._conflict_points

    # ------------------------------------------------------------------------------------------ projection
    def project(self, xy: np.ndarray, heading: np.ndarray | None = None) -> Projection:
        """Project points ``xy [N, 2]`` (m) with headings ``[N]`` (rad, optional) onto the closest compatible lane.

        Candidate segments come from a grid of points sampled every <= 4 m along the segments: any segment within
        the assignment distance of a point has a sample in the 3 x 3 cells around it, and a point only meets the
        few segments around it instead of all of them (compiled: `seal.scoring.kernels.project_points`).
        """
        xy = np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
        use_heading = heading is not None
        h = np.ascontiguousarray(np.asarray(heading, dtype=np.float64).reshape(-1)) if use_heading else np.zeros(0)
        lane, s, d, in_lane = project_points(
            xy, h, use_heading, self._grid_origin, self._search_radius, self._grid_cells, self._grid_start,
            self._grid_seg, self.seg_a, self.seg_d, self.seg_len2, self.seg_len, self._seg_cos, self._seg_sin,
            float(np.cos(MAX_HEADING_DIFF_RAD)), self.seg_lane, self.seg_s0, self.widths, MAX_LANE_DIST_WIDTHS,
        )
        return Projection(lane=lane, s=s, d=d, in_lane=in_lane)

    # ------------------------------------------------------------------------------------------ lane chains
    def chain(self, lane: int, min_length_m: float, route: tuple[int, ...] = ()) -> LaneChain:
        """Centre polyline starting with ``lane`` and continuing through successors for at least ``min_length_m``
        metres (or until a lane has none). Cached per (lane, route).

        Where a lane has several successors the chain takes the one that comes first in ``route`` (the lanes the
        agent drives on in its logged future, in order of preference), and the straightest one where none of them
        is in ``route``: the counterfactual driver follows the way it really went, and keeps going where the log
        does not say.
        """
        key = (lane, route)
        hit = self._chains.get(key)
        # A cached chain serves if it is long enough or ended at a dead end (it cannot grow).
        if hit is not None and (hit.polyline.length >= min_length_m or hit.dead_end):
            return hit
        rank = {r: k for k, r in enumerate(route)}  # route lanes are distinct
        # Build generously (8 s at 50 m/s past the lane) so that one build serves every agent on the lane.
        target = max(min_length_m, float(self.lane_lengths[lane]) + 400.0)
        pts = [self.centerlines[lane]]
        seg_lane = [np.full(pts[0].shape[0] - 1, lane)]
        total = float(self.lane_lengths[lane])
        current = lane
        seen = {lane}
        dead_end = False
        while total < target:
            options = [c for c in self.successors[current] if c not in seen]
            on_route = [c for c in options if c in rank]
            if on_route:
                best = min(on_route, key=rank.__getitem__)
            elif options:
                end_dir = _end_direction(self.centerlines[current])
                turns = [abs(float(wrap_angle(_start_direction(self.centerlines[c]) - end_dir))) for c in options]
                best = options[int(np.argmin(turns))]
            else:
                dead_end = True
                break
            nxt = self.centerlines[best]
            if np.hypot(*(nxt[0] - pts[-1][-1])) < 1e-6:  # shared joint point: do not repeat it
                nxt = nxt[1:]
            pts.append(nxt)
            seg_lane.append(np.full(nxt.shape[0], best))  # each appended point closes one segment
            total += float(self.lane_lengths[best])
            current = best
            seen.add(best)
        polyline = Polyline(np.concatenate(pts))
        lanes = np.concatenate(seg_lane)
        result = LaneChain(polyline, lanes, dead_end, self._conflicts_along(polyline, lanes))
        self._chains[key] = result
        return result

    def _conflicts_along(self, polyline: Polyline, seg_lane: np.ndarray) -> np.ndarray:
        """Sorted arc lengths (m) along ``polyline`` of the road's conflict points within half a lane width of it."""
        points = self.conflict_points
        if points.shape[0] == 0:
            return np.zeros(0)
        s, d, seg = polyline.project_many(points)
        near = np.abs(d) <= 0.5 * self.widths[seg_lane[seg]]
        return np.sort(s[near])


@dataclass(frozen=True)
class LaneChain:
    """A lane chain of `RoadIndex.chain`.

    Attributes:
        polyline: the chained centre lines.
        seg_lane: ``[P-1]`` lane index of each segment of ``polyline``.
        dead_end: the chain ends at a lane without (unvisited) successors.
        conflict_s: sorted arc lengths (m) of the road's conflict points on the chain (crossings, merges, lane
            drops; `seal.scoring.conflict_points`).
    """

    polyline: Polyline
    seg_lane: np.ndarray
    dead_end: bool
    conflict_s: np.ndarray


def _polyline_length(pts: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def _start_direction(pts: np.ndarray) -> float:
    v = pts[1] - pts[0]
    return float(np.arctan2(v[1], v[0]))


def _end_direction(pts: np.ndarray) -> float:
    v = pts[-1] - pts[-2]
    return float(np.arctan2(v[1], v[0]))


class Polyline:
    """A polyline ``[P, 2]`` (m) with arc lengths and tangents precomputed, for Frenet <-> Cartesian."""

    def __init__(self, points: np.ndarray) -> None:
        self.points = np.asarray(points, dtype=np.float64)
        seg = np.diff(self.points, axis=0)
        self.seg_len = np.maximum(np.hypot(seg[:, 0], seg[:, 1]), 1e-12)
        self.tang = seg / self.seg_len[:, None]
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        # Vertex tangents: average of the adjacent segments' tangents (ends: the end segment's), so that an offset
        # path along a curve stays smooth instead of kinking at every vertex.
        vt = np.concatenate([self.tang[:1], self.tang[:-1] + self.tang[1:], self.tang[-1:]])
        self.vertex_tang = vt / np.maximum(np.hypot(vt[:, 0], vt[:, 1]), 1e-12)[:, None]

    @property
    def length(self) -> float:
        return float(self.cum[-1])

    def project(self, xy: np.ndarray) -> tuple[float, float, np.ndarray]:
        """Arc length ``s`` (m), signed lateral offset ``d`` (m, left positive) of point ``xy [2]`` and the unit
        tangent ``[2]`` of the closest segment."""
        a = self.points[:-1]
        rx, ry = xy[0] - a[:, 0], xy[1] - a[:, 1]
        t = np.clip((rx * self.tang[:, 0] + ry * self.tang[:, 1]) / self.seg_len, 0.0, 1.0)
        ex, ey = rx - t * self.seg_len * self.tang[:, 0], ry - t * self.seg_len * self.tang[:, 1]
        dist2 = ex * ex + ey * ey
        k = int(np.argmin(dist2))
        cross = self.tang[k, 0] * ry[k] - self.tang[k, 1] * rx[k]
        return float(self.cum[k] + t[k] * self.seg_len[k]), float(np.sign(cross) * np.sqrt(dist2[k])), self.tang[k]

    def project_many(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`project` for points ``xy [N, 2]``: arc lengths ``[N]`` (m), signed offsets ``[N]`` (m) and the index of
        the closest segment ``[N]``."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        a = self.points[:-1]
        rx, ry = xy[:, 0, None] - a[None, :, 0], xy[:, 1, None] - a[None, :, 1]  # [N, P-1]
        t = np.clip((rx * self.tang[:, 0] + ry * self.tang[:, 1]) / self.seg_len, 0.0, 1.0)
        ex, ey = rx - t * self.seg_len * self.tang[:, 0], ry - t * self.seg_len * self.tang[:, 1]
        k = np.argmin(ex * ex + ey * ey, axis=1)
        n = np.arange(xy.shape[0])
        cross = self.tang[k, 0] * ry[n, k] - self.tang[k, 1] * rx[n, k]
        dist = np.hypot(ex[n, k], ey[n, k])
        return self.cum[k] + t[n, k] * self.seg_len[k], np.sign(cross) * dist, k

    def at(self, s: np.ndarray, d: float) -> tuple[np.ndarray, np.ndarray]:
        """Points ``[K, 2]`` at arc lengths ``s [K]`` shifted ``d`` metres to the left, and their headings ``[K]``.

        Beyond the ends the first / last segment is extended as a straight line.
        """
        s = np.asarray(s, dtype=np.float64)
        cum = self.cum
        inside = np.clip(s, 0.0, cum[-1])
        x = np.interp(inside, cum, self.points[:, 0])
        y = np.interp(inside, cum, self.points[:, 1])
        tx = np.interp(inside, cum, self.vertex_tang[:, 0])
        ty = np.interp(inside, cum, self.vertex_tang[:, 1])
        over = s - inside
        outside = over != 0
        if outside.any():
            end_t = np.where((s > cum[-1])[:, None], self.tang[-1], self.tang[0])
            x = x + over * end_t[:, 0]
            y = y + over * end_t[:, 1]
            tx = np.where(outside, end_t[:, 0], tx)
            ty = np.where(outside, end_t[:, 1], ty)
        norm = np.maximum(np.hypot(tx, ty), 1e-12)
        tx, ty = tx / norm, ty / norm
        return np.stack([x - d * ty, y + d * tx], axis=1), np.arctan2(ty, tx)
