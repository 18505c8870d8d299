"""Inputs of the RAPID background model (paper 004, sections 3.2-3.3), computed with numpy for all agents at once.

Agent-centric and translation-invariant (3.2): every relative quantity (velocity, neighbours, destination, the
local map read-out) is expressed in the agent's frame (x forward, y left); the absolute position enters only
through a Fourier encoding relative to the road's centre (`MapGeometry.origin_xy`), which also anchors the map
tokens, so moving the whole scene moves nothing the model sees but the encoding it learns to read.

Absent inputs carry a mask (the model swaps in a learned "missing" embedding, 3.2): the previous acceleration
of an agent that has just entered, the intent inputs a user has not set, no leader ahead, no neighbours.

Map (3.3): `MapGeometry` holds, per road, the lane centre segments and road-edge segments (the local read-out:
offset and heading to the nearest lane centre at the agent and 15 m ahead, the nearest edge point) and the map
tokens (points along the lane centres every few metres: Fourier position, direction, lane width) that the
network compresses once per scenario into its global latents (`seal.models.rapid.network.MapEncoder`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from seal.core.road import RoadDescription
from seal.core.scenario import DT_S, HEADING, VX, VY, X, Y
from seal.envs.car_following import (
    CONTACT_HORIZON_S,
    CONTACT_MARGIN_M,
    COS_SAME_DIRECTION,
    LEADER_RANGE_M,
    PATH_MARGIN_M,
)
from seal.envs.road_geometry import get_road_geometry
from seal.models.rapid.kernels import closest_points_grid, neighbor_features, pair_scan, segment_grid

N_FREQ = 8
"""Fourier frequencies per axis, linearly spaced from 2 pi / 1 km to 2 pi / 0.5 m (paper 3.2)."""
FREQS = np.linspace(2 * math.pi * 1e-3, 2 * math.pi * 2.0, N_FREQ)
N_NEIGHBORS = 8
"""Nearest agents each agent sees (within `NEIGHBOR_RANGE_M`)."""
NEIGHBOR_RANGE_M = 60.0
MAX_TOKENS = 256
"""Map tokens per road at most (the spacing grows on long roads)."""
ACC_SCALE_MPS2 = 3.0
"""Accelerations are divided by this in the model (its outputs are multiplied back)."""
OWN_DIM = 5 + 4 * N_FREQ + 8
NEIGHBOR_DIM = 8
POS_DIM = 4 * N_FREQ


def fourier(xy: np.ndarray) -> np.ndarray:
    """``[n, 4 N_FREQ]`` sin / cos of each frequency times x and y (m)."""
    ang = xy[:, :, None] * FREQS[None, None, :]
    return np.concatenate([np.sin(ang).reshape(len(xy), -1), np.cos(ang).reshape(len(xy), -1)], axis=1)


GRID_CELL_M = 10.0
"""Cell size (m) of the segment grid `Segments.nearest` searches."""


@dataclass(frozen=True)
class Segments:
    """Polyline segments as arrays: starts ``a [S, 2]``, vectors ``e [S, 2]`` (m), squared lengths ``[S]``, the
    ``[4, S]`` rows (a x, a y, e x, e y) the compiled kernels read and their `segment_grid` (``grid``: meta,
    start, items), built once per road."""

    a: np.ndarray
    e: np.ndarray
    len2: np.ndarray
    cols: np.ndarray
    grid: tuple[np.ndarray, np.ndarray, np.ndarray]

    @classmethod
    def of(cls, polylines: list[np.ndarray]) -> Segments:
        starts = [np.asarray(p, dtype=np.float64)[:-1, :2] for p in polylines if len(p) > 1]
        ends = [np.asarray(p, dtype=np.float64)[1:, :2] for p in polylines if len(p) > 1]
        a = np.concatenate(starts) if starts else np.zeros((0, 2))
        e = (np.concatenate(ends) if ends else np.zeros((0, 2))) - a
        len2 = (e**2).sum(axis=1)
        keep = len2 > 1e-6
        a, e, len2 = a[keep], e[keep], np.ascontiguousarray(len2[keep])
        cols = np.ascontiguousarray(np.vstack([a.T, e.T]))
        return cls(a, e, len2, cols, segment_grid(cols, GRID_CELL_M))

    def nearest(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For points ``p [n, 2]``: (closest point on any segment ``[n, 2]``, that segment's direction (unit));
        one compiled call through the grid (`seal.models.rapid.kernels.closest_points_grid`: the segments near
        each point only, the answer of the brute-force `closest_points`)."""
        pts = np.ascontiguousarray(p, dtype=np.float64)
        q, ks = closest_points_grid(self.cols, self.len2, pts, *self.grid, GRID_CELL_M)
        return q, self.e[ks] / np.sqrt(self.len2[ks])[:, None]


