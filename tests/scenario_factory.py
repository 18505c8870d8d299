"""Hand-built scenarios for tests and benchmarks: simple roads as `LaneSpec` polylines and agents whose logs
come from the bicycle model driven by a path-tracking controller at 100 Hz (so a 10 Hz replay of the log is
not trivially exact).

Roads: `straight_road` (multi-lane, lane 0 rightmost at y = 0, lanes to the left at +y) and `curved_road`
(straight, left-hand arc, straight). Agents: `simulate_track`. Scenarios: `highway_scenario` (random traffic),
`lane_change_scenario`, `curve_scenario`, `stopped_adversary_scenario`, `mixed_speed_scenario`.

Recordings for the importer tests: CommonRoad XML documents (`document`, `lanelet`, `obstacle`, `road_2020a`,
`cut_in`) and ScenarioNet scenario dicts in the documented format (`scenarionet_scenario`, `dump_pickle`).
"""

from __future__ import annotations

import collections
import math
import pickle
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.road import LaneSpec, RoadDescription
from seal.core.road_area import offset_polyline
from seal.core.scenario import CURRENT_STEP, DT_S, N_STEPS, Scenario

LANE_WIDTH_M = 4.0


def _lane_lines(i: int, n: int) -> tuple[str, str]:
    return ("continuous" if i == n - 1 else "striped", "continuous" if i == 0 else "striped")


def straight_road(
    n_lanes: int = 3, length_m: float = 800.0, lane_width_m: float = LANE_WIDTH_M, speed_limit_mps: float = 30.0,
    x0: float = -100.0,
) -> RoadDescription:
    """``n_lanes`` parallel lanes along +x from ``x0``; lane ``i`` centred at ``y = i * lane_width_m``."""
    lanes = tuple(
        LaneSpec(
            lane_id=f"a:b:{i}",
            centerline=np.array([[x0, i * lane_width_m], [x0 + length_m, i * lane_width_m]]),
            width_m=lane_width_m,
            line_types=_lane_lines(i, n_lanes),
            speed_limit_mps=speed_limit_mps,
        )
        for i in range(n_lanes)
    )
    return RoadDescription(layout="polylines", lanes=lanes, params={"factory": "straight", "n_lanes": n_lanes})


def curve_centerline(
    radius_m: float = 80.0, angle_rad: float = math.pi / 2, before_m: float = 150.0, after_m: float = 150.0,
    step_m: float = 1.0,
) -> np.ndarray:
    """Polyline: straight along +x ending at the origin, a left arc of ``radius_m``, then straight."""
    straight1 = np.stack([np.linspace(-before_m, 0.0, int(before_m / 10) + 1), np.zeros(int(before_m / 10) + 1)], 1)
    n_arc = max(2, int(radius_m * angle_rad / step_m))
    ang = np.linspace(0.0, angle_rad, n_arc + 1)[1:]
    arc = np.stack([radius_m * np.sin(ang), radius_m * (1 - np.cos(ang))], 1)
    end, h = arc[-1], angle_rad
    dist = np.linspace(0.0, after_m, int(after_m / 10) + 1)[1:]
    straight2 = end + dist[:, None] * np.array([math.cos(h), math.sin(h)])
    return np.vstack([straight1, arc, straight2])


def curved_road(
    n_lanes: int = 2, radius_m: float = 80.0, angle_rad: float = math.pi / 2, lane_width_m: float = LANE_WIDTH_M,
    speed_limit_mps: float = 20.0,
) -> RoadDescription:
    """``n_lanes`` lanes around a left-hand curve; lane 0 (rightmost) follows `curve_centerline`."""
    base = curve_centerline(radius_m, angle_rad)
    lanes = tuple(
        LaneSpec(
            lane_id=f"c:d:{i}",
            centerline=offset_polyline(base, i * lane_width_m),
            width_m=lane_width_m,
            line_types=_lane_lines(i, n_lanes),
            speed_limit_mps=speed_limit_mps,
        )
        for i in range(n_lanes)
    )
    return RoadDescription(layout="polylines", lanes=lanes, params={"factory": "curve", "radius_m": radius_m})


def _arc_lengths(path: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])


