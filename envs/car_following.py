"""Car-following physics of the reactive background (issue 22): who is ahead of each agent and how hard it must
brake for it, for all agents at once (numpy, ``[n, m]`` tables of agents x present boxes).

* `leader_gaps`: the nearest box whose centre is in the agent's heading corridor ahead (the leader input of the
  RAPID model; kept as it was trained).
* `obstacle_gaps`: the boxes a driver must brake for: `leader_gaps`' boxes plus those that, with both keeping
  their velocity, touch the agent within `CONTACT_HORIZON_S` while in front of it: a car cutting into its lane,
  a car crossing its path at a junction or merge before it gets there, the ego or the adversary included. A
  box that is predicted to reach the crossing first has priority (the agent yields); one that would only come in
  after the agent has passed is ignored (it has to yield). The heading corridor alone sees a cutting-in car only
  once its centre is in the lane, too late at highway speeds, and treats a crossing car as stopped forever.
* `idm_acceleration`: highway-env's IDM; `safe_acceleration`: the Gipps (1981) safe-speed bound, the largest
  acceleration after which the agent can still stop behind the box ahead if that box brakes as hard as it can.
"""

from __future__ import annotations

import math

import numpy as np

from seal.core.scenario import DT_S, HEADING, LENGTH, VALID, VX, VY, WIDTH, X, Y

# highway-env's IDMVehicle constants (highway_env.vehicle.behavior.IDMVehicle), copied so the kinematic layer
# does not import a vehicle class only for its numbers.
IDM_ACC_MAX_MPS2 = 6.0
IDM_COMFORT_ACC_MAX_MPS2 = 3.0
IDM_COMFORT_ACC_MIN_MPS2 = -5.0
IDM_DISTANCE_WANTED_M = 10.0
"""highway-env's DISTANCE_WANTED = 5 m + its vehicle length (5 m), a centre-to-centre distance."""
IDM_TIME_WANTED_S = 1.5
IDM_DELTA = 4.0
HIGHWAY_ENV_LENGTH_M = 5.0
"""highway-env's vehicle length: its wanted distance less this is the wanted bumper gap (5 m)."""
LEADER_RANGE_M = 80.0
"""How far ahead a leader is looked for (m)."""
PATH_MARGIN_M = 0.6
"""Lateral clearance (m) beyond the two half widths within which a box ahead counts as in the agent's path."""
HEADWAY_QUANTILE = 0.1
"""Quantile of an agent's logged time headways its IDM keeps (`logged_time_headway`)."""
HEADWAY_MIN_S = 0.5
"""Shortest time headway (s) an IDM agent is given, whatever its log."""
HEADWAY_MIN_SPEED_MPS = 2.0
"""Logged steps slower than this (m/s) say nothing about a time headway (queues)."""
CONTACT_HORIZON_S = 2.0
"""How far ahead (s) a constant-velocity contact makes a box an obstacle (`obstacle_gaps`)."""
SAME_DIRECTION_DEG = 30.0
"""Heading difference (deg) below which a box entering the agent's corridor is a car cutting in."""
COS_SAME_DIRECTION = math.cos(math.radians(SAME_DIRECTION_DEG))
CONTACT_MARGIN_M = 0.3
"""Lateral clearance (m) added to the two half extents in the predicted-contact test."""
SAFE_DECEL_MPS2 = 6.0
"""Braking the Gipps bound plans with (m/s^2): highway-env's ACC_MAX, also the ego's largest braking."""
SAFE_REACTION_S = 0.3
"""Reaction time of the Gipps bound (s): braking starts one control step late plus a margin."""
SAFE_MIN_GAP_M = 2.0
"""Bumper gap (m) the Gipps bound keeps when both have stopped."""
EMERGENCY_DECEL_MPS2 = 8.0
"""Hardest braking (m/s^2) a safety bound asks of a learned background agent (a car's emergency stop, 0.8 g)."""


def _frames(cur: np.ndarray, rows: np.ndarray, present: np.ndarray) -> dict[str, np.ndarray]:
    """Per (agent, box): position and velocity of the box relative to the agent, in the agent's frame."""
    me, other = cur[rows], cur[present]
    c, s = np.cos(me[:, HEADING])[:, None], np.sin(me[:, HEADING])[:, None]
    dx = other[None, :, X] - me[:, X, None]
    dy = other[None, :, Y] - me[:, Y, None]
    ovx, ovy = other[None, :, VX], other[None, :, VY]
    return {
        "lon": c * dx + s * dy, "lat": -s * dx + c * dy,
        "v_lon": c * ovx + s * ovy, "v_lat": -s * ovx + c * ovy,
        "my_v": c[:, 0] * me[:, VX] + s[:, 0] * me[:, VY],
        "dh": other[None, :, HEADING] - me[:, HEADING, None],
    }


