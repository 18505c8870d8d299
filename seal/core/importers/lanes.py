"""Lanes of the `seal.core.road` model (centre polyline, constant width, line types, successors) from recorded maps.

A recorded lane is given by its left and right border polylines (CommonRoad lanelets) or by a centre line with
a width per point (ScenarioNet). `seal.core.road.LaneSpec` has one width per lane, so a lane whose width varies
(a tapering on-ramp, a widening exit) is cut along its length into pieces within which the width varies by at
most `WIDTH_TOLERANCE_M`; each piece gets the largest width it has, so the pieces cover the recorded lane and
adjacent lanes, which share a border, leave no gap between them (where they would, the drivable area would get
a hole and the road-edge sensors a phantom edge). Pieces are chained with ``successors``; the last piece
continues into the first pieces of the lane's successors.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import shapely

from seal.core.road import LaneSpec

WIDTH_TOLERANCE_M = 0.3
"""Largest width variation (m) within one lane piece; a border is then at most 0.15 m off the recorded one."""
DENSIFY_M = 2.0
"""Borders are resampled to points at most this far apart (m) before a lane is cut into pieces."""
MIN_WIDTH_M = 0.5
"""Pieces narrower than this (the pointed end of a taper) get this width (m)."""
MIN_PIECE_M = 2.0
"""Pieces shorter than this (m) are merged into a neighbour (highway-env's ``PolyLane`` needs at least 1 m)."""
MIN_LANE_M = 1.0
"""Recorded lanes shorter than this (m) are dropped (highway-env cannot represent them)."""
_DUP_M = 1e-6


@dataclass(frozen=True)
class LaneGeometry:
    """A recorded lane before conversion: ``centre`` ``[P, 2]`` (m, driving order) and ``width`` ``[P]`` (m)."""

    centre: np.ndarray
    width: np.ndarray


def _arc_param(pts: np.ndarray) -> np.ndarray:
    """Normalised arc length ``[P]`` in [0, 1] of a polyline (uniform when it has zero length)."""
    seg = np.hypot(*np.diff(pts, axis=0).T)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= 0.0:
        return np.linspace(0.0, 1.0, len(pts))
    return cum / cum[-1]


def _at(pts: np.ndarray, param: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(u, param, pts[:, 0]), np.interp(u, param, pts[:, 1])], axis=1)


def geometry_from_bounds(left: np.ndarray, right: np.ndarray) -> LaneGeometry:
    """Centre line and width of a lane between its ``left`` and ``right`` border polylines (``[P, 2]``, ``[Q, 2]``,
    both in driving order).

    Borders with different point counts are matched by normalised arc length (the union of both borders'
    vertices); segments longer than `DENSIFY_M` are subdivided so the width is known every 2 m.

    Raises:
        ValueError: when the left border lies to the right of the centre line (borders swapped or reversed).
    """
    left = np.asarray(left, dtype=np.float64)
    right = np.asarray(right, dtype=np.float64)
    if len(left) != len(right):
        pl, pr = _arc_param(left), _arc_param(right)
        u = np.unique(np.concatenate([pl, pr]))
        left, right = _at(left, pl, u), _at(right, pr, u)
    # Subdivide long segments (linear on both borders, so matched points stay matched).
    seg = np.maximum(np.hypot(*np.diff(left, axis=0).T), np.hypot(*np.diff(right, axis=0).T))
    n_sub = np.maximum(1, np.ceil(seg / DENSIFY_M).astype(np.int64))
    frac = np.concatenate([np.arange(n) / n + i for i, n in enumerate(n_sub)] + [np.array([len(seg)], float)])
    idx = np.arange(len(left), dtype=np.float64)
    left = np.stack([np.interp(frac, idx, left[:, 0]), np.interp(frac, idx, left[:, 1])], axis=1)
    right = np.stack([np.interp(frac, idx, right[:, 0]), np.interp(frac, idx, right[:, 1])], axis=1)
    centre = 0.5 * (left + right)
    width = np.hypot(*(left - right).T)
    keep = np.concatenate([[True], np.hypot(*np.diff(centre, axis=0).T) > _DUP_M])
    centre, width, left = centre[keep], width[keep], left[keep]
    if len(centre) >= 2:
        d = np.diff(centre, axis=0)
        d = np.vstack([d, d[-1:]])
        side = d[:, 0] * (left[:, 1] - centre[:, 1]) - d[:, 1] * (left[:, 0] - centre[:, 0])
        if np.median(side) < 0:
            raise ValueError("the left border lies to the right of the lane (borders swapped or reversed)")
    return LaneGeometry(centre, width)


