"""Pure-numpy references of the compiled hot-loop kernels (issue 23): the observation's ray casts, box lidar and
nearest vehicles (`seal.envs.obs_kernels`), the env's box collision test and the route projection
(`seal.core.kernels`), the lane lookup of the prior's road projection (`seal.models.prior.road_projection`). These
are the float64 numpy code paths the kernels replaced, kept here (and only here) as the reference the kernels are
tested against.
"""

from __future__ import annotations

import math

import numpy as np

from seal.core.geometry import overlaps_one
from seal.core.road import RoadDescription
from seal.envs import observation as ob
from seal.envs.kinematics import MAX_SPEED_MPS, AgentState
from seal.envs.road_geometry import RoadGeometry
from seal.envs.route import Route, RouteProjection
from seal.models.prior.lanes import open_map_edges

_RAY_COS = np.concatenate([np.cos(ob._EDGE_ANG), np.cos(ob._LINE_ANG)])[:, None]  # [42, 1]
_RAY_SIN_SIGNED = np.array([-1.0, 1.0])[:, None, None] * np.concatenate(
    [np.sin(ob._EDGE_ANG), np.sin(ob._LINE_ANG)])[:, None]  # [2, 42, 1]: -sin, +sin


def _hit_distances(
    dx: np.ndarray, dy: np.ndarray, ax: np.ndarray, ay: np.ndarray, ex: np.ndarray, ey: np.ndarray, max_range: float,
) -> np.ndarray:
    """Distance along each ray ``[K, 1]`` to each segment ``[M]`` it hits, ``max_range`` where it misses."""
    inv = dx * ey
    inv -= dy * ex
    np.reciprocal(inv, out=inv)
    t = ax * ey
    t -= ay * ex
    t = t * inv
    u = dy * ax
    u -= dx * ay
    u *= inv
    hit = t >= 0.0
    hit &= u >= 0.0
    hit &= u <= 1.0
    return np.where(hit, t, max_range)


def _box_lidar(
    dx: np.ndarray, dy: np.ndarray, rx: np.ndarray, ry: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray,
    half_length: np.ndarray, half_width: np.ndarray, max_range: float,
) -> np.ndarray:
    """Distance ``[K]`` along rays ``[K, 1]`` to the first of ``n`` oriented boxes (slab test), ``max_range`` when
    none is hit; ``rx, ry``: ``[n]`` box centres relative to the viewer (m)."""
    px = -(rx * cos_h + ry * sin_h)
    py = rx * sin_h - ry * cos_h
    inv_x = 1.0 / (dx * cos_h + dy * sin_h)
    inv_y = 1.0 / (dy * cos_h - dx * sin_h)
    a = (-half_length - px) * inv_x
    b = (half_length - px) * inv_x
    c = (-half_width - py) * inv_y
    d = (half_width - py) * inv_y
    enter = np.maximum(np.minimum(a, b), np.minimum(c, d))
    leave = np.minimum(np.maximum(a, b), np.maximum(c, d))
    hit = (enter <= leave) & (leave >= 0.0)
    return np.where(hit, np.where(enter >= 0.0, enter, leave), max_range).min(axis=-1)


def cast_rays(
    dx: np.ndarray, dy: np.ndarray, ax: np.ndarray, ay: np.ndarray, ex: np.ndarray, ey: np.ndarray,
    max_range: float,
) -> np.ndarray:
    """Distance (m) along each ray ``[K]`` (unit directions) to the first of the segments ``[M]`` (starts relative to
    the ray origin ``ax, ay``, vectors ``ex, ey``) hit, ``max_range`` when none within it (the numpy ray caster)."""
    if ax.shape[0] == 0:
        return np.full(dx.shape[0], max_range)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / (np.multiply.outer(dx, ey) - np.multiply.outer(dy, ex))  # [K, M]
        t = (ax * ey - ay * ex) * inv
        u = (np.multiply.outer(dy, ax) - np.multiply.outer(dx, ay)) * inv
    hit = (t >= 0.0) & (u >= 0.0) & (u <= 1.0)
    return np.minimum(np.where(hit, t, max_range).min(axis=1), max_range)