def leader_gaps(cur: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each agent of ``rows``: (bumper gap to the nearest box in its path ahead (m, inf when none within
    `LEADER_RANGE_M`), that box's speed along the agent's heading (m/s)). A box is in the path when its centre is
    ahead and within the two half widths plus `PATH_MARGIN_M` of the agent's heading line (the ego and the
    adversary count like everyone else)."""
    present = np.flatnonzero(cur[:, VALID] > 0.5)
    f = _frames(cur, rows, present)
    me, other = cur[rows], cur[present]
    half_w = 0.5 * (me[:, WIDTH, None] + other[None, :, WIDTH])
    in_path = (f["lon"] > 0) & (f["lon"] < LEADER_RANGE_M) & (np.abs(f["lat"]) < half_w + PATH_MARGIN_M)
    in_path &= present[None, :] != rows[:, None]
    gap = np.where(in_path, f["lon"] - 0.5 * (me[:, LENGTH, None] + other[None, :, LENGTH]), np.inf)
    return _nearest(gap, f["v_lon"])


def _nearest(gap: np.ndarray, v_lon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = np.argmin(gap, axis=1)
    idx = np.arange(gap.shape[0])
    best = gap[idx, k]
    return best, np.where(np.isfinite(best), v_lon[idx, k], 0.0)


def _interval(x0: np.ndarray, u: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Times ``(lo, hi)`` (s) during which ``|x0 + u t| < half`` (empty: lo >= hi)."""
    moving = np.abs(u) > 1e-9
    safe_u = np.where(moving, u, 1.0)
    a, b = (-half - x0) / safe_u, (half - x0) / safe_u
    lo = np.where(moving, np.minimum(a, b), np.where(np.abs(x0) < half, -np.inf, np.inf))
    hi = np.where(moving, np.maximum(a, b), np.where(np.abs(x0) < half, np.inf, -np.inf))
    return lo, hi


def predicted_contacts(boxes: np.ndarray, rows: np.ndarray, horizon_s: float = CONTACT_HORIZON_S) -> np.ndarray:
    """``[n, A]`` bool: whether box ``j`` of ``boxes [A, 8]`` (valid ones only), both keeping their velocity,
    overlaps agent ``rows[i]`` within ``horizon_s`` while in front of it at first contact (rectangles in the
    agent's frame, ``CONTACT_MARGIN_M`` of lateral clearance; boxes up to `LEADER_RANGE_M` ahead), or, driving
    the same way (within `SAME_DIRECTION_DEG`), enters the agent's heading corridor (`leader_gaps`' test)
    within ``horizon_s`` ahead of it: a car cutting in at the agent's own speed never touches it but becomes
    its leader."""
    allrows = np.arange(len(boxes))
    f = _frames(boxes, rows, allrows)
    me, other = boxes[rows], boxes
    cd, sd = np.abs(np.cos(f["dh"])), np.abs(np.sin(f["dh"]))
    ext_lon = 0.5 * me[:, LENGTH, None] + 0.5 * (cd * other[None, :, LENGTH] + sd * other[None, :, WIDTH])
    ext_lat = 0.5 * me[:, WIDTH, None] + 0.5 * (sd * other[None, :, LENGTH] + cd * other[None, :, WIDTH])
    rel_u = f["v_lon"] - f["my_v"][:, None]
    lo_a, hi_a = _interval(f["lon"], rel_u, ext_lon)
    lo_b, hi_b = _interval(f["lat"], f["v_lat"], ext_lat + CONTACT_MARGIN_M)
    first = np.maximum(np.maximum(lo_a, lo_b), 0.0)
    contact = (first < np.minimum(np.minimum(hi_a, hi_b), horizon_s)) & (first <= horizon_s)
    ahead_then = f["lon"] + rel_u * np.where(np.isfinite(first), first, 0.0) > 0.0
    contact &= ahead_then & (f["lon"] > -ext_lon) & (f["lon"] < LEADER_RANGE_M)
    lo_c, hi_c = _interval(f["lat"], f["v_lat"], 0.5 * (me[:, WIDTH, None] + other[None, :, WIDTH]) + PATH_MARGIN_M)
    enter = np.maximum(lo_c, 0.0)
    at = np.where(np.isfinite(enter), enter, 0.0)
    cut_in = (np.cos(f["dh"]) > COS_SAME_DIRECTION) & (enter <= horizon_s) & (enter < hi_c)
    cut_in &= (f["lon"] + rel_u * at > 0.0) & (f["lon"] < LEADER_RANGE_M)
    contact |= cut_in
    contact &= (other[None, :, VALID] > 0.5) & (me[:, VALID, None] > 0.5) & (allrows[None, :] != rows[:, None])
    return contact