@dataclass(frozen=True)
class MapGeometry:
    """The per-road map inputs (module docstring); built once per road by `build_map_geometry`.

    Attributes:
        origin_xy: ``[2]`` centre of the road's bounding box (m), the origin of every Fourier encoding.
        centres: lane centre segments; edges: road-edge segments (painted continuous lines and the drivable
            area's boundary).
        tokens: ``[M, 4 N_FREQ + 3]`` map tokens (Fourier position, direction cos / sin, lane width / 4 m).
    """

    origin_xy: np.ndarray
    centres: Segments
    edges: Segments
    tokens: np.ndarray


def build_map_geometry(road: RoadDescription) -> MapGeometry:
    """`MapGeometry` of ``road`` (tokens every max(4 m, total lane length / `MAX_TOKENS`))."""
    lines = [np.asarray(lane.centerline, dtype=np.float64) for lane in road.lanes]
    pts = np.concatenate(lines)
    origin = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    geom = get_road_geometry(road)
    centres = Segments.of(lines)
    edges = Segments.of(list(geom.continuous_polylines) + list(geom.boundary_polylines))
    total = float(np.sqrt(centres.len2).sum())
    spacing = max(4.0, total / MAX_TOKENS)
    rows = []
    for lane, line in zip(road.lanes, lines, strict=True):
        seg = np.diff(line, axis=0)
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        s = np.arange(0.0, cum[-1], spacing)
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        frac = (s - cum[k]) / np.maximum(cum[k + 1] - cum[k], 1e-9)
        xy = line[k] + frac[:, None] * seg[k]
        ang = np.arctan2(seg[k, 1], seg[k, 0])
        width = np.full(len(s), lane.width_m / 4)
        rows.append(np.column_stack([fourier(xy - origin), np.cos(ang), np.sin(ang), width]))
    tokens = np.concatenate(rows)[:MAX_TOKENS].astype(np.float32)
    return MapGeometry(origin, centres, edges, tokens)