def _point_at(path: np.ndarray, cum: np.ndarray, s: float, offset: float) -> tuple[np.ndarray, float]:
    """Point at arc length ``s`` shifted ``offset`` m to the left, and the path heading there."""
    s = float(np.clip(s, 0.0, cum[-1] - 1e-6))
    i = int(np.searchsorted(cum, s, side="right") - 1)
    d = path[i + 1] - path[i]
    h = math.atan2(d[1], d[0])
    p = path[i] + d * (s - cum[i]) / max(cum[i + 1] - cum[i], 1e-9)
    return p + offset * np.array([-math.sin(h), math.cos(h)]), h


def _project(path: np.ndarray, cum: np.ndarray, x: float, y: float, s_hint: float) -> float:
    """Arc length of the closest path point to (x, y) among segments within 10 m of ``s_hint``."""
    lo = max(0, int(np.searchsorted(cum, s_hint - 10.0)) - 1)
    hi = min(len(path) - 1, int(np.searchsorted(cum, s_hint + 10.0)) + 1)
    a, e = path[lo:hi], np.diff(path[lo : hi + 1], axis=0)
    px, py = x - a[:, 0], y - a[:, 1]
    u = np.clip((px * e[:, 0] + py * e[:, 1]) / np.maximum((e * e).sum(1), 1e-12), 0.0, 1.0)
    d2 = (px - u * e[:, 0]) ** 2 + (py - u * e[:, 1]) ** 2
    k = int(np.argmin(d2))
    return float(cum[lo + k] + u[k] * (cum[lo + k + 1] - cum[lo + k]))


def simulate_track(
    path: np.ndarray,
    s0: float,
    speed_mps: float,
    accel_fn: Callable[[float], float] | None = None,
    offset_fn: Callable[[float], float] | None = None,
    length_m: float = 5.0,
    width_m: float = 2.0,
    valid_from: int = 0,
    valid_to: int = N_STEPS,
    substeps: int = 10,
) -> np.ndarray:
    """Log ``[N_STEPS, 8]`` of a bicycle-model car tracking ``path`` (pure pursuit at ``substeps`` x 10 Hz).

    Args:
        path: ``[P, 2]`` polyline to follow (e.g. a lane centre line).
        s0: start arc length on the path at step ``valid_from`` (m).
        speed_mps: initial speed.
        accel_fn: acceleration (m/s^2) as a function of time since step 0 (s); default 0.
        offset_fn: lateral offset from the path (m, + left) as a function of time (s), e.g. a lane change.
        valid_from, valid_to: the agent exists on steps ``[valid_from, valid_to)``.
    """
    accel_fn = accel_fn or (lambda _t: 0.0)
    offset_fn = offset_fn or (lambda _t: 0.0)
    cum = _arc_lengths(path)
    dt = DT_S / substeps
    t = valid_from * DT_S
    p, h = _point_at(path, cum, s0, offset_fn(t))
    x, y, v = float(p[0]), float(p[1]), float(speed_mps)
    s = s0
    track = np.zeros((N_STEPS, 8), dtype=np.float32)
    for k in range(valid_from, valid_to):
        track[k] = (x, y, h, v * math.cos(h), v * math.sin(h), length_m, width_m, 1.0)
        for _ in range(substeps):
            lookahead = max(5.0, 0.6 * v)
            target, _ = _point_at(path, cum, s + lookahead, offset_fn(t + lookahead / max(v, 1.0)))
            alpha = math.atan2(target[1] - y, target[0] - x) - h
            dist = max(math.hypot(target[0] - x, target[1] - y), 1e-3)
            sin_beta = float(np.clip(2 * math.sin(alpha) / dist * length_m / 2, -0.44, 0.44))
            beta = math.asin(sin_beta)
            x += v * math.cos(h + beta) * dt
            y += v * math.sin(h + beta) * dt
            h += v * sin_beta / (length_m / 2) * dt
            v = max(0.0, v + accel_fn(t) * dt)
            t += dt
            s = _project(path, cum, x, y, s)
    return track


def make_scenario(
    road: RoadDescription, tracks: list[np.ndarray], scenario_id: str, ego: int = 0, adv: int = 1,
    metadata: dict | None = None,
) -> Scenario:
    """A `Scenario` from per-agent ``[N_STEPS, 8]`` tracks; agent ids are 0..A-1."""
    return Scenario(
        scenario_id=scenario_id,
        tracks=np.stack(tracks),
        agent_ids=np.arange(len(tracks)),
        agent_types=("vehicle",) * len(tracks),
        ego_id=ego,
        adv_id=adv,
        road=road,
        source="factory",
        metadata={"layout": road.params.get("factory", "factory"), **(metadata or {})},
    )