def route_distances(cur: np.ndarray, rows: np.ndarray, log: np.ndarray, t: int) -> np.ndarray:
    """``[n, A]`` distance (m) from the centre of each box of ``cur`` to the route of each agent of ``rows``: the
    polyline from the agent's current position through its logged positions from step ``t`` on (``log
    [A, T, 8]``, valid steps only; the current position first, so an agent behind its log keeps the stretch up
    to its logged one), its segments that start within `LEADER_RANGE_M` of arc length."""
    out = np.full((rows.size, len(cur)), np.inf)
    for k, r in enumerate(rows.tolist()):
        pts = log[r, t:][log[r, t:, VALID] > 0.5][:, [X, Y]]
        poly = np.vstack([cur[r, [X, Y]], pts])
        a, e = poly[:-1], np.diff(poly, axis=0)
        seg = np.hypot(e[:, 0], e[:, 1])
        keep = np.concatenate([[0.0], np.cumsum(seg)[:-1]]) < LEADER_RANGE_M
        a, e = a[keep], e[keep]
        if not len(a):
            out[k] = np.hypot(cur[:, X] - poly[0, 0], cur[:, Y] - poly[0, 1])
            continue
        p = cur[:, None, [X, Y]] - a[None]
        len2 = np.maximum((e**2).sum(axis=1), 1e-12)
        u = np.clip((p * e[None]).sum(axis=2) / len2, 0.0, 1.0)
        d = p - u[..., None] * e[None]
        out[k] = np.sqrt((d**2).sum(axis=2)).min(axis=1)
    return out


def obstacle_pairs(cur: np.ndarray, rows: np.ndarray, logged: np.ndarray | None = None,
                   horizon_s: float = CONTACT_HORIZON_S, route_dist: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``[n, A]`` tables for each agent of ``rows`` and box of ``cur``: whether the box is an obstacle of the
    agent (`obstacle_gaps`), the bumper gap to it along the agent's heading (m, inf where not an obstacle), its
    speed along that heading (m/s) and whether it is in the agent's path (the other obstacles are predicted
    contacts only). With ``route_dist`` (`route_distances`), a box in the heading corridor counts only where its
    centre is also within the two half widths plus `PATH_MARGIN_M` of the agent's route: on a curve or a turn the
    straight corridor holds cars of other lanes that are not in the agent's way."""
    allrows = np.arange(len(cur))
    f = _frames(cur, rows, allrows)
    me, other = cur[rows], cur
    contact = predicted_contacts(cur, rows, horizon_s)
    if logged is not None:
        contact &= ~predicted_contacts(logged, rows, horizon_s)
    cd, sd = np.abs(np.cos(f["dh"])), np.abs(np.sin(f["dh"]))
    ext_lon = 0.5 * me[:, LENGTH, None] + 0.5 * (cd * other[None, :, LENGTH] + sd * other[None, :, WIDTH])
    half_w = 0.5 * (me[:, WIDTH, None] + other[None, :, WIDTH])
    in_path = (f["lon"] > 0) & (f["lon"] < LEADER_RANGE_M) & (np.abs(f["lat"]) < half_w + PATH_MARGIN_M)
    in_path &= (other[None, :, VALID] > 0.5) & (allrows[None, :] != rows[:, None])
    if route_dist is not None:
        in_path &= route_dist < half_w + PATH_MARGIN_M
    hit = in_path | contact
    return hit, np.where(hit, f["lon"] - ext_lon, np.inf), f["v_lon"], in_path


