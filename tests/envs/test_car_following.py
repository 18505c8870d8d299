"""Car-following physics of the reactive background (issue 22): obstacles (cut-ins, crossings, the log's own
encounters), IDM+, the logged headway, the Gipps bound, the step-wise logged desired speed, IDM with the ego."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import scenario_factory as sf

from seal.core.geometry import pairwise_overlaps
from seal.core.scenario import CURRENT_STEP, DT_S, VALID, VX, VY, X
from seal.envs.background import IDMBackground, Intent, logged_desired_speed, roll_background
from seal.envs.car_following import (
    IDM_COMFORT_ACC_MAX_MPS2,
    IDM_TIME_WANTED_S,
    SAFE_DECEL_MPS2,
    SAFE_MIN_GAP_M,
    SAFE_REACTION_S,
    idm_acceleration,
    idm_plus_acceleration,
    leader_gaps,
    logged_time_headway,
    obstacle_gaps,
    route_distances,
    safe_acceleration,
    safety_obstacles,
)


def boxes(*rows: tuple[float, float, float, float]) -> np.ndarray:
    """Box table ``[n, 8]`` of 5 x 2 m cars from (x, y, heading, speed) rows."""
    out = np.zeros((len(rows), 8))
    for i, (x, y, h, v) in enumerate(rows):
        out[i] = (x, y, h, v * math.cos(h), v * math.sin(h), 5.0, 2.0, 1.0)
    return out


def test_a_car_cutting_in_is_an_obstacle_before_its_centre_is_in_the_lane() -> None:
    # agent 0 at 20 m/s; agent 1 10 m ahead one lane over (3.5 m), drifting in at 2 m/s; agent 2 parallel
    cur = boxes((0.0, 0.0, 0.0, 20.0), (10.0, 3.5, 0.0, 20.0), (10.0, -3.5, 0.0, 20.0))
    cur[1, VY] = -2.0
    rows = np.array([0])
    assert np.isinf(leader_gaps(cur, rows)[0][0])  # not in the heading corridor yet
    gap, lead_v = obstacle_gaps(cur, rows)
    assert gap[0] == pytest.approx(10.0 - 5.0) and lead_v[0] == pytest.approx(20.0)
    parallel = cur.copy()
    parallel[1, VY] = 0.0
    assert np.isinf(obstacle_gaps(parallel, rows)[0][0])  # a neighbour keeping its lane is none


def test_a_crossing_car_is_an_obstacle_only_if_it_gets_there_first() -> None:
    # agent 0 at 10 m/s toward a crossing 30 m ahead (there from 2.65 s to 3.35 s); a slow crosser from 6 m to
    # its right at 2 m/s is in its lane from 1.1 s on (first: an obstacle); one from 40 m right at 10 m/s comes
    # in at 3.6 s, after agent 0 has passed (none)
    first = boxes((0.0, 0.0, 0.0, 10.0), (30.0, -6.0, math.pi / 2, 2.0))
    late = boxes((0.0, 0.0, 0.0, 10.0), (30.0, -40.0, math.pi / 2, 10.0))
    gap, lead_v = obstacle_gaps(first, np.array([0]), horizon_s=4.0)
    assert gap[0] == pytest.approx(30.0 - 2.5 - 1.0) and lead_v[0] == pytest.approx(0.0, abs=1e-9)
    assert np.isinf(obstacle_gaps(late, np.array([0]), horizon_s=4.0)[0][0])
    # the same encounter in the log: the logged drivers resolved it, no reaction
    assert np.isinf(obstacle_gaps(first, np.array([0]), logged=first, horizon_s=4.0)[0][0])
    # ... but a box in the lane ahead always counts, logged or not
    ahead = boxes((0.0, 0.0, 0.0, 10.0), (20.0, 0.0, 0.0, 5.0))
    assert obstacle_gaps(ahead, np.array([0]), logged=ahead)[0][0] == pytest.approx(15.0)


def test_idm_plus_keeps_the_wanted_gap_and_is_free_on_an_open_road() -> None:
    v, v0 = np.array([15.0]), np.array([20.0])
    s_star = 5.0 + 15.0 * IDM_TIME_WANTED_S  # bumper gap: highway-env's 10 m centre distance less 5 m
    at = idm_plus_acceleration(v, v0, np.array([s_star]), v)
    assert at[0] == pytest.approx(0.0, abs=1e-12)  # equilibrium exactly at s*
    plain = idm_acceleration(v, v0, np.array([s_star]), v)[0]
    assert plain == pytest.approx(-IDM_COMFORT_ACC_MAX_MPS2 * 0.75**4)  # plain IDM still brakes there
    free = idm_plus_acceleration(v, v0, np.array([np.inf]), np.zeros(1))
    assert free[0] == pytest.approx(IDM_COMFORT_ACC_MAX_MPS2 * (1 - 0.75**4))
    s_short = 5.0 + 15.0 * 0.8  # a logged headway of 0.8 s: s* is 17 m, at 0.8 x s* the term is 1 - 1 / 0.64
    short = idm_plus_acceleration(v, v0, np.array([0.8 * s_short]), v, time_wanted_s=np.array([0.8]))
    assert short[0] == pytest.approx(IDM_COMFORT_ACC_MAX_MPS2 * (1 - 1 / 0.64))


def test_gipps_bound_stops_the_agent_behind_a_stopped_box() -> None:
    gap, v = 40.0, 15.0
    a = safe_acceleration(np.array([v]), np.array([gap]), np.zeros(1))[0]
    v1 = v + a * DT_S
    # reaction then braking at SAFE_DECEL from v1 ends exactly SAFE_MIN_GAP short of the box
    assert v1 * SAFE_REACTION_S + v1**2 / (2 * SAFE_DECEL_MPS2) == pytest.approx(gap - SAFE_MIN_GAP_M)
    far = safe_acceleration(np.array([v]), np.array([200.0]), np.zeros(1))[0]
    assert far > 0 and np.isinf(safe_acceleration(np.array([v]), np.array([np.inf]), np.zeros(1))[0])


def two_car_scenario(gap_m: float, speed_mps: float) -> sf.Scenario:
    """Ego ahead in lane 0, a follower ``gap_m`` behind (bumper gap) at the same speed, adversary in lane 1."""
    road = sf.straight_road(2)
    lane0, lane1 = road.lanes[0].centerline, road.lanes[1].centerline
    ego = sf.simulate_track(lane0, 100.0, speed_mps)
    adv = sf.simulate_track(lane1, 100.0, speed_mps)
    follower = sf.simulate_track(lane0, 100.0 - 5.0 - gap_m, speed_mps)
    return sf.make_scenario(road, [ego, adv, follower], "two_cars")


def test_logged_time_headway_is_the_followers_own_capped_by_highway_env() -> None:
    sc = two_car_scenario(20.0, 15.0)
    t = logged_time_headway(sc.tracks.astype(np.float64), np.array([2, 1]))
    assert t[0] == pytest.approx((20.0 - 5.0) / 15.0, rel=1e-3)
    assert t[1] == IDM_TIME_WANTED_S  # follows nobody
    assert logged_time_headway(two_car_scenario(80.0, 15.0).tracks.astype(np.float64), np.array([2]))[0] == \
        IDM_TIME_WANTED_S


def test_desired_speed_follows_the_log_step_by_step_unless_commanded() -> None:
    sc = sf.highway_scenario(4)
    log = sc.tracks.astype(np.float64)
    intent = Intent.from_log(sc)
    rows = np.arange(sc.n_agents)
    for t in (CURRENT_STEP, 40):
        want = logged_desired_speed(log, log[:, :, VALID] > 0.5, t, rows)
        got = intent.desired_at(t, rows)
        ok = np.isfinite(want)
        np.testing.assert_array_equal(got[ok], want[ok])
        np.testing.assert_array_equal(got[~ok], intent.desired_speed_mps[~ok])
    i = int(np.flatnonzero(np.isfinite(intent.desired_at(40, rows)))[0])
    w = slice(41, 71)
    spd = np.hypot(log[i, w, VX], log[i, w, VY])[log[i, w, VALID] > 0.5]
    assert intent.desired_at(40, np.array([i]))[0] == pytest.approx(spd.mean())
    intent.set_speed(i, 3.0)
    assert intent.desired_at(40, np.array([i]))[0] == 3.0


def test_idm_follows_a_logged_slow_down_with_nothing_ahead() -> None:
    road = sf.straight_road(2)
    lane0, lane1 = road.lanes[0].centerline, road.lanes[1].centerline
    ego = sf.simulate_track(lane1, 300.0, 15.0)
    adv = sf.simulate_track(lane1, 200.0, 15.0)
    slowing = sf.simulate_track(lane0, 50.0, 15.0, accel_fn=lambda t: -1.5 if 3.0 < t < 8.0 else 0.0)
    sc = sf.make_scenario(road, [ego, adv, slowing], "slowing")
    out = roll_background(sc, IDMBackground(), np.random.default_rng(0))
    speed = np.hypot(out[2, :, VX], out[2, :, VY])
    logged = np.hypot(sc.tracks[2, :, VX], sc.tracks[2, :, VY])
    assert np.abs(speed[CURRENT_STEP:] - logged[CURRENT_STEP:]).max() < 2.0  # a constant desired speed: 4.4
    assert np.abs(out[2, -1, X] - sc.tracks[2, -1, X]) < 8.0


def test_idm_background_yields_to_an_ego_cutting_in() -> None:
    """The (logged) ego changes into the background car's lane 12 m ahead of it, 6 m/s slower: replayed, the car
    runs into it; with IDM it brakes for the ego and does not touch it."""
    road = sf.straight_road(2)
    lane0, lane1 = road.lanes[0].centerline, road.lanes[1].centerline
    ego = sf.simulate_track(lane1, 100.0, 14.0, offset_fn=sf._smoothstep(1.2, 1.5, -road.lanes[1].centerline[0, 1]))
    adv = sf.simulate_track(lane1, 400.0, 14.0)
    follower = sf.simulate_track(lane0, 100.0 - 17.0 + 1.2 * 14.0 - 1.2 * 20.0, 20.0)  # 12 m gap at 1.2 s
    sc = sf.make_scenario(road, [ego, adv, follower], "cut_in")

    def touches(tracks: np.ndarray) -> bool:
        return any(pairwise_overlaps(tracks[[0, 2], t])[0, 1] for t in range(CURRENT_STEP, tracks.shape[1])
                   if tracks[0, t, VALID] > 0.5 and tracks[2, t, VALID] > 0.5)

    assert touches(sc.tracks.astype(np.float64))
    assert not touches(roll_background(sc, IDMBackground(), np.random.default_rng(0)))


def test_a_box_in_the_straight_corridor_but_off_the_route_is_no_safety_obstacle() -> None:
    # agent 0 at 10 m/s turning left (its logged route bends up at x = 10); a car stopped across the road 30 m
    # straight ahead (no contact within the 2 s horizon; a same-direction box there would count as a cut-in)
    cur = boxes((0.0, 0.0, 0.0, 10.0), (30.0, 0.0, math.pi / 2, 0.0))
    log = np.zeros((2, 10, 8))
    log[0, :, VALID] = 1.0
    log[0, :, 0] = np.minimum(np.arange(10) * 5.0, 10.0)
    log[0, :, 1] = np.maximum(np.arange(10) * 5.0 - 10.0, 0.0)
    rows = np.array([0])
    assert obstacle_gaps(cur, rows)[0][0] == pytest.approx(26.5)  # the straight corridor sees it
    gap, _ = safety_obstacles(cur, rows, None, route_distances(cur, rows, log, 0))
    assert np.isinf(gap[0])
    straight = log.copy()
    straight[0, :, 0], straight[0, :, 1] = np.arange(10) * 5.0, 0.0
    gap, _ = safety_obstacles(cur, rows, None, route_distances(cur, rows, straight, 0))
    assert gap[0] == pytest.approx(26.5)  # on its route: an obstacle


def test_of_two_simulated_agents_in_each_others_way_only_the_slower_yields() -> None:
    # agents 1 and 2 head-on in one corridor, 20 m apart; agent 0 (not simulated: the ego) stands 10 m behind 2
    cur = boxes((30.0, 0.0, math.pi, 0.0), (0.0, 0.0, 0.0, 8.0), (20.0, 0.0, math.pi, 5.0))
    rows = np.array([1, 2])
    plain, _ = obstacle_gaps(cur, rows)
    assert np.isfinite(plain).all()  # each brakes for the other (and 1 for the ego)
    gap, _ = safety_obstacles(cur, rows, None, None)
    assert gap[0] == pytest.approx(25.0)  # agent 1 is faster: it no longer yields to 2, but to the ego behind 2
    assert gap[1] == pytest.approx(15.0)  # agent 2 yields to agent 1
    alone, _ = safety_obstacles(cur, np.array([1]), None, None)
    assert alone[0] == pytest.approx(15.0)  # agent 2 not simulated (ego-like): agent 1 yields to it


def test_a_slower_simulated_crosser_yields_to_a_faster_simulated_agent_but_a_slower_leader_does_not() -> None:
    # agent 0 at 10 m/s; agent 1 creeping across its lane 30 m ahead at 2 m/s (a predicted contact within 4 s);
    # agent 2 in its lane 50 m ahead at 3 m/s (in its path)
    cur = boxes((0.0, 0.0, 0.0, 10.0), (30.0, -6.0, math.pi / 2, 2.0), (50.0, 0.0, 0.0, 3.0))
    both, _ = safety_obstacles(cur[:2], np.array([0, 1]), None, None, horizon_s=4.0)
    assert np.isinf(both[0])  # both simulated: the faster agent 0 goes first
    only, _ = safety_obstacles(cur[:2], np.array([0]), None, None, horizon_s=4.0)
    assert only[0] == pytest.approx(30.0 - 2.5 - 1.0)  # agent 1 not simulated (ego-like): agent 0 yields to it
    led, _ = safety_obstacles(cur[[0, 2]], np.array([0, 1]), None, None, horizon_s=4.0)
    assert led[0] == pytest.approx(50.0 - 5.0)  # a slower simulated car in the path stays an obstacle


def test_idm_background_catches_up_with_its_logged_schedule_once_the_way_is_clear() -> None:
    """The logged ego cuts in front of a background car, drives slower and leaves the lane again 1.2 s later: the
    car brakes for it and falls ~20 m behind its logged position; with the schedule correction it then closes
    the lag (it shrinks over the last 3 s), without it (gain 0) the lag keeps growing; a commanded speed is never
    corrected."""
    road = sf.straight_road(2)
    lane0, lane1 = road.lanes[0].centerline, road.lanes[1].centerline
    dy = -road.lanes[1].centerline[0, 1]
    cut_in, back = sf._smoothstep(1.2, 1.0, dy), sf._smoothstep(2.4, 1.0, -dy)
    ego = sf.simulate_track(lane1, 100.0, 14.0, offset_fn=lambda t: cut_in(t) + back(t))
    adv = sf.simulate_track(lane1, 400.0, 14.0)
    follower = sf.simulate_track(lane0, 100.0 - 17.0 + 1.2 * 14.0 - 1.2 * 20.0, 20.0)
    sc = sf.make_scenario(road, [ego, adv, follower], "cut_in_and_out")

    def lag(controller: IDMBackground, setup: Any = None) -> np.ndarray:
        out = roll_background(sc, controller, np.random.default_rng(0), setup=setup)
        return sc.tracks[2, :, X] - out[2, :, X]  # metres behind the logged position, per step

    kept, closed = lag(IDMBackground(schedule_gain_per_s=0.0)), lag(IDMBackground())
    assert kept[-1] > 20.0 and kept[-1] > kept[-31]  # still growing over the last 3 s
    assert closed[-1] < closed[-31] - 4.0 and closed[-1] < 0.6 * kept[-1]
    np.testing.assert_allclose(closed[:CURRENT_STEP + 20], kept[:CURRENT_STEP + 20], atol=1e-3)  # on schedule
    commanded = lag(IDMBackground(), setup=lambda c: c.intent.set_speed(2, 20.0))
    np.testing.assert_allclose(commanded, kept, atol=1e-9)
    with pytest.raises(ValueError, match="schedule_gain_per_s"):
        IDMBackground(schedule_gain_per_s=-1.0)