def reference_observation(
    geom: RoadGeometry, state: AgentState, route: Route, projection: RouteProjection, boxes: np.ndarray,
    self_row: int = -1,
) -> np.ndarray:
    """The observation ``[OBS_DIM]`` float32 of one viewer as the numpy builder computed it, ray casts against every
    road segment (the builder's grid only leaves out segments beyond ray range). ``boxes [N, >=7]``: vehicles in
    track layout; ``self_row``: the viewer's own row in it, or -1."""
    obs = np.empty(ob.OBS_DIM, dtype=np.float32)
    x, y, h = state.x, state.y, state.heading
    c, s = math.cos(h), math.sin(h)
    cos_sin = np.array((c, s))[:, None, None]  # [2, 1, 1]
    dx, dy = cos_sin * _RAY_COS + cos_sin[::-1] * _RAY_SIN_SIGNED  # [42, 1] each
    dx30, dy30, dx12, dy12 = dx[:30], dy[:30], dx[30:], dy[30:]
    with np.errstate(divide="ignore", invalid="ignore"):
        for seg, ddx, ddy, rng_m, sl in ((geom.edges.segments, dx30, dy30, ob.EDGE_RANGE_M, ob.EDGE_RAYS),
                                         (geom.lines.segments, dx12, dy12, ob.LINE_RANGE_M, ob.LINE_RAYS)):
            if seg.size:
                obs[sl] = _hit_distances(ddx, ddy, seg.ax - x, seg.ay - y, seg.ex, seg.ey, rng_m).min(-1) / rng_m
            else:
                obs[sl] = 1.0
        herr = (projection.heading - h + math.pi) % (2 * math.pi) - math.pi
        p1x, p1y = route.point_at(projection.s + ob.CHECKPOINT_SPACING_M)
        p2x, p2y = route.point_at(projection.s + 2 * ob.CHECKPOINT_SPACING_M)
        p1x, p1y, p2x, p2y = p1x - x, p1y - y, p2x - x, p2y - y
        obs[ob.HEADING_ERROR : ob.LINE_RAYS.start] = (
            herr / math.pi, state.speed / MAX_SPEED_MPS, state.steering, state.steering, state.accel,
            state.yaw_rate / ob.YAW_RATE_SCALE,
        )
        obs[ob.LATERAL : ob.LIDAR.start] = (
            projection.lateral / ob.LATERAL_SCALE_M,
            (p1x * c + p1y * s) / ob.NAV_SCALE_M, (p1y * c - p1x * s) / ob.NAV_SCALE_M,
            (p2x * c + p2y * s) / ob.NAV_SCALE_M, (p2y * c - p2x * s) / ob.NAV_SCALE_M,
            geom.speed_limit_at(x, y) / MAX_SPEED_MPS, route.speed_at(projection.s) / MAX_SPEED_MPS,
        )
        rx, ry = boxes[:, 0] - x, boxes[:, 1] - y
        d2 = rx * rx + ry * ry
        if self_row >= 0:
            d2[self_row] = math.inf
        near = np.flatnonzero(d2 < ob.LIDAR_REACH2)
        obs[ob.LIDAR] = 1.0
        obs[ob.NEAREST] = 0.0
        if near.size:
            o = boxes[near]
            obs[ob.LIDAR] = _box_lidar(dx30, dy30, rx[near], ry[near], np.cos(o[:, 2]), np.sin(o[:, 2]),
                                       0.5 * o[:, 5], 0.5 * o[:, 6], ob.LIDAR_RANGE_M) / ob.LIDAR_RANGE_M
            dn = d2[near]
            slots: list[float] = []
            vx, vy = state.speed * c, state.speed * s
            for i in np.argsort(dn, kind="stable")[: ob.N_NEAREST]:
                if not dn[i] < ob.LIDAR_RANGE2:
                    break
                px, py = float(rx[near[i]]), float(ry[near[i]])
                dvx, dvy = float(o[i, 3]) - vx, float(o[i, 4]) - vy
                slots += (1.0, (px * c + py * s) / ob.LIDAR_RANGE_M, (py * c - px * s) / ob.LIDAR_RANGE_M,
                          (dvx * c + dvy * s) / ob.REL_SPEED_SCALE, (dvy * c - dvx * s) / ob.REL_SPEED_SCALE)
            obs[ob.NEAREST.start : ob.NEAREST.start + len(slots)] = slots
    np.maximum(obs, ob.OBS_LOW, out=obs)
    np.minimum(obs, ob.OBS_HIGH, out=obs)
    return obs