def obstacle_gaps(cur: np.ndarray, rows: np.ndarray, logged: np.ndarray | None = None,
                  horizon_s: float = CONTACT_HORIZON_S) -> tuple[np.ndarray, np.ndarray]:
    """For each agent of ``rows``: (bumper gap (m, inf: none) to the nearest obstacle, its speed along the
    agent's heading (m/s)). Obstacles: the boxes of `leader_gaps` and the `predicted_contacts` (a car cutting
    in, one crossing first) that the log did not have: with ``logged [A, 8]`` (the logged boxes of the same step),
    a pair that is a predicted contact there too is left out: the logged drivers resolved that encounter
    themselves (right of way, signals, a turn) in ways constant velocity cannot see, and braking for it (e.g. for
    a car turning away at a junction) stops the agent in the path of traffic that the log lets pass. The gap is
    the current one along the agent's heading (<= 0 for a box already beside it: brake as hard as allowed)."""
    _, gap, v_lon, _ = obstacle_pairs(cur, rows, logged, horizon_s)
    return _nearest(gap, v_lon)


def safety_obstacles(cur: np.ndarray, rows: np.ndarray, logged: np.ndarray | None, route_dist: np.ndarray | None,
                     horizon_s: float = CONTACT_HORIZON_S) -> tuple[np.ndarray, np.ndarray]:
    """`obstacle_gaps` for the safety bound of learned background agents (`seal.models.rapid`): the boxes of
    `obstacle_pairs` with ``route_dist``, less, between two agents of ``rows`` (both simulated), the one the agent
    has priority over (the faster one goes first; ties: the lower row) where they are each other's obstacle or
    where that one is only a predicted contact of the agent (crossing or cutting in, not in its path on its
    route). Why: two simulated agents that meet where their logs did not (a left turner and oncoming traffic, each
    a little off its log's timing) would otherwise both brake for each other until both stand still; and a car
    that waited at a junction in its log creeps forward at its log's timing, so the faster agent it would cross
    braked for a car that was not coming (on validation, pool2500 train 300-339, this second rule took the 8 s
    ADE from 2.197 to 2.153 m, background collisions 0.037 -> 0.039). The ego and the adversary are never in
    ``rows``, so a background agent always yields to them."""
    hit, gap, v_lon, in_path = obstacle_pairs(cur, rows, logged, horizon_s, route_dist)
    pos = np.full(len(cur), -1)
    pos[rows] = np.arange(rows.size)
    speed = np.hypot(cur[:, VX], cur[:, VY])
    back = np.zeros_like(hit)
    kk, jj = np.nonzero(pos[None, :].repeat(rows.size, 0) >= 0)
    back[kk, jj] = hit[pos[jj], rows[kk]]
    mine = speed[rows, None]
    first = (mine > speed[None, :]) | ((mine == speed[None, :]) & (rows[:, None] < np.arange(len(cur))[None, :]))
    simulated = np.zeros(len(cur), dtype=bool)
    simulated[rows] = True
    yields = first & (back | ~in_path) & simulated[None, :]
    return _nearest(np.where(hit & yields, np.inf, gap), v_lon)


def _wanted_gap(speed: np.ndarray, lead_speed: np.ndarray, time_wanted_s: float | np.ndarray) -> np.ndarray:
    """IDM's wanted bumper gap s* (m): highway-env measures the distance between centres (its wanted distance
    includes its 5 m vehicle length); bumper gaps here are compared with `IDM_DISTANCE_WANTED_M` -
    `HIGHWAY_ENV_LENGTH_M`."""
    dv = speed - lead_speed
    return (IDM_DISTANCE_WANTED_M - HIGHWAY_ENV_LENGTH_M + np.maximum(speed, 0.0) * time_wanted_s
            + speed * dv / (2.0 * math.sqrt(IDM_COMFORT_ACC_MAX_MPS2 * -IDM_COMFORT_ACC_MIN_MPS2)))