def _lane_path(road: RoadDescription, lane: int) -> np.ndarray:
    return road.lanes[lane].centerline


def _smoothstep(t0: float, duration: float, amplitude: float) -> Callable[[float], float]:
    def f(t: float) -> float:
        u = min(1.0, max(0.0, (t - t0) / duration))
        return amplitude * u * u * (3 - 2 * u)

    return f


def lane_change_scenario(scenario_id: str = "lane_change") -> Scenario:
    """Ego changes from lane 0 to lane 1 at 25 m/s; the adversary drives ahead in lane 1; two background cars,
    one appearing at step 20 and one leaving at step 60."""
    road = straight_road(3)
    ego = simulate_track(_lane_path(road, 0), 50.0, 25.0, offset_fn=_smoothstep(2.0, 3.0, LANE_WIDTH_M))
    adv = simulate_track(_lane_path(road, 1), 110.0, 27.0)
    late = simulate_track(_lane_path(road, 2), 60.0, 24.0, valid_from=20)
    early = simulate_track(_lane_path(road, 2), 0.0, 23.0, accel_fn=lambda t: 0.5, valid_to=60)
    return make_scenario(road, [ego, adv, late, early], scenario_id)


def curve_scenario(scenario_id: str = "curve") -> Scenario:
    """Ego around a 80 m left curve at 15 m/s with gentle acceleration; the adversary in the inner lane."""
    road = curved_road(2, radius_m=80.0)
    base = road.lanes[0].centerline
    ego = simulate_track(base, 80.0, 15.0, accel_fn=lambda t: 0.3 if t < 5 else -0.2)
    adv = simulate_track(road.lanes[1].centerline, 100.0, 14.0)
    return make_scenario(road, [ego, adv], scenario_id)


def stopped_adversary_scenario(scenario_id: str = "stopped_adv", gap_m: float = 60.0) -> Scenario:
    """Ego at 20 m/s in lane 0; in the log the adversary ahead in the same lane drives away at 30 m/s (so the
    logged ego is safe); tests replace the adversary by a stopped car to force a collision."""
    road = straight_road(2)
    ego = simulate_track(_lane_path(road, 0), 50.0, 20.0)
    adv = simulate_track(_lane_path(road, 0), 50.0 + gap_m, 30.0)
    return make_scenario(road, [ego, adv], scenario_id)


