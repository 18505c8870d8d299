"""Compiled (numba) kernels of the RAPID step: the closest point of a set of segments for many points at once
(`closest_points`) and every pairwise quantity in one pass (`pair_scan`).

Why compiled: the local map read-out and the map force ask it for every background agent (two points each) on
every env step; a numpy ``[points, segments]`` table or one kernel call per point made it the largest per-agent
cost at 120 agents. It does in float64 the textbook projection of `seal.core.kernels.closest_segment` (the same
first-segment-of-the-smallest-distance rule), for each point. Explicit signature: compiled (or loaded from
numba's on-disk cache) at import.
"""

from __future__ import annotations

import math

import numpy as np
from numba import float32, float64, int64, njit, types


@njit(types.Tuple((float64[:, ::1], int64[::1]))(float64[:, ::1], float64[::1], float64[:, ::1]),
      cache=True, nogil=True, error_model="numpy")
def closest_points(cols: np.ndarray, len2: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For points ``pts [m, 2]`` (m): the closest point ``[m, 2]`` on any of the segments ``cols [4, n]`` (rows a x,
    a y, e x, e y; squared lengths ``len2 [n]`` > 0) and that segment's index ``[m]``."""
    m = pts.shape[0]
    n = len2.shape[0]
    out = np.empty((m, 2))
    idx = np.zeros(m, dtype=np.int64)
    for i in range(m):
        x = pts[i, 0]
        y = pts[i, 1]
        best = np.inf
        for k in range(n):
            px = x - cols[0, k]
            py = y - cols[1, k]
            t = (px * cols[2, k] + py * cols[3, k]) / len2[k]
            t = min(max(t, 0.0), 1.0)
            dx = px - t * cols[2, k]
            dy = py - t * cols[3, k]
            d2 = dx * dx + dy * dy
            if d2 < best:
                best = d2
                idx[i] = k
                out[i, 0] = cols[0, k] + t * cols[2, k]
                out[i, 1] = cols[1, k] + t * cols[3, k]
    return out, idx


# Track columns (`seal.core.scenario`), repeated here because numba freezes globals into its on-disk cache,
# which checks only this file for changes (a test holds them equal to the data model's).
_X, _Y, _H, _VX, _VY, _L, _W, _VALID = 0, 1, 2, 3, 4, 5, 6, 7

N_PAIR_PARAMS = 11
"""Length of `pair_scan`'s ``params`` (see there)."""


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _interval(x0: float, u: float, half: float) -> tuple[float, float]:
    """Times ``(lo, hi)`` (s) during which ``|x0 + u t| < half``: `seal.envs.car_following._interval`."""
    if abs(u) > 1e-9:
        a = (-half - x0) / u
        b = (half - x0) / u
        return min(a, b), max(a, b)
    if abs(x0) < half:
        return -np.inf, np.inf
    return np.inf, -np.inf


@njit(cache=True, nogil=True, error_model="numpy")
def _contact_frame(lon: float, lat: float, v_lat: float, rel_u: float, cos_dh: float, sin_dh: float,
                   li: float, wi: float, lj: float, wj: float, reach: float, path_margin: float, horizon: float,
                   margin: float, cos_same: float) -> bool:
    """`seal.envs.car_following.predicted_contacts` for one pair in the agent's frame: box ``j`` at (``lon``,
    ``lat``) (m) moving ``v_lat`` sideways and ``rel_u`` ahead relative to the agent (m/s), heading difference
    cos / sin, lengths and widths of agent ``i`` and box ``j`` (m); leader reach (m), path margin (m), horizon
    (s), contact margin (m), cosine of the same-direction angle. Scalars only and not inlined: the inlined
    array form made the pair loop three times slower (and array arguments cost reference counting)."""
    if lon >= reach:
        return False
    # both tests below need the box within its widest lateral extent (either corridor) at some time of the
    # horizon: most pairs fail this without the divisions of `_interval` (1 mm covers their rounding)
    if abs(lat) - abs(v_lat) * horizon > 0.5 * wi + 0.5 * (lj + wj) + max(margin, path_margin) + 1e-3:
        return False
    cd, sd = abs(cos_dh), abs(sin_dh)
    ext_lon = 0.5 * li + 0.5 * (cd * lj + sd * wj)
    ext_lat = 0.5 * wi + 0.5 * (sd * lj + cd * wj)
    if cos_dh > cos_same:  # same direction: entering the corridor ahead (a cut-in)
        lo_c, hi_c = _interval(lat, v_lat, 0.5 * (wi + wj) + path_margin)
        enter = max(lo_c, 0.0)
        at = enter if math.isfinite(enter) else 0.0
        if enter <= horizon and enter < hi_c and lon + rel_u * at > 0.0:
            return True
    lo_a, hi_a = _interval(lon, rel_u, ext_lon)
    lo_b, hi_b = _interval(lat, v_lat, ext_lat + margin)
    first = max(max(lo_a, lo_b), 0.0)
    if not (first < min(min(hi_a, hi_b), horizon) and first <= horizon):
        return False
    at = first if math.isfinite(first) else 0.0
    return lon + rel_u * at > 0.0 and lon > -ext_lon


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _contact(b: np.ndarray, cs: np.ndarray, i: int, j: int, params: np.ndarray) -> bool:
    """`_contact_frame` of agent ``i`` and box ``j`` of the boxes ``b`` (``cs [A, 2]``: cos / sin of their
    headings)."""
    if i == j or b[i, _VALID] <= 0.5 or b[j, _VALID] <= 0.5:
        return False
    c, s = cs[i, 0], cs[i, 1]
    dx, dy = b[j, _X] - b[i, _X], b[j, _Y] - b[i, _Y]
    rel_u = c * b[j, _VX] + s * b[j, _VY] - (c * b[i, _VX] + s * b[i, _VY])
    return _contact_frame(c * dx + s * dy, -s * dx + c * dy, -s * b[j, _VX] + c * b[j, _VY], rel_u,
                          cs[j, 0] * c + cs[j, 1] * s, cs[j, 1] * c - cs[j, 0] * s, b[i, _L], b[i, _W], b[j, _L],
                          b[j, _W], params[0], params[1], params[2], params[3], params[9])


@njit(cache=True, nogil=True, error_model="numpy")
def _cos_sin(b: np.ndarray) -> np.ndarray:
    out = np.empty((b.shape[0], 2))
    for i in range(b.shape[0]):
        out[i, 0] = math.cos(b[i, _H])
        out[i, 1] = math.sin(b[i, _H])
    return out


ROUTE_CHUNK = 8
"""Route segments per bounding box of `_route_table` (a box far from a chunk's box skips its segments)."""


@njit(cache=True, nogil=True, error_model="numpy")
def _route_table(cur: np.ndarray, rows: np.ndarray, route: np.ndarray, t: int, reach: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each agent's route of `seal.envs.car_following.route_distances`, built once per step: ``verts [n, V, 2]``
    (the agent's position, then ``route[i, t:]``'s valid positions while the arc before them is below ``reach``),
    ``nv [n]`` vertices used, ``boxes [n, C, 4]`` (x min, y min, x max, y max) of the vertices of each chunk of
    `ROUTE_CHUNK` segments. Why: the route test of every (agent, box) pair walked the same polyline again."""
    n = rows.shape[0]
    n_steps = route.shape[1]
    nvmax = max(n_steps - t, 0) + 1
    verts = np.empty((n, nvmax, 2))
    nv = np.zeros(n, dtype=np.int64)
    boxes = np.empty((n, (nvmax + ROUTE_CHUNK - 1) // ROUTE_CHUNK, 4))
    for r in range(n):
        i = rows[r]
        ax, ay = cur[i, _X], cur[i, _Y]
        verts[r, 0, 0], verts[r, 0, 1] = ax, ay
        m, arc = 1, 0.0
        for k in range(t, n_steps):
            if route[i, k, _VALID] <= 0.5:
                continue
            if arc >= reach:
                break
            bx, by = route[i, k, _X], route[i, k, _Y]
            arc += math.hypot(bx - ax, by - ay)
            verts[r, m, 0], verts[r, m, 1] = bx, by
            m += 1
            ax, ay = bx, by
        nv[r] = m
        for c in range((m - 1 + ROUTE_CHUNK - 1) // ROUTE_CHUNK):
            lo, hi = c * ROUTE_CHUNK, min((c + 1) * ROUTE_CHUNK, m - 1)
            x0, y0, x1, y1 = verts[r, lo, 0], verts[r, lo, 1], verts[r, lo, 0], verts[r, lo, 1]
            for q in range(lo + 1, hi + 1):
                x0, x1 = min(x0, verts[r, q, 0]), max(x1, verts[r, q, 0])
                y0, y1 = min(y0, verts[r, q, 1]), max(y1, verts[r, q, 1])
            boxes[r, c, 0], boxes[r, c, 1], boxes[r, c, 2], boxes[r, c, 3] = x0, y0, x1, y1
    return verts, nv, boxes


@njit(cache=True, nogil=True, error_model="numpy")
def _near_route(verts: np.ndarray, nv: np.ndarray, boxes: np.ndarray, r: int, px: float, py: float,
                within: float) -> bool:
    """Whether (px, py) is closer than ``within`` (m) to the route of the ``r``-th agent of a `_route_table`
    (`seal.envs.car_following.route_distances` < ``within``, the same segment arithmetic); chunks whose box,
    grown by ``within`` and 1 mm (rounding), misses the point are skipped: none of their segments can be near."""
    if math.hypot(px - verts[r, 0, 0], py - verts[r, 0, 1]) < within:
        return True
    grow = within + 1e-3
    for c in range((nv[r] - 1 + ROUTE_CHUNK - 1) // ROUTE_CHUNK):
        if (px < boxes[r, c, 0] - grow or px > boxes[r, c, 2] + grow or py < boxes[r, c, 1] - grow
                or py > boxes[r, c, 3] + grow):
            continue
        for q in range(c * ROUTE_CHUNK, min((c + 1) * ROUTE_CHUNK, nv[r] - 1)):
            ax, ay = verts[r, q, 0], verts[r, q, 1]
            ex, ey = verts[r, q + 1, 0] - ax, verts[r, q + 1, 1] - ay
            qx, qy = px - ax, py - ay
            u = min(max((qx * ex + qy * ey) / max(ex * ex + ey * ey, 1e-12), 0.0), 1.0)
            dx, dy = qx - u * ex, qy - u * ey
            if math.sqrt(dx * dx + dy * dy) < within:
                return True
    return False


@njit(cache=True, nogil=True, error_model="numpy")
def _obstacle(cur: np.ndarray, cs: np.ndarray, logged: np.ndarray, cs_log: np.ndarray, use_log: bool,
              table: tuple[np.ndarray, np.ndarray, np.ndarray], pos: np.ndarray, i: int, j: int,
              params: np.ndarray) -> bool:
    """Whether box ``j`` is an obstacle of agent ``i``: `seal.envs.car_following.obstacle_pairs` for one pair,
    with the route test where ``pos[i]`` >= 0 (``i``'s row of the `_route_table` ``table``)."""
    if i == j or cur[i, _VALID] <= 0.5 or cur[j, _VALID] <= 0.5:
        return False
    reach, margin_p = params[0], params[1]
    c, s = cs[i, 0], cs[i, 1]
    dx, dy = cur[j, _X] - cur[i, _X], cur[j, _Y] - cur[i, _Y]
    lon, lat = c * dx + s * dy, -s * dx + c * dy
    half_w = 0.5 * (cur[i, _W] + cur[j, _W])
    in_path = lon > 0.0 and lon < reach and abs(lat) < half_w + margin_p
    if in_path and (pos[i] < 0 or _near_route(table[0], table[1], table[2], pos[i], cur[j, _X], cur[j, _Y],
                                              half_w + margin_p)):
        return True
    return _contact(cur, cs, i, j, params) and not (use_log and _contact(logged, cs_log, i, j, params))


@njit(cache=True, nogil=True, error_model="numpy")
def _rows_and_speeds(cur: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``[A]`` each box's row in ``rows`` (-1: none), and each box's speed (m/s)."""
    pos = np.full(cur.shape[0], -1, dtype=np.int64)
    for r in range(rows.shape[0]):
        pos[rows[r]] = r
    speed = np.empty(cur.shape[0])
    for j in range(cur.shape[0]):
        speed[j] = math.hypot(cur[j, _VX], cur[j, _VY])
    return pos, speed


SOCIAL_CUTOFF = 40.0
"""Gaps beyond this many social ranges add nothing to the social force (exp(-40) ~ 4e-18 of its strength): the
exponential is skipped, the largest per-pair cost after the route walk."""


@njit(cache=True, nogil=True, error_model="numpy")
def _social(dx: float, dy: float, lon: float, lat: float, dist: float, sum_l: float, sum_w: float, rvx: float,
            rvy: float, a_soc: float, b_soc: float, t_head: float, behind: float) -> float:
    """Magnitude (m/s^2) of the eq. 9 repulsion of a box at (``dx``, ``dy``) (m; ``lon``, ``lat`` in the agent's
    frame, ``dist`` away) on the agent, pushing along ``-(dx, dy) / dist``: ``sum_l`` / ``sum_w`` the two
    lengths / widths (m), (``rvx``, ``rvy``) the agent's velocity less the box's (m/s); strength (m/s^2), range
    (m), headway (s), weight behind."""
    d = max(dist, 1e-6)
    gap = max(abs(lon) - 0.5 * sum_l, abs(lat) - 0.5 * sum_w)
    if t_head > 0.0:
        gap = gap - t_head * max((rvx * dx + rvy * dy) / d, 0.0)
    gap = max(gap, 0.0)
    if gap > SOCIAL_CUTOFF * b_soc:
        return 0.0
    fov = behind + (1.0 - behind) * 0.5 * (1.0 + lon / d)
    return a_soc * math.exp(-gap / b_soc) * fov


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _insert(nb: np.ndarray, nbd: np.ndarray, r: int, j: int, dist: float) -> None:
    """Box ``j`` at ``dist`` (m) into row ``r`` of the nearest-first lists ``nb`` / ``nbd`` (the last one drops
    out); whole arrays, not row views: a view per call cost as much as the rest of the pair."""
    q = nb.shape[1] - 1
    while q > 0 and nbd[r, q - 1] > dist:
        nbd[r, q], nb[r, q] = nbd[r, q - 1], nb[r, q - 1]
        q -= 1
    nbd[r, q], nb[r, q] = dist, j


@njit(types.Tuple((float64[:, ::1], int64[:, ::1], float64[:, ::1]))(
    float64[:, ::1], int64[::1], float64[:, ::1], float64[::1], int64, float64[:, :, ::1], int64),
    cache=True, nogil=True, error_model="numpy")
def pair_scan(cur: np.ndarray, rows: np.ndarray, logged: np.ndarray, params: np.ndarray, k: int,
              route: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pairwise quantity of the RAPID step in one pass over (agent, box) pairs, float64, the numpy
    functions' operations (`seal.envs.car_following.leader_gaps` / `obstacle_gaps`, the eq. 9 social force, the
    ``k`` nearest neighbours of `seal.models.rapid.features`); the routes are built once (`_route_table`).

    Args:
        cur: ``[A, 8]`` boxes of the step; rows: ``[n]`` the agents; logged: ``[A, 8]`` the logged boxes of the
            step (all valid = 0: no log to compare with).
        params: leader reach (m), path margin (m), contact horizon (s), contact margin (m), social strength
            (m/s^2), social range (m), social headway (s), weight behind, neighbour range (m), cosine of the
            same-direction angle, 0.
        k: neighbours kept.
        route: ``[A, T, 8]`` the logged tracks, read from step ``t`` on: the obstacles are then those of
            `seal.envs.car_following.safety_obstacles`; ``[A, 0, 8]``: those of `obstacle_gaps`.

    Returns:
        ``[n, 6]`` leader gap (m, inf: none), leader speed along the heading (m/s), obstacle gap, obstacle speed,
        social force x, y (map frame, m/s^2); ``[n, k]`` neighbour rows nearest first (-1: none); ``[n, k]``
        their centre distances (m, inf: none).
    """
    n, m = rows.shape[0], cur.shape[0]
    reach, margin_p, nb_range = params[0], params[1], params[8]
    a_soc, b_soc, t_head, behind = params[4], params[5], params[6], params[7]
    use_log = logged[:, _VALID].max() > 0.5 if m else False
    cs, cs_log = _cos_sin(cur), _cos_sin(logged)
    out = np.empty((n, 6))
    nb, nbd = np.full((n, k), -1, dtype=np.int64), np.full((n, k), np.inf)
    pos, speed = _rows_and_speeds(cur, rows)
    mutual = route.shape[1] > 0
    table = _route_table(cur, rows, route, t, reach)
    for r in range(n):
        i = rows[r]
        c, s = cs[i, 0], cs[i, 1]
        my_v = c * cur[i, _VX] + s * cur[i, _VY]
        lead, lead_v, obs, obs_v, fx, fy = np.inf, 0.0, np.inf, 0.0, 0.0, 0.0
        for j in range(m):
            if j == i or cur[j, _VALID] <= 0.5:
                continue
            dx, dy = cur[j, _X] - cur[i, _X], cur[j, _Y] - cur[i, _Y]
            lon, lat = c * dx + s * dy, -s * dx + c * dy
            v_lon, v_lat = c * cur[j, _VX] + s * cur[j, _VY], -s * cur[j, _VX] + c * cur[j, _VY]
            cos_dh, sin_dh = cs[j, 0] * c + cs[j, 1] * s, cs[j, 1] * c - cs[j, 0] * s
            half_w = 0.5 * (cur[i, _W] + cur[j, _W])
            in_path = lon > 0.0 and lon < reach and abs(lat) < half_w + margin_p
            if in_path and lon - 0.5 * (cur[i, _L] + cur[j, _L]) < lead:
                lead, lead_v = lon - 0.5 * (cur[i, _L] + cur[j, _L]), v_lon
            # `_obstacle` written out on scalars (the hot path); the reverse test below is rare
            on_route = cur[i, _VALID] > 0.5 and in_path and (not mutual or _near_route(
                table[0], table[1], table[2], r, cur[j, _X], cur[j, _Y], half_w + margin_p))
            hit = on_route
            if not hit and cur[i, _VALID] > 0.5 and _contact_frame(
                    lon, lat, v_lat, v_lon - my_v, cos_dh, sin_dh, cur[i, _L], cur[i, _W], cur[j, _L], cur[j, _W],
                    reach, margin_p, params[2], params[3], params[9]):
                hit = not (use_log and _contact(logged, cs_log, i, j, params))
            if hit and mutual and pos[j] >= 0 and (speed[i] > speed[j] or (speed[i] == speed[j] and i < j)):
                # the agent with priority goes where the other is only a predicted contact or has it as its obstacle
                # too (`safety_obstacles`)
                hit = on_route and not _obstacle(cur, cs, logged, cs_log, use_log, table, pos, j, i, params)
            if hit:
                g = lon - (0.5 * cur[i, _L] + 0.5 * (abs(cos_dh) * cur[j, _L] + abs(sin_dh) * cur[j, _W]))
                if g < obs:
                    obs, obs_v = g, v_lon
            dist = math.sqrt(dx * dx + dy * dy)  # not math.hypot: a library call per pair
            mag = _social(dx, dy, lon, lat, dist, cur[i, _L] + cur[j, _L], cur[i, _W] + cur[j, _W],
                          cur[i, _VX] - cur[j, _VX], cur[i, _VY] - cur[j, _VY], a_soc, b_soc, t_head, behind)
            if mag > 0.0:
                fx -= mag * dx / max(dist, 1e-6)
                fy -= mag * dy / max(dist, 1e-6)
            if dist <= nb_range and k > 0 and dist < nbd[r, k - 1]:
                _insert(nb, nbd, r, j, dist)
        out[r, 0], out[r, 1] = lead, (lead_v if math.isfinite(lead) else 0.0)
        out[r, 2], out[r, 3] = obs, (obs_v if math.isfinite(obs) else 0.0)
        out[r, 4], out[r, 5] = fx, fy
    return out, nb, nbd


@njit(types.Tuple((float32[:, :, ::1], float32[:, ::1]))(float64[:, ::1], int64[::1], int64[:, ::1]), cache=True,
      nogil=True, error_model="numpy")
def neighbor_features(cur: np.ndarray, rows: np.ndarray, nb_rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`seal.models.rapid.features` neighbour inputs in one compiled pass: for agent ``rows[r]`` and its neighbour
    ``nb_rows[r, q]`` (-1: none), in the agent's frame: position / 30 m, velocity difference / 10 m/s, heading
    difference cos / sin, length / 5 m, width / 2 m (``[n, K, 8]``, zeros where none) and the mask ``[n, K]``.
    Why: the numpy form (fancy indexing and a stack of ``[n, K]`` tables) was a per-agent cost of every step."""
    n, k = nb_rows.shape[0], nb_rows.shape[1]
    out = np.zeros((n, k, 8), dtype=np.float32)
    mask = np.zeros((n, k), dtype=np.float32)
    for r in range(n):
        i = rows[r]
        c, s = math.cos(cur[i, _H]), math.sin(cur[i, _H])
        for q in range(k):
            j = nb_rows[r, q]
            if j < 0:
                continue
            dx, dy = cur[j, _X] - cur[i, _X], cur[j, _Y] - cur[i, _Y]
            dvx, dvy = cur[j, _VX] - cur[i, _VX], cur[j, _VY] - cur[i, _VY]
            dh = cur[j, _H] - cur[i, _H]
            out[r, q, 0], out[r, q, 1] = (c * dx + s * dy) / 30.0, (-s * dx + c * dy) / 30.0
            out[r, q, 2], out[r, q, 3] = (c * dvx + s * dvy) / 10.0, (-s * dvx + c * dvy) / 10.0
            out[r, q, 4], out[r, q, 5] = math.cos(dh), math.sin(dh)
            out[r, q, 6], out[r, q, 7] = cur[j, _L] / 5.0, cur[j, _W] / 2.0
            mask[r, q] = 1.0
    return out, mask
