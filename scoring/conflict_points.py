"""Lane conflict points of a road: where the paths of different lanes meet (used by mTTCP_map).

SafeShift's map conflict points are crosswalks, stop signs, traffic lights and lane-centreline intersections
(WOMD). Our roads have only lanes, so a conflict point is:

* a crossing of the centre lines of two lanes that are not the same lane or directly connected (intersections),
  except where both lanes just start together (a diverge is not a conflict);
* a merge: the start point of a lane that several lanes continue into (roundabout entries, intersection exits);
* a lane drop: the end point of a lane without successors beside a lane that continues (on-ramp merges).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from seal.core.geometry import wrap_angle


class RoadIndex(Protocol):
    """The lane geometry the conflict points are computed from (`seal.scoring.frenet.RoadIndex` provides it; a
    protocol keeps this module below the Frenet index in the import graph)."""

    @property
    def n_lanes(self) -> int:
        """Number of lanes."""
        ...

    centerlines: list[np.ndarray]
    """Per lane ``[P, 2]`` centre-line points (m)."""
    widths: np.ndarray
    """``[L]`` lane widths (m)."""
    successors: list[list[int]]
    """Per lane the indices of the lanes it continues into."""
    connected: np.ndarray
    """``[L, L]`` bool: lanes connected by a successor / predecessor link (their crossings are no conflicts)."""
    seg_a: np.ndarray
    """``[S, 2]`` start point of every centre-line segment (m)."""
    seg_d: np.ndarray
    """``[S, 2]`` segment vector (m)."""
    seg_lane: np.ndarray
    """``[S]`` lane index of every segment."""
    seg_heading: np.ndarray
    """``[S]`` segment heading (rad)."""

_DEDUP_M = 1.0  # conflict points closer than this are the same point
_SHARED_START_M = 0.5
_LANE_DROP_WIDTHS = 1.5


def lane_conflict_points(index: RoadIndex) -> np.ndarray:
    """``[C, 2]`` conflict points (m) of the road behind ``index`` (may be empty)."""
    points = [_crossings(index), _merges(index), _lane_drops(index)]
    pts = np.concatenate([p for p in points if p.size] or [np.zeros((0, 2))])
    return _dedup(pts)


def _crossings(index: RoadIndex) -> np.ndarray:
    a, d, lane = index.seg_a, index.seg_d, index.seg_lane
    # Candidate segment pairs from different, unconnected lanes (upper triangle only).
    ii, jj = np.triu_indices(a.shape[0], k=1)
    keep = ~index.connected[lane[ii], lane[jj]]
    ii, jj = ii[keep], jj[keep]
    if ii.size == 0:
        return np.zeros((0, 2))
    p, r = a[ii], d[ii]
    q, s = a[jj], d[jj]
    denom = r[:, 0] * s[:, 1] - r[:, 1] * s[:, 0]
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[:, 0] * s[:, 1] - qp[:, 1] * s[:, 0]) / denom
        u = (qp[:, 0] * r[:, 1] - qp[:, 1] * r[:, 0]) / denom
    hit = (np.abs(denom) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    pts = p[hit] + t[hit, None] * r[hit]
    li, lj = lane[ii][hit], lane[jj][hit]
    starts = np.array([c[0] for c in index.centerlines])
    near_start_i = np.linalg.norm(pts - starts[li], axis=1) < _SHARED_START_M
    near_start_j = np.linalg.norm(pts - starts[lj], axis=1) < _SHARED_START_M
    return pts[~(near_start_i & near_start_j)]


def _merges(index: RoadIndex) -> np.ndarray:
    n_pred = np.zeros(index.n_lanes, dtype=int)
    for succ in index.successors:
        for b in succ:
            n_pred[b] += 1
    return np.array([index.centerlines[k][0] for k in np.flatnonzero(n_pred >= 2)]).reshape(-1, 2)


def _lane_drops(index: RoadIndex) -> np.ndarray:
    out = []
    for k, succ in enumerate(index.successors):
        if succ:
            continue
        end = index.centerlines[k][-1]
        end_dir = index.centerlines[k][-1] - index.centerlines[k][-2]
        # Only neighbours driving the same way (an oncoming lane beside a map exit is no merge).
        same_way = np.abs(wrap_angle(index.seg_heading - np.arctan2(end_dir[1], end_dir[0]))) < np.pi / 3
        others = (index.seg_lane != k) & same_way
        if not others.any():
            continue
        a, d = index.seg_a[others], index.seg_d[others]
        t = np.clip(((end - a) * d).sum(1) / np.maximum((d**2).sum(1), 1e-12), 0.0, 1.0)
        dist = np.linalg.norm(end - (a + t[:, None] * d), axis=1)
        close = dist <= _LANE_DROP_WIDTHS * index.widths[k]
        for lane_b in np.unique(index.seg_lane[others][close]):
            # The neighbour must carry on past this point: it has successors or this point is not its end.
            b_end = index.centerlines[lane_b][-1]
            if index.successors[lane_b] or np.linalg.norm(b_end - end) > _LANE_DROP_WIDTHS * index.widths[k]:
                out.append(end)
                break
    return np.array(out).reshape(-1, 2)


def _dedup(pts: np.ndarray) -> np.ndarray:
    if pts.shape[0] == 0:
        return pts.reshape(0, 2)
    keep: list[np.ndarray] = []
    for p in pts[np.lexsort((pts[:, 1], pts[:, 0]))]:
        if not keep or np.min(np.linalg.norm(np.asarray(keep) - p, axis=1)) >= _DEDUP_M:
            keep.append(p)
    return np.asarray(keep)