def highway_scenario(seed: int, n_lanes: int = 3, n_agents: int = 12, scenario_id: str | None = None) -> Scenario:
    """Random multi-lane traffic: per lane a common speed profile (no rear-end collisions in the log), cars
    spaced 25-55 m; the ego in the middle lane, the adversary the closest car in an adjacent lane. Some cars
    appear late or leave early."""
    rng = np.random.default_rng(seed)
    road = straight_road(n_lanes, length_m=1200.0)
    tracks: list[np.ndarray] = []
    lanes_of: list[int] = []
    per_lane = [n_agents // n_lanes + (1 if i < n_agents % n_lanes else 0) for i in range(n_lanes)]
    ego_lane = n_lanes // 2
    for lane, count in enumerate(per_lane):
        v = float(rng.uniform(18.0, 30.0))
        acc = float(rng.uniform(-0.8, 0.8))
        s = float(rng.uniform(20.0, 60.0))
        for _ in range(count):
            valid_from = int(rng.choice([0, 0, 0, 0, 25]))
            valid_to = int(rng.choice([N_STEPS, N_STEPS, N_STEPS, 70]))
            if not any(lanes_of[i] == lane for i in range(len(tracks))):
                valid_from, valid_to = 0, N_STEPS  # the first car of each lane is there all along
            # A car appearing late starts where the lane's common motion has carried it by then.
            t0 = valid_from * DT_S
            tracks.append(
                simulate_track(
                    _lane_path(road, lane), s + v * t0 + 0.5 * acc * t0 * t0, v + acc * t0,
                    accel_fn=lambda t, a=acc: a, valid_from=valid_from, valid_to=valid_to, substeps=2,
                )
            )
            lanes_of.append(lane)
            s += float(rng.uniform(25.0, 55.0))
    ego = next(i for i, lane in enumerate(lanes_of) if lane == ego_lane)
    ex = tracks[ego][CURRENT_STEP, 0]
    cands = [
        i for i, lane in enumerate(lanes_of)
        if abs(lane - ego_lane) == 1 and tracks[i][CURRENT_STEP, 7] > 0.5
    ]
    adv = min(cands, key=lambda i: abs(tracks[i][CURRENT_STEP, 0] - ex)) if cands else (ego + 1) % len(tracks)
    order = [ego, adv] + [i for i in range(len(tracks)) if i not in (ego, adv)]
    return make_scenario(road, [tracks[i] for i in order], scenario_id or f"highway-{seed}")


def mixed_speed_scenario(seed: int, scenario_id: str | None = None) -> Scenario:
    """Three lanes with one speed profile each, so every motion class of paper 002 occurs: lane 0 slow and
    accelerating (~3 m/s, +0.6 m/s^2), lane 1 moderate and steady (~10 m/s), lane 2 fast and braking (~22 m/s,
    -1.2 m/s^2); three cars per lane 30-45 m apart, the ego first in lane 1, the adversary first in lane 2."""
    rng = np.random.default_rng(seed)
    road = straight_road(3, length_m=800.0)
    tracks: list[np.ndarray] = []
    for lane, (v, acc) in enumerate(((3.0, 0.6), (10.0, 0.0), (22.0, -1.2))):
        v += float(rng.uniform(-0.5, 0.5))
        s = float(rng.uniform(20.0, 40.0))
        for _ in range(3):
            tracks.append(simulate_track(_lane_path(road, lane), s, v, accel_fn=lambda t, a=acc: a, substeps=2))
            s += float(rng.uniform(30.0, 45.0))
    order = [3, 6] + [i for i in range(len(tracks)) if i not in (3, 6)]
    return make_scenario(road, [tracks[i] for i in order], scenario_id or f"mixed-{seed}")


# ------------------------------------------------------------------------------------------------ recordings
# CommonRoad XML documents (importer tests).
CR_LANE_W = 3.5


def _cr_bound(tag: str, pts: list[tuple[float, float]], marking: str | None) -> str:
    body = "".join(f"<point><x>{x}</x><y>{y}</y></point>" for x, y in pts)
    if marking:
        body += f"<lineMarking>{marking}</lineMarking>"
    return f"<{tag}>{body}</{tag}>"


def lanelet(lid: int, left: list, right: list, marks: tuple[str | None, str | None] = (None, None),
            succ: tuple[int, ...] = (), adj_left: int | None = None, adj_right: int | None = None,
            extra: str = "") -> str:
    x = f'<lanelet id="{lid}">' + _cr_bound("leftBound", left, marks[0]) + _cr_bound("rightBound", right, marks[1])
    x += "".join(f'<successor ref="{s}"/>' for s in succ)
    if adj_left is not None:
        x += f'<adjacentLeft ref="{adj_left}" drivingDir="same"/>'
    if adj_right is not None:
        x += f'<adjacentRight ref="{adj_right}" drivingDir="same"/>'
    return x + extra + "</lanelet>"


def _cr_state(tag: str, step: int, x: float, y: float, h: float, v: float | None) -> str:
    vel = f"<velocity><exact>{v}</exact></velocity>" if v is not None else ""
    return (f"<{tag}><position><point><x>{x}</x><y>{y}</y></point></position>"
            f"<orientation><exact>{h}</exact></orientation><time><exact>{step}</exact></time>{vel}</{tag}>")


def obstacle(oid: int, states: list[tuple[int, float, float, float, float | None]], kind: str = "car",
             size: tuple[float, float] = (4.5, 1.8), tag: str = "dynamicObstacle", role: str | None = None,
             shape: str | None = None) -> str:
    x = f'<{tag} id="{oid}">' + (f"<role>{role}</role>" if role else "") + f"<type>{kind}</type>"
    x += shape or f"<shape><rectangle><length>{size[0]}</length><width>{size[1]}</width></rectangle></shape>"
    x += _cr_state("initialState", *states[0])
    if len(states) > 1:
        x += "<trajectory>" + "".join(_cr_state("state", *s) for s in states[1:]) + "</trajectory>"
    return x + f"</{tag}>"


def document(lanelets: list[str], obstacles: list[str], version: str = "2020a", dt: float = 0.1,
             benchmark: str = "TEST-1") -> str:
    return (f'<?xml version="1.0"?><commonRoad commonRoadVersion="{version}" timeStepSize="{dt}" '
            f'benchmarkID="{benchmark}">' + "".join(lanelets) + "".join(obstacles) + "</commonRoad>")


def road_2020a() -> list[str]:
    """Two lanes along +x (lane 1 right, y in [0, 3.5]; lane 2 left) in two segments (x 0..200, 200..400) and a
    widening on-ramp right of lane 1 (x 0..100, 3.5 m wide at the start, 5.5 m at the end)."""
    w = CR_LANE_W
    return [
        lanelet(1, [(0, w), (200, w)], [(0, 0), (200, 0)], ("dashed", "dashed"), (3,), 2, 5),
        lanelet(2, [(0, 2 * w), (200, 2 * w)], [(0, w), (200, w)], ("solid", "dashed"), (4,), None, 1),
        lanelet(3, [(200, w), (400, w)], [(200, 0), (400, 0)], ("dashed", "broad_solid"), (), 4),
        lanelet(4, [(200, 2 * w), (400, 2 * w)], [(200, w), (400, w)], ("broad_solid", "broad_dashed"), (), None, 3),
        lanelet(5, [(0, 0), (100, 0)], [(0, -w), (100, -w - 2.0)], ("dashed", "solid"), (), 1),
    ]


def _cr_smooth(u: float) -> float:
    u = min(1.0, max(0.0, u))
    return u * u * (3 - 2 * u)


def cut_in(steps: int = 101, dt: float = 0.1, gap_m: float = 8.0, v: float = 20.0) -> list[str]:
    """Ego-to-be 10 in lane 1; 11 starts in lane 2 ``gap_m`` ahead and cuts into lane 1 between 3 s and 6 s;
    12 drives far ahead in lane 2; 13 is parked on the ramp (static)."""
    a, b, c = [], [], []
    for k in range(steps):
        t = k * dt
        a.append((k, 20.0 + v * t, 1.75, 0.0, v))
        y = 5.25 - 3.5 * _cr_smooth((t - 3.0) / 3.0)
        dy = -3.5 * 6 * ((t - 3.0) / 3.0) * (1 - (t - 3.0) / 3.0) / 3.0 if 3.0 < t < 6.0 else 0.0
        b.append((k, 20.0 + gap_m + v * t, y, math.atan2(dy, v), math.hypot(v, dy)))
        c.append((k, 150.0 + v * t, 5.25, 0.0, v))
    return [
        obstacle(10, a), obstacle(11, b, kind="truck", size=(6.0, 2.2)), obstacle(12, c),
        obstacle(13, [(0, 90.0, -2.5, 0.0, 0.0)], kind="parkedVehicle", tag="staticObstacle"),
    ]


def write_text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


# ScenarioNet scenario pickles in the documented format (importer tests).
SN_T = 91
"""Steps of the ScenarioNet test recordings (9.1 s at 10 Hz)."""
SN_LANE_W = 3.6


def sn_track(kind: str, x0: float, y: Any, v: float, valid: np.ndarray | None = None,
             size: tuple[float, float] = (4.6, 1.9)) -> dict:
    t = np.arange(SN_T) * 0.1
    x = x0 + v * t
    y = np.broadcast_to(np.asarray(y, dtype=np.float64), (SN_T,)).copy()
    vy = np.gradient(y, t)
    valid = np.ones(SN_T, dtype=bool) if valid is None else valid
    state = {
        "position": np.stack([x, y, np.zeros(SN_T)], axis=1).astype(np.float32),
        "heading": np.arctan2(vy, v).astype(np.float32),
        "velocity": np.stack([np.full(SN_T, v), vy], axis=1).astype(np.float32),
        "length": np.full((SN_T, 1), size[0], dtype=np.float32),
        "width": np.full((SN_T, 1), size[1], dtype=np.float32),
        "height": np.full((SN_T, 1), 1.5, dtype=np.float32),
        "valid": valid,
    }
    for key in ("position", "heading", "velocity"):  # ScenarioNet zeroes invalid steps
        state[key][~valid] = 0.0
    return {"type": kind, "state": state, "metadata": {"type": kind, "track_length": SN_T}}


def sn_line(y: float, x0: float = -100.0, x1: float = 300.0) -> np.ndarray:
    x = np.arange(x0, x1 + 0.5, 0.5)
    return np.stack([x, np.full_like(x, y), np.zeros_like(x)], axis=1)


def scenarionet_scenario(objects_of_interest: list[str] | None = ("300", "200")) -> dict:
    """Waymo-like: SDC 100 in lane 1 (y = 0) at 12 m/s; 200 cuts in from lane 2 (y = 3.6) 9 m ahead; 300 a
    pedestrian of interest; 400 occluded for 3 steps; 500 gone for 20 steps mid-scenario; 600 far away."""
    ts = np.arange(SN_T) * 0.1
    cut = 3.6 - 3.6 * np.clip((ts - 2.0) / 3.0, 0.0, 1.0) ** 2 * (3 - 2 * np.clip((ts - 2.0) / 3.0, 0.0, 1.0))
    occluded = np.ones(SN_T, dtype=bool)
    occluded[50:53] = False
    gone = np.ones(SN_T, dtype=bool)
    gone[40:60] = False
    tracks = {
        "100": sn_track("VEHICLE", 0.0, 0.0, 12.0),
        "200": sn_track("VEHICLE", 9.0, cut, 12.0),
        "300": sn_track("PEDESTRIAN", 30.0, 9.0, 1.2, size=(0.5, 0.5)),
        "400": sn_track("VEHICLE", -25.0, 0.0, 12.0, occluded),
        "500": sn_track("VEHICLE", -20.0, 3.6, 12.5, gone),
        "600": sn_track("VEHICLE", 200.0, 3.6, 10.0),
    }
    width = np.full((len(sn_line(0.0)), 2), SN_LANE_W / 2, dtype=np.float32)
    poly_lane = sn_line(-7.2, 0.0, 100.0)
    features = {
        "1": {"type": "LANE_SURFACE_STREET", "polyline": sn_line(0.0), "width": width, "exit_lanes": ["3"],
              "entry_lanes": [], "speed_limit_mph": 25.0},
        "2": {"type": "LANE_SURFACE_STREET", "polyline": sn_line(SN_LANE_W), "width": width, "exit_lanes": []},
        "3": {"type": "LANE_SURFACE_STREET", "polyline": sn_line(0.0, 300.0, 400.0), "exit_lanes": ["999"]},
        "4": {"type": "LANE_SURFACE_STREET", "polyline": poly_lane,
              "polygon": np.vstack([poly_lane[:, :2] + [0, 1.5], (poly_lane[:, :2] - [0, 1.5])[::-1]])},
        "5": {"type": "LANE_BIKE_LANE", "polyline": sn_line(-12.0)},
        "10": {"type": "ROAD_LINE_BROKEN_SINGLE_WHITE", "polyline": sn_line(SN_LANE_W / 2)},
        "11": {"type": "ROAD_LINE_SOLID_DOUBLE_YELLOW", "polyline": sn_line(1.5 * SN_LANE_W)},
        "12": {"type": "ROAD_EDGE_BOUNDARY", "polyline": sn_line(-SN_LANE_W / 2)},
        "20": {"type": "CROSSWALK", "polygon": np.zeros((4, 3))},
    }
    meta: dict[str, Any] = {
        "ts": ts.astype(np.float32), "sdc_id": "100", "dataset": "waymo", "coordinate": "waymo",
        "scenario_id": "abc123", "metadrive_processed": False, "current_time_index": 10,
        "number_summary": {"num_moving_objects_each_type": collections.defaultdict(int, {"VEHICLE": 5}),
                           "object_types": {"VEHICLE", "PEDESTRIAN"}},
    }
    if objects_of_interest is not None:
        meta["objects_of_interest"] = list(objects_of_interest)
    return {"id": "abc123", "version": "v1", "length": SN_T, "tracks": tracks, "dynamic_map_states": {},
            "map_features": features, "metadata": meta}


def dump_pickle(path: Path, obj: Any, protocol: int = 4) -> Path:
    with path.open("wb") as f:
        pickle.dump(obj, f, protocol=protocol)
    return path