def reference_box_hits(state: AgentState, cur: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Rows in ``idx`` (of the box table ``cur [A, 8]``) whose boxes overlap ``state``'s box: the half-diagonal
    pre-filter, then the numpy separating-axis test (`seal.core.geometry.overlaps_one`)."""
    if idx.size == 0:
        return idx
    b = cur[idx]
    reach = 0.5 * (math.hypot(state.length, state.width) + np.hypot(b[:, 5], b[:, 6]))
    d2 = (b[:, 0] - state.x) ** 2 + (b[:, 1] - state.y) ** 2
    cand = idx[d2 < reach * reach]
    if not cand.size:
        return cand
    return cand[overlaps_one(state.x, state.y, state.heading, state.length, state.width, cur[cand])]


def reference_projection(route: Route, x: float, y: float, hint: int | None = None) -> tuple[int, float, float]:
    """(segment, s, lateral) of the closest point of ``route`` to (x, y), numpy, windowed around ``hint`` as
    `Route.project` does (8 segments back, 40 ahead)."""
    cols = route._cols
    n = cols.shape[1]
    lo, hi = (0, n) if hint is None else (max(0, hint - 8), min(n, hint + 40))
    ax, ay, ex, ey = cols[:, lo:hi]
    px, py = x - ax, y - ay
    seg_len = np.hypot(ex, ey)
    t = np.clip((px * ex + py * ey) / (seg_len * seg_len), 0.0, 1.0)
    k = int(np.argmin((px - t * ex) ** 2 + (py - t * ey) ** 2))
    lateral = (float(ex[k]) * float(py[k]) - float(ey[k]) * float(px[k])) / float(seg_len[k])
    s0 = float(route._cum[lo + k])
    return lo + k, s0 + float(t[k]) * float(seg_len[k]), lateral


# RAPID's pairwise terms (issue 22): the numpy code `seal.models.rapid.kernels.pair_scan` replaced.
def rapid_social_force(cur: np.ndarray, rows: np.ndarray, a: float, b: float, t_headway: float, behind: float
                       ) -> np.ndarray:
    """Eq. 9 ``[n, 2]`` (map frame, m/s^2): box-gap repulsion from every other present agent."""
    present = np.flatnonzero(cur[:, 7] > 0.5)
    me, other = cur[rows], cur[present]
    c, s = np.cos(me[:, 2])[:, None], np.sin(me[:, 2])[:, None]
    d = other[None, :, :2] - me[:, None, :2]
    lon = c * d[..., 0] + s * d[..., 1]
    lat = -s * d[..., 0] + c * d[..., 1]
    gap_lon = np.abs(lon) - 0.5 * (me[:, 5, None] + other[None, :, 5])
    gap_lat = np.abs(lat) - 0.5 * (me[:, 6, None] + other[None, :, 6])
    dist = np.maximum(np.hypot(d[..., 0], d[..., 1]), 1e-6)
    rel_v = me[:, None, 3:5] - other[None, :, 3:5]
    closing = np.maximum((rel_v * d).sum(-1) / dist, 0.0)
    gap = np.maximum(np.maximum(gap_lon, gap_lat) - t_headway * closing, 0.0)
    fov = behind + (1.0 - behind) * 0.5 * (1.0 + lon / dist)
    mag = a * np.exp(-gap / b) * fov
    mag[present[None, :] == rows[:, None]] = 0.0
    return -(mag[..., None] * d / dist[..., None]).sum(axis=1)


def rapid_neighbors(cur: np.ndarray, rows: np.ndarray, k: int, max_range: float) -> tuple[np.ndarray, np.ndarray]:
    """Rows ``[n, k]`` (-1: none) and centre distances (inf: none) of the ``k`` nearest present agents within
    ``max_range``, nearest first."""
    present = np.flatnonzero(cur[:, 7] > 0.5)
    rel = cur[present][None, :, :2] - cur[rows][:, None, :2]
    dist = np.hypot(rel[..., 0], rel[..., 1])
    dist[present[None, :] == rows[:, None]] = np.inf
    dist[dist > max_range] = np.inf
    order = np.argsort(dist, axis=1, kind="stable")[:, :k]
    d_sel = np.take_along_axis(dist, order, axis=1)
    idx = np.where(np.isfinite(d_sel), present[order], -1)
    pad = k - idx.shape[1]
    return (np.pad(idx, ((0, 0), (0, pad)), constant_values=-1),
            np.pad(d_sel, ((0, 0), (0, pad)), constant_values=np.inf))


def reference_lane_excess(points: np.ndarray, road: RoadDescription) -> tuple[np.ndarray, np.ndarray]:
    """`seal.models.prior.road_projection.closest_lane_points` by a scan of every segment: the closest centreline
    point ``[N, 2]`` of the lane each point is least outside of and the excess over its half width ``[N]`` (m;
    the first segment wins a tie), the map's crop edges opened."""
    best_e = np.full(len(points), np.inf)
    best_q = np.zeros((len(points), 2))
    for lane in open_map_edges(road).lanes:
        c = lane.centerline
        for a, b in zip(c[:-1], c[1:], strict=True):
            e = b - a
            t = np.clip(((points - a) @ e) / max(float(e @ e), 1e-18), 0.0, 1.0)
            q = a + t[:, None] * e
            ex = np.linalg.norm(points - q, axis=1) - lane.width_m / 2
            better = ex < best_e
            best_e[better], best_q[better] = ex[better], q[better]
    return best_q, best_e


def rapid_neighbor_features(cur: np.ndarray, rows: np.ndarray, nb_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[n, K, 8]`` neighbour inputs (agent frame: position / 30 m, velocity difference / 10 m/s, heading
    difference cos / sin, length / 5 m, width / 2 m; zeros where ``nb_rows`` is -1) and the ``[n, K]`` mask."""
    ok = nb_rows >= 0
    other = cur[np.where(ok, nb_rows, 0)]
    me = cur[rows]
    c, s = np.cos(me[:, 2])[:, None], np.sin(me[:, 2])[:, None]
    rxy = other[..., 0:2] - me[:, None, 0:2]
    rv = other[..., 3:5] - me[:, None, 3:5]
    dh = other[..., 2] - me[:, None, 2]
    f = np.stack([
        (c * rxy[..., 0] + s * rxy[..., 1]) / 30.0, (-s * rxy[..., 0] + c * rxy[..., 1]) / 30.0,
        (c * rv[..., 0] + s * rv[..., 1]) / 10.0, (-s * rv[..., 0] + c * rv[..., 1]) / 10.0,
        np.cos(dh), np.sin(dh), other[..., 5] / 5.0, other[..., 6] / 2.0,
    ], axis=-1)
    return np.where(ok[..., None], f, 0.0).astype(np.float32), ok.astype(np.float32)


def _to_frame(vec: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Map-frame vectors ``[n, 2]`` in the frames of heading cos ``c`` / sin ``s`` ``[n]``."""
    return np.column_stack([c * vec[:, 0] + s * vec[:, 1], -s * vec[:, 0] + c * vec[:, 1]])


def rapid_local_map(geo: object, xy: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``[n, 8]`` RAPID local map read-out: at the agent and 15 m ahead, the nearest lane centre's offset (agent
    frame y, /4 m) and direction (cos, sin in the agent frame); the nearest edge point (agent frame, /10 m)."""
    out = []
    for ahead in (0.0, 15.0):
        p = xy + ahead * np.column_stack([c, s])
        q, d = geo.centres.nearest(p)  # type: ignore[attr-defined]
        rel = _to_frame(q - xy, c, s)
        out += [rel[:, 1:2] / 4.0, _to_frame(d, c, s)]
    q, _ = geo.edges.nearest(xy) if len(geo.edges.a) else (xy + 50.0, None)  # type: ignore[attr-defined]
    out.append(_to_frame(q - xy, c, s) / 10.0)
    return np.concatenate(out, axis=1)


def rapid_agent_inputs(geo: object, cur: np.ndarray, rows: np.ndarray, prev_vel: np.ndarray, prev_ok: np.ndarray,
                       desired_speed: np.ndarray, destination: np.ndarray, leader_gap: np.ndarray,
                       leader_v: np.ndarray) -> dict[str, np.ndarray]:
    """The numpy `seal.models.rapid.features.agent_inputs` (all fields but the neighbours, float32) that
    `seal.models.rapid.input_kernels.own_inputs` replaced."""
    from seal.core.scenario import DT_S, HEADING, VX, VY, X, Y
    from seal.models.rapid.features import ACC_SCALE_MPS2, fourier

    me = cur[rows]
    c, s = np.cos(me[:, HEADING]), np.sin(me[:, HEADING])
    vel = me[:, [VX, VY]]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    v_local = _to_frame(vel, c, s)
    own = np.column_stack([speed / 20.0, v_local / 20.0, c, s, fourier(me[:, [X, Y]] - geo.origin_xy),  # type: ignore[attr-defined]
                           rapid_local_map(geo, me[:, [X, Y]], c, s)])
    prev_acc = _to_frame((vel - prev_vel) / DT_S, c, s) / ACC_SCALE_MPS2
    speed_mask = np.isfinite(desired_speed)
    speed_cmd = np.where(speed_mask, (np.nan_to_num(desired_speed) - speed) / 20.0, 0.0)[:, None]
    dest_mask = np.isfinite(destination).all(axis=1)
    rel = _to_frame(np.nan_to_num(destination) - me[:, [X, Y]], c, s)
    dist = np.hypot(rel[:, 0], rel[:, 1])
    dest = np.column_stack([rel / 100.0, np.log1p(dist) / 5.0])
    dest[~dest_mask] = 0.0
    leader_mask = np.isfinite(leader_gap)
    closing = np.where(leader_mask, speed - leader_v, 0.0)
    leader = np.column_stack([np.where(leader_mask, leader_gap, 0.0) / 50.0, closing / 10.0])
    f32 = np.float32
    return {"own": own.astype(f32), "prev_acc": np.where(prev_ok[:, None], prev_acc, 0.0).astype(f32),
            "prev_mask": prev_ok.astype(f32), "speed_cmd": speed_cmd.astype(f32), "speed_mask": speed_mask.astype(f32),
            "dest": dest.astype(f32), "dest_mask": dest_mask.astype(f32), "leader": leader.astype(f32),
            "leader_mask": leader_mask.astype(f32)}
