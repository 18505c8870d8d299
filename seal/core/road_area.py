"""The drivable area of a `seal.core.road.RoadDescription`: lane borders and the union of the lane polygons.

Shared by the simulator's road checks (`seal.envs.road_geometry`) and the importers, which drop windows whose
logged ego leaves the mapped road, so both judge "on the road" with one geometry.
"""

from __future__ import annotations

import numpy as np
import shapely

from seal.core.road import RoadDescription

UNION_PAD_M = 0.05
"""Lane polygons are grown by this much before the union so float gaps between adjacent lanes close."""
OFFROAD_TOLERANCE_M = 0.5
"""How far (m) a box corner may leave the drivable area before the box counts as off the road (the simulator's
default ``offroad_tolerance_m``: where consecutive lanes meet at an angle their polygons leave small notches)."""


def offset_polyline(pts: np.ndarray, offset: float) -> np.ndarray:
    """Polyline ``[P, 2]`` shifted by ``offset`` metres to its left (negative: right), mitred at vertices."""
    seg = np.diff(pts, axis=0)
    seg_len = np.maximum(np.hypot(seg[:, 0], seg[:, 1]), 1e-12)
    normals = np.stack([-seg[:, 1], seg[:, 0]], axis=1) / seg_len[:, None]  # left normals [P-1, 2]
    vn = np.vstack([normals[:1], normals[:-1] + normals[1:], normals[-1:]])
    vn /= np.maximum(np.hypot(vn[:, 0], vn[:, 1]), 1e-12)[:, None]
    # Mitre: scale by 1 / cos(half turn angle), capped so sharp corners do not spike.
    cos_half = np.ones(len(pts))
    cos_half[1:-1] = np.einsum("ij,ij->i", vn[1:-1], normals[1:])
    return pts + vn * (offset / np.clip(cos_half, 0.5, None))[:, None]


def lane_borders(road: RoadDescription) -> tuple[list[np.ndarray], list[np.ndarray], list[shapely.Geometry]]:
    """(left borders, right borders, lane polygons) of every lane: polylines ``[P, 2]`` in metres at
    ``+-width/2`` from the centre line, and the (made valid) polygon between them."""
    lefts, rights, polys = [], [], []
    for lane in road.lanes:
        c = lane.centerline
        left = offset_polyline(c, lane.width_m / 2)
        right = offset_polyline(c, -lane.width_m / 2)
        lefts.append(left)
        rights.append(right)
        polys.append(shapely.make_valid(shapely.Polygon(np.vstack([left, right[::-1]]))))
    return lefts, rights, polys


def drivable_area(polys: list[shapely.Geometry]) -> shapely.Geometry:
    """Union of lane polygons (from `lane_borders`), each grown by `UNION_PAD_M`; prepared for point tests."""
    area = shapely.union_all([shapely.buffer(p, UNION_PAD_M, join_style="mitre") for p in polys])
    shapely.prepare(area)
    return area