def _to_frame(vec: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Map-frame vectors ``[n, 2]`` in the frames of heading cos ``c`` / sin ``s`` ``[n]``."""
    return np.column_stack([c * vec[:, 0] + s * vec[:, 1], -s * vec[:, 0] + c * vec[:, 1]])


def local_map(geo: MapGeometry, xy: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``[n, 8]`` local read-out: at the agent and 15 m ahead, the nearest lane centre's offset (agent frame
    y, /4 m) and direction (cos, sin in the agent frame); the nearest edge point (agent frame, /10 m)."""
    out = []
    for ahead in (0.0, 15.0):
        p = xy + ahead * np.column_stack([c, s])
        q, d = geo.centres.nearest(p)
        rel = _to_frame(q - xy, c, s)
        out += [rel[:, 1:2] / 4.0, _to_frame(d, c, s)]
    q, _ = geo.edges.nearest(xy) if len(geo.edges.a) else (xy + 50.0, None)
    out.append(_to_frame(q - xy, c, s) / 10.0)
    return np.concatenate(out, axis=1)


@dataclass
class AgentInputs:
    """Model inputs of ``n`` agents at one step (float32; masks 1 = present, 0 = use the missing embedding).

    Attributes:
        own: ``[n, OWN_DIM]`` speed, agent-frame velocity, heading cos / sin, Fourier position, local map.
        prev_acc: ``[n, 2]`` last step's acceleration (agent frame, / `ACC_SCALE_MPS2`); ``prev_mask [n]``.
        speed_cmd: ``[n, 1]`` desired speed (/ 20 m/s) relative to the current one; ``speed_mask [n]``.
        dest: ``[n, 3]`` destination in the agent frame (/ 100 m) and its log distance; ``dest_mask [n]``.
        leader: ``[n, 2]`` gap to the box ahead (/ 50 m) and closing speed (/ 10 m/s); ``leader_mask [n]``.
        neighbors: ``[n, N_NEIGHBORS, NEIGHBOR_DIM]``; ``neighbor_mask [n, N_NEIGHBORS]``.
    """

    own: np.ndarray
    prev_acc: np.ndarray
    prev_mask: np.ndarray
    speed_cmd: np.ndarray
    speed_mask: np.ndarray
    dest: np.ndarray
    dest_mask: np.ndarray
    leader: np.ndarray
    leader_mask: np.ndarray
    neighbors: np.ndarray
    neighbor_mask: np.ndarray


@dataclass(frozen=True)
class PairScan:
    """The pairwise quantities of one step (`seal.models.rapid.kernels.pair_scan`), for ``n`` agents.

    Attributes:
        leader_gap, leader_v: ``[n]`` `seal.envs.car_following.leader_gaps` (m, inf: none; m/s).
        obstacle_gap, obstacle_v: ``[n]`` `seal.envs.car_following.obstacle_gaps` (m, inf: none; m/s).
        social: ``[n, 2]`` eq. 9 social force in the map frame (m/s^2) for the constants scanned with.
        neighbor_rows: ``[n, N_NEIGHBORS]`` the nearest agents within `NEIGHBOR_RANGE_M`, nearest first (-1:
            none); neighbor_dist: their centre distances (m, inf: none).
    """

    leader_gap: np.ndarray
    leader_v: np.ndarray
    obstacle_gap: np.ndarray
    obstacle_v: np.ndarray
    social: np.ndarray
    neighbor_rows: np.ndarray
    neighbor_dist: np.ndarray


def scan_pairs(cur: np.ndarray, rows: np.ndarray, logged: np.ndarray | None = None,
               social: tuple[float, float, float, float] = (6.0, 2.0, 0.0, 0.1), route: np.ndarray | None = None,
               t: int = 0) -> PairScan:
    """`PairScan` of the agents ``rows`` of the box table ``cur [A, 8]`` in one compiled call; ``logged``: the
    logged boxes of the step (`obstacle_gaps`); ``social``: strength (m/s^2), range (m), headway (s) and weight
    behind of the social force; ``route``: the logged tracks ``[A, T, 8]`` and ``t`` the step: the obstacles are
    then `seal.envs.car_following.safety_obstacles` (route test, priority between two simulated agents)."""
    cur = np.ascontiguousarray(cur, dtype=np.float64)
    log = np.zeros_like(cur) if logged is None else np.ascontiguousarray(logged, dtype=np.float64)
    params = np.array([LEADER_RANGE_M, PATH_MARGIN_M, CONTACT_HORIZON_S, CONTACT_MARGIN_M, *social,
                       NEIGHBOR_RANGE_M, COS_SAME_DIRECTION, 0.0])
    if route is None:
        route = np.zeros((len(cur), 0, 8))
    out, nb, nbd = pair_scan(cur, np.ascontiguousarray(rows, dtype=np.int64), log, params, N_NEIGHBORS,
                             np.ascontiguousarray(route, dtype=np.float64), int(t))
    return PairScan(out[:, 0], out[:, 1], out[:, 2], out[:, 3], out[:, 4:6], nb, nbd)


def agent_inputs(
    geo: MapGeometry, cur: np.ndarray, rows: np.ndarray, prev_vel: np.ndarray, prev_ok: np.ndarray,
    desired_speed: np.ndarray, destination: np.ndarray, scan: PairScan | None = None,
) -> AgentInputs:
    """`AgentInputs` of the agents ``rows`` of the box table ``cur [A, 8]`` (``scan``: their `scan_pairs`,
    computed here when not given).

    Args:
        prev_vel: ``[n, 2]`` map-frame velocity of each agent one step before (m/s), read where ``prev_ok [n]``.
        desired_speed: ``[n]`` desired speed (m/s), NaN = not set; destination: ``[n, 2]`` (m), NaN = not set.
    """
    me = cur[rows]
    c, s = np.cos(me[:, HEADING]), np.sin(me[:, HEADING])
    vel = me[:, [VX, VY]]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    v_local = _to_frame(vel, c, s)
    own = np.column_stack([speed / 20.0, v_local / 20.0, c, s, fourier(me[:, [X, Y]] - geo.origin_xy),
                           local_map(geo, me[:, [X, Y]], c, s)])
    prev_acc = _to_frame((vel - prev_vel) / DT_S, c, s) / ACC_SCALE_MPS2
    prev_mask = prev_ok.astype(np.float32)
    speed_mask = np.isfinite(desired_speed)
    speed_cmd = np.where(speed_mask, (np.nan_to_num(desired_speed) - speed) / 20.0, 0.0)[:, None]
    dest_mask = np.isfinite(destination).all(axis=1)
    rel = _to_frame(np.nan_to_num(destination) - me[:, [X, Y]], c, s)
    dist = np.hypot(rel[:, 0], rel[:, 1])
    dest = np.column_stack([rel / 100.0, np.log1p(dist) / 5.0])
    dest[~dest_mask] = 0.0
    if scan is None:
        scan = scan_pairs(cur, rows)
    gap, lead_v = scan.leader_gap, scan.leader_v
    leader_mask = np.isfinite(gap)
    closing = np.where(leader_mask, speed - lead_v, 0.0)
    leader = np.column_stack([np.where(leader_mask, gap, 0.0) / 50.0, closing / 10.0])
    neighbors, neighbor_mask = neighbor_features(np.ascontiguousarray(cur, dtype=np.float64),
                                                 np.ascontiguousarray(rows, dtype=np.int64), scan.neighbor_rows)
    f32 = np.float32
    return AgentInputs(
        own.astype(f32), np.where(prev_ok[:, None], prev_acc, 0.0).astype(f32), prev_mask,
        speed_cmd.astype(f32), speed_mask.astype(f32), dest.astype(f32), dest_mask.astype(f32),
        leader.astype(f32), leader_mask.astype(f32), neighbors, neighbor_mask,
    )