def split_by_width(
    centre: np.ndarray, width: np.ndarray, tolerance_m: float = WIDTH_TOLERANCE_M, min_length_m: float = MIN_PIECE_M
) -> list[tuple[int, int]]:
    """Vertex ranges ``(a, b)`` (inclusive; consecutive pieces share a vertex) covering a lane with centre points
    ``[P, 2]`` and widths ``[P]`` such that ``max - min <= tolerance_m`` within each piece, except that pieces
    shorter than ``min_length_m`` are merged into a neighbour (highway-env lanes need some length)."""
    n = len(width)
    pieces: list[tuple[int, int]] = []
    a = 0
    while a < n - 1:
        # Extend the piece while the running width range stays within the tolerance (at least one segment).
        rest = width[a:]
        spread = np.maximum.accumulate(rest) - np.minimum.accumulate(rest)
        over = np.flatnonzero(spread > tolerance_m)
        b = a + max(1, int(over[0]) - 1) if over.size else n - 1
        pieces.append((a, b))
        a = b
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(centre, axis=0).T))])
    merged: list[tuple[int, int]] = []
    for a, b in pieces:
        if merged and (cum[b] - cum[a] < min_length_m or cum[merged[-1][1]] - cum[merged[-1][0]] < min_length_m):
            merged[-1] = (merged[-1][0], b)
        else:
            merged.append((a, b))
    return merged


def lane_pieces(
    lane_id: str,
    geometry: LaneGeometry,
    line_types: tuple[str, str],
    speed_limit_mps: float,
    tolerance_m: float = WIDTH_TOLERANCE_M,
) -> list[LaneSpec]:
    """`LaneSpec` pieces of one recorded lane (module docstring), chained in driving order; ids are ``lane_id``
    for a single piece, else ``lane_id#0``, ``lane_id#1``, ...; the last piece's successors are left empty
    (see `link_successors`). A lane shorter than `MIN_LANE_M` gives no piece."""
    centre, width = geometry.centre, geometry.width
    if len(centre) < 2:
        raise ValueError("the lane has fewer than two distinct centre points")
    if polyline_length_m(centre) < MIN_LANE_M:
        return []
    ranges = split_by_width(centre, width, tolerance_m)
    ids = [lane_id] if len(ranges) == 1 else [f"{lane_id}#{k}" for k in range(len(ranges))]
    out = []
    for k, (a, b) in enumerate(ranges):
        out.append(
            LaneSpec(
                lane_id=ids[k],
                centerline=centre[a : b + 1],
                width_m=max(MIN_WIDTH_M, float(np.max(width[a : b + 1]))),
                line_types=line_types,
                speed_limit_mps=speed_limit_mps,
                successors=(ids[k + 1],) if k + 1 < len(ids) else (),
            )
        )
    return out


def link_successors(pieces: dict[str, list[LaneSpec]], successors: Mapping[str, Sequence[str]]) -> list[LaneSpec]:
    """All pieces, with each lane's last piece continuing into the first piece of each of its successor lanes
    (successors not among ``pieces`` are dropped)."""
    out: list[LaneSpec] = []
    for lane_id, lane in pieces.items():
        nxt = tuple(pieces[s][0].lane_id for s in successors.get(lane_id, ()) if pieces.get(s) and s != lane_id)
        for k, p in enumerate(lane):
            if k == len(lane) - 1 and nxt:
                p = LaneSpec(p.lane_id, p.centerline, p.width_m, p.line_types, p.speed_limit_mps, nxt)
            out.append(p)
    return out


def sample_along(centre: np.ndarray, step_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step_m`` metres along a polyline ``[P, 2]`` (both ends included) and the unit left normals
    there: ``([K, 2], [K, 2])``."""
    seg = np.diff(centre, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    n = max(2, int(np.ceil(cum[-1] / step_m)) + 1)
    s = np.linspace(0.0, cum[-1], n)
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    u = np.where(seg_len[k] > 0, (s - cum[k]) / np.maximum(seg_len[k], 1e-12), 0.0)
    pts = centre[k] + u[:, None] * seg[k]
    tangent = seg[k] / np.maximum(seg_len[k], 1e-12)[:, None]
    return pts, np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)


def chunked_lines(
    polylines: Sequence[np.ndarray], points_per_chunk: int = 8
) -> tuple[list[shapely.LineString], np.ndarray]:
    """Short ``shapely.LineString`` pieces of polylines (consecutive pieces share a vertex) and the index of the
    polyline each comes from: spatial queries on many short pieces are much faster than on long lines."""
    coords, chunk_of, owner = [], [], []
    n_chunks = 0
    width = np.arange(points_per_chunk)
    for i, pts in enumerate(polylines):
        starts = np.arange(0, len(pts) - 1, points_per_chunk - 1)  # every chunk gets at least 2 points
        idx = starts[:, None] + width[None, :]
        keep = idx < len(pts)
        coords.append(np.asarray(pts, dtype=np.float64)[idx[keep]])
        chunk_of.append(n_chunks + np.repeat(np.arange(len(starts)), keep.sum(axis=1)))
        owner.append(np.full(len(starts), i, dtype=np.int64))
        n_chunks += len(starts)
    if n_chunks == 0:
        return [], np.zeros(0, dtype=np.int64)
    geoms = shapely.linestrings(np.concatenate(coords), indices=np.concatenate(chunk_of))
    return list(geoms), np.concatenate(owner)


def lane_of_piece(piece_id: str) -> str:
    """The recorded lane id of a piece id (inverse of the ``lane_id#k`` naming)."""
    return piece_id.split("#", 1)[0]


def polyline_length_m(pts: np.ndarray) -> float:
    return float(np.sum(np.hypot(*np.diff(np.asarray(pts, dtype=np.float64), axis=0).T))) if len(pts) > 1 else 0.0
