"""Inputs of the RAPID background model (paper 004, sections 3.2-3.3), computed with numpy for all agents at once.

Agent-centric and translation-invariant (3.2): every relative quantity (velocity, neighbours, destination, the
local map read-out) is expressed in the agent's frame (x forward, y left); the absolute position enters only
through a Fourier encoding relative to the road's centre (`MapGeometry.origin_xy`), which also anchors the map
tokens, so moving the whole scene moves nothing the model sees but the encoding it learns to read.

Absent inputs carry a mask (the model swaps in a learned "missing" embedding, 3.2): the previous acceleration
of an agent that has just entered, the intent inputs a user has not set, no leader ahead, no neighbours.

Map (3.3): `MapGeometry` holds, per road, the lane centre segments and road-edge segments (the local read-out:
offset and heading to the nearest lane centre at the agent and 15 m ahead, the nearest edge point; compiled:
`seal.models.rapid.input_kernels.own_inputs`) and the map
tokens (points along the lane centres every few metres: Fourier position, direction, lane width) that the
network compresses once per scenario into its global latents (`seal.models.rapid.network.MapEncoder`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from seal.core.road import RoadDescription
from seal.envs.car_following import (
    CONTACT_HORIZON_S,
    CONTACT_MARGIN_M,
    COS_SAME_DIRECTION,
    LEADER_RANGE_M,
    PATH_MARGIN_M,
)
from seal.envs.road_geometry import get_road_geometry
from seal.models.rapid.input_kernels import closest_points_grid, own_inputs, segment_grid
from seal.models.rapid.kernels import neighbor_features, pair_scan

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
        one compiled call through the grid (`seal.models.rapid.input_kernels.closest_points_grid`: the segments near
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
    computed here when not given); `agent_input_tables` as named fields (views of its tables).

    Args:
        prev_vel: ``[n, 2]`` map-frame velocity of each agent one step before (m/s), read where ``prev_ok [n]``.
        desired_speed: ``[n]`` desired speed (m/s), NaN = not set; destination: ``[n, 2]`` (m), NaN = not set.
    """
    t = agent_input_tables(geo, cur, rows, prev_vel, prev_ok, desired_speed, destination, scan)
    return AgentInputs(t.own, t.opt[:, 0:2], t.masks[:, 0], t.opt[:, 2:3], t.masks[:, 1], t.opt[:, 3:6],
                       t.masks[:, 2], t.opt[:, 6:8], t.masks[:, 3], t.neighbors, t.neighbor_mask)


@dataclass(frozen=True)
class InputTables:
    """The `AgentInputs` of ``n`` agents as the few float32 tables the per-step network path reads
    (`seal.models.rapid.fast.FastAgentEncoder.tables`), and the nearest road-edge points.

    Attributes:
        own: ``[n, OWN_DIM]`` (`AgentInputs.own`).
        opt: ``[n, 8]`` previous acceleration, desired speed, destination, leader (`AgentInputs` fields, zero
            where absent); masks: ``[n, 4]`` their masks in that order (1 = present).
        neighbors, neighbor_mask: `AgentInputs` fields.
        edge_xy: ``[n, 2]`` float64: the nearest road-edge point of each agent (map frame, m), for `map_force`.
    """

    own: np.ndarray
    opt: np.ndarray
    masks: np.ndarray
    neighbors: np.ndarray
    neighbor_mask: np.ndarray
    edge_xy: np.ndarray


def agent_input_tables(
    geo: MapGeometry, cur: np.ndarray, rows: np.ndarray, prev_vel: np.ndarray, prev_ok: np.ndarray,
    desired_speed: np.ndarray, destination: np.ndarray, scan: PairScan | None = None,
) -> InputTables:
    """`InputTables` of the agents ``rows`` (arguments: `agent_inputs`): two compiled calls
    (`seal.models.rapid.input_kernels.own_inputs`, `seal.models.rapid.kernels.neighbor_features`); their numpy
    form is ``rapid_agent_inputs`` in ``tests/kernel_reference.py``."""
    cur = np.ascontiguousarray(cur, dtype=np.float64)
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    if scan is None:
        scan = scan_pairs(cur, rows)
    c, e = geo.centres, geo.edges
    own, opt, masks, edge = own_inputs(
        cur, rows, geo.origin_xy, FREQS, c.cols, c.len2, *c.grid, e.cols, e.len2, *e.grid, GRID_CELL_M,
        np.ascontiguousarray(prev_vel, dtype=np.float64), np.ascontiguousarray(prev_ok, dtype=np.bool_),
        np.ascontiguousarray(desired_speed, dtype=np.float64), np.ascontiguousarray(destination, dtype=np.float64),
        np.ascontiguousarray(scan.leader_gap), np.ascontiguousarray(scan.leader_v))
    neighbors, neighbor_mask = neighbor_features(cur, rows, scan.neighbor_rows)
    return InputTables(own, opt, masks, neighbors, neighbor_mask, edge)
