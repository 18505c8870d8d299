"""A route: the polyline a vehicle is asked to follow (the logged track of the ego, or of the adversary).

Arc length ``s`` (m) is measured from the first route point. For projection and navigation the polyline is
extended by `EXTENSION_M` straight metres before its start and after its end (so ``s`` may be negative or
beyond `length`); route completion only counts the original polyline.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from seal.core.kernels import closest_segment
from seal.core.scenario import CURRENT_STEP, VALID, VX, VY, X, Y

EXTENSION_M = 50.0
MIN_ROUTE_M = 1.0
"""Routes shorter than this (a logged agent that stands still) are extended along its heading."""
_DEDUP_M = 0.05
_WINDOW_BACK = 8
_WINDOW_AHEAD = 40


@dataclass(frozen=True, slots=True)
class RouteProjection:
    """Where a point lies relative to a route.

    Attributes:
        s: arc length of the closest route point (m).
        lateral: signed distance to the route (m), positive when the point is left of the route.
        heading: route tangent direction at ``s`` (rad).
        segment: index of the closest segment (pass it back as the next ``hint``).
    """

    s: float
    lateral: float
    heading: float
    segment: int


class Route:
    """A polyline route with per-vertex reference speeds.

    Args:
        points: ``[P, 2]`` route points in driving order (m).
        speeds: ``[P]`` reference speed at each point (m/s), e.g. the logged speed; default 0.
        start_index: index of the point where the episode starts (its ``s`` is `start_s`).
    """

    def __init__(self, points: np.ndarray, speeds: np.ndarray | None = None, start_index: int = 0) -> None:
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        spd = np.zeros(len(pts)) if speeds is None else np.asarray(speeds, dtype=np.float64).reshape(-1)
        if len(pts) == 0:
            raise ValueError("a route needs at least one point")
        # Drop repeated points (a stopped vehicle): zero-length segments have no direction.
        keep = np.ones(len(pts), dtype=bool)
        last = pts[0]
        for i in range(1, len(pts)):
            if math.hypot(pts[i, 0] - last[0], pts[i, 1] - last[1]) < _DEDUP_M:
                keep[i] = False
            else:
                last = pts[i]
        # The start point maps to the last kept point at or before it.
        start_index = int(np.clip(start_index, 0, len(pts) - 1))
        start_kept = int(np.count_nonzero(keep[: start_index + 1]) - 1)
        pts, spd = pts[keep], spd[keep]
        if len(pts) == 1:
            pts = np.vstack([pts, pts + [MIN_ROUTE_M, 0.0]])
            spd = np.concatenate([spd, spd])
        length = float(np.sum(np.hypot(*np.diff(pts, axis=0).T)))
        if length < MIN_ROUTE_M:
            d = pts[-1] - pts[0]
            d = d / max(np.hypot(*d), 1e-9)
            pts = np.vstack([pts, pts[-1] + d * (MIN_ROUTE_M - length)])
            spd = np.concatenate([spd, spd[-1:]])
        self.points = pts
        t0 = pts[1] - pts[0]
        t1 = pts[-1] - pts[-2]
        t0 /= np.hypot(*t0)
        t1 /= np.hypot(*t1)
        ext = np.vstack([pts[0] - EXTENSION_M * t0, pts, pts[-1] + EXTENSION_M * t1])
        seg = np.diff(ext, axis=0)
        seg_len = np.hypot(seg[:, 0], seg[:, 1])
        cum = np.concatenate([[0.0], np.cumsum(seg_len)]) - EXTENSION_M
        self._ext = ext
        self._cum = cum  # s of every extended vertex
        self._cum_list = cum.tolist()
        self._x_list, self._y_list = ext[:, 0].tolist(), ext[:, 1].tolist()
        self._spd = np.concatenate([spd[:1], spd, spd[-1:]])
        self._spd_list = self._spd.tolist()
        self.nav = np.ascontiguousarray(np.vstack([cum, ext[:, 0], ext[:, 1], self._spd]))
        """``[4, P]`` per extended vertex: arc length s (m), x, y (m), reference speed (m/s); what the compiled
        observation (`seal.envs.obs_kernels`) reads `point_at` / `speed_at` from."""
        # Segment starts and vectors as contiguous rows ``ax, ay, ex, ey`` [4, n] (one slice per projection) and
        # per-segment scalars as lists: `project` runs every step for the ego and a reactive adversary.
        self._cols = np.ascontiguousarray(np.vstack([ext[:-1].T, seg.T]))
        self._len2 = np.ascontiguousarray(seg_len**2)
        self._seg_s0 = cum[:-1].tolist()
        self._seg_len = seg_len.tolist()
        self._seg_heading = np.arctan2(seg[:, 1], seg[:, 0]).tolist()
        self.length = float(cum[-2])
        """Length of the route polyline without extensions (m)."""
        self.input_s = cum[np.cumsum(keep)]  # kept point j is extended vertex j + 1
        """``[len(points)]`` arc length (m) of every given point: that of the last kept point at or before it
        (repeated points, dropped above, sit within 5 cm of it); for a track's route, the logged schedule."""
        self.start_s = float(cum[start_kept + 1])
        """Arc length of the episode start point (m)."""
        self.start_segment = start_kept + 1

    @classmethod
    def from_track(cls, track: np.ndarray, start_step: int = CURRENT_STEP) -> Route:
        """Route through all valid steps of a ``[T, 8]`` track; the episode starts at ``start_step``."""
        valid = np.flatnonzero(track[:, VALID] > 0.5)
        pts = track[valid][:, [X, Y]]
        speeds = np.hypot(track[valid, VX], track[valid, VY])
        start_index = int(np.searchsorted(valid, start_step))
        return cls(pts, speeds, start_index=min(start_index, len(valid) - 1))

    @property
    def n_segments(self) -> int:
        return len(self._seg_len)

    def completion(self, s: float) -> float:
        """Share of the route from `start_s` to its end covered at arc length ``s`` (may be < 0 or > 1)."""
        return (s - self.start_s) / max(self.length - self.start_s, 1e-6)

    def project(self, x: float, y: float, hint: int | None = None) -> RouteProjection:
        """Closest route point to (x, y); with ``hint`` (a previous segment index) only nearby segments count,
        so routes that come back near themselves (loops, U-turns) do not make the projection jump."""
        n = len(self._seg_len)
        if hint is None:
            lo, hi = 0, n
        else:
            lo, hi = max(0, hint - _WINDOW_BACK), min(n, hint + _WINDOW_AHEAD)
        # Compiled (`seal.core.kernels.closest_segment`): a dozen numpy calls on a few dozen segments cost more
        # than the arithmetic.
        i, t, cross = closest_segment(self._cols, self._len2, x, y, lo, hi)
        seg_len = self._seg_len[i]
        return RouteProjection(
            s=self._seg_s0[i] + t * seg_len,
            lateral=cross / seg_len,
            heading=self._seg_heading[i],
            segment=i,
        )

    def point_at(self, s: float) -> tuple[float, float]:
        """Position at one arc length ``s`` (clamped to the extended route); pure Python, for per-step use."""
        cum = self._cum_list
        i = min(max(bisect.bisect_right(cum, s) - 1, 0), len(cum) - 2)
        u = min(1.0, max(0.0, (s - cum[i]) / (cum[i + 1] - cum[i])))
        xs, ys = self._x_list, self._y_list
        return xs[i] + u * (xs[i + 1] - xs[i]), ys[i] + u * (ys[i + 1] - ys[i])

    def speed_at(self, s: float) -> float:
        """Reference speed at arc length ``s`` (m/s), linear between route points."""
        cum = self._cum_list
        i = min(max(bisect.bisect_right(cum, s) - 1, 0), len(cum) - 2)
        u = min(1.0, max(0.0, (s - cum[i]) / (cum[i + 1] - cum[i])))
        return self._spd_list[i] + u * (self._spd_list[i + 1] - self._spd_list[i])