def _idm_terms(speed: np.ndarray, desired: np.ndarray, gap: np.ndarray, lead_speed: np.ndarray,
               time_wanted_s: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IDM's free-road term ``1 - (v / v0)^delta`` and interaction term ``(s* / s)^2`` (0 on a free road)."""
    v0 = np.maximum(desired, 0.1)
    free = 1.0 - np.power(np.maximum(speed, 0.0) / v0, IDM_DELTA)
    s_star = _wanted_gap(speed, lead_speed, time_wanted_s)
    finite = np.isfinite(gap)
    interact = np.zeros_like(speed)
    g = np.maximum(gap[finite], 0.1)
    interact[finite] = (np.maximum(np.broadcast_to(s_star, speed.shape)[finite], 0.0) / g) ** 2
    return free, interact


def idm_acceleration(speed: np.ndarray, desired: np.ndarray, gap: np.ndarray, lead_speed: np.ndarray,
                     time_wanted_s: float | np.ndarray = IDM_TIME_WANTED_S) -> np.ndarray:
    """highway-env's IDM acceleration (m/s^2) for speeds, desired speeds, bumper gaps (inf: free road) and the
    leaders' speeds, all ``[n]``; clipped to +-`IDM_ACC_MAX_MPS2` as highway-env does; ``time_wanted_s``: the
    time headway (s; scalar or ``[n]``), highway-env's by default."""
    free, interact = _idm_terms(speed, desired, gap, lead_speed, time_wanted_s)
    return np.clip(IDM_COMFORT_ACC_MAX_MPS2 * (free - interact), -IDM_ACC_MAX_MPS2, IDM_ACC_MAX_MPS2)


def idm_plus_acceleration(speed: np.ndarray, desired: np.ndarray, gap: np.ndarray, lead_speed: np.ndarray,
                          time_wanted_s: float | np.ndarray = IDM_TIME_WANTED_S) -> np.ndarray:
    """IDM+ (Schakel, Knoop and van Arem 2010): `idm_acceleration`'s terms and constants, combined as
    ``a (min(1 - (v/v0)^delta, 1 - (s*/s)^2))`` instead of their difference. Plain IDM's equilibrium gap grows
    without bound as the speed nears the desired one (``s* / sqrt(1 - (v/v0)^4)``), so an IDM car that should
    follow its logged speed falls back from the queue it was logged in; IDM+ keeps ``s*`` (the reason
    `IDMBackground` uses it)."""
    free, interact = _idm_terms(speed, desired, gap, lead_speed, time_wanted_s)
    acc = IDM_COMFORT_ACC_MAX_MPS2 * np.minimum(free, 1.0 - interact)
    return np.clip(acc, -IDM_ACC_MAX_MPS2, IDM_ACC_MAX_MPS2)


def logged_time_headway(log: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``[len(rows)]`` time headway (s) each agent keeps in its log: the `HEADWAY_QUANTILE` quantile over its
    logged steps at more than `HEADWAY_MIN_SPEED_MPS` with a `leader_gaps` box ahead of ``(gap - s0) / speed``
    (s0 the IDM's wanted bumper gap), within [`HEADWAY_MIN_S`, `IDM_TIME_WANTED_S`]; `IDM_TIME_WANTED_S` for an
    agent that never follows anyone in its log. ``log [A, T, 8]``."""
    s0 = IDM_DISTANCE_WANTED_M - HIGHWAY_ENV_LENGTH_M
    heads = np.full((rows.size, log.shape[1]), np.nan)
    for t in range(log.shape[1]):
        cur = np.where(log[:, t, VALID, None] > 0.5, log[:, t], 0.0)
        ok = np.flatnonzero(cur[rows, VALID] > 0.5)
        if not ok.size:
            continue
        gap, _ = leader_gaps(cur, rows[ok])
        speed = np.hypot(cur[rows[ok], VX], cur[rows[ok], VY])
        follow = np.isfinite(gap) & (speed > HEADWAY_MIN_SPEED_MPS)
        heads[ok[follow], t] = (gap[follow] - s0) / speed[follow]
    out = np.full(rows.size, IDM_TIME_WANTED_S)
    some = np.isfinite(heads).any(axis=1)
    if some.any():
        out[some] = np.nanquantile(heads[some], HEADWAY_QUANTILE, axis=1)
    return np.clip(out, HEADWAY_MIN_S, IDM_TIME_WANTED_S)


def safe_acceleration(speed: np.ndarray, gap: np.ndarray, lead_speed: np.ndarray) -> np.ndarray:
    """The Gipps safe-speed bound as an acceleration (m/s^2, inf where ``gap`` is inf), all ``[n]``: the speed
    ``v`` reached after this step must let the agent, reacting `SAFE_REACTION_S` late and braking at
    `SAFE_DECEL_MPS2`, stop `SAFE_MIN_GAP_M` behind where the box ahead stops braking as hard
    (``v tau + v^2 / 2b <= gap - s_min + v_lead^2 / 2b``); a box coming toward the agent stops at once."""
    b, tau = SAFE_DECEL_MPS2, SAFE_REACTION_S
    lead = np.maximum(lead_speed, 0.0)
    room = 2.0 * b * (np.where(np.isfinite(gap), gap, 0.0) - SAFE_MIN_GAP_M) + lead**2
    v_safe = -b * tau + np.sqrt(np.maximum((b * tau) ** 2 + room, 0.0))
    acc = (np.maximum(v_safe, 0.0) - np.maximum(speed, 0.0)) / DT_S
    return np.where(np.isfinite(gap), acc, np.inf)
