"""Background traffic kinds of `ScenarioEnv` (issue 22): replay unchanged bit for bit, IDM reacts to the ego."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import scenario_factory as sf

from seal.core.scenario import CURRENT_STEP, VALID, VX, VY, Scenario, X
from seal.envs.background import (
    ConstantVelocityBackground,
    IDMBackground,
    Intent,
    idm_acceleration,
    leader_gaps,
    roll_background,
)
from seal.envs.heuristic import HeuristicDriver
from seal.envs.scenario_env import ScenarioEnv

REPLAY_DIGEST = "3f1747af4519118eaabc85d74df29599fca2f99e9fdff838f063368e16b7821c"
"""sha256 of observations, rewards and roll-out tracks of `_digest` computed with the env before the
``background`` option existed (commit 58e8bba)."""


def _digest(config: dict) -> str:
    h = hashlib.sha256()
    for sc in [sf.highway_scenario(0), sf.mixed_speed_scenario(1), sf.lane_change_scenario()]:
        env = ScenarioEnv([sc], config={"terminate_on_crash": False, **config})
        obs, _ = env.reset(seed=3)
        driver, done = HeuristicDriver(), False
        while not done:
            obs, r, term, trunc, _ = env.step(driver.predict(obs)[0])
            done = term or trunc
            h.update(obs.tobytes())
            h.update(np.float64(r).tobytes())
        assert env.rollout is not None
        h.update(env.rollout.tracks.tobytes())
    return h.hexdigest()


def test_replay_background_is_unchanged_bit_for_bit() -> None:
    assert _digest({}) == REPLAY_DIGEST
    assert _digest({"background": "replay"}) == REPLAY_DIGEST


def test_background_option_errors_name_the_option() -> None:
    sc = sf.highway_scenario(0)
    with pytest.raises(ValueError, match="background must be one of"):
        ScenarioEnv([sc], config={"background": "smart"})
    with pytest.raises(ValueError, match="needs background_model"):
        ScenarioEnv([sc], config={"background": "rapid"})
    with pytest.raises(ValueError, match="only used with background 'rapid'"):
        ScenarioEnv([sc], config={"background": "idm"}, background_model=IDMBackground())


def test_idm_acceleration_free_road_and_closing_gap() -> None:
    free = idm_acceleration(np.array([10.0, 20.0]), np.array([20.0, 20.0]), np.full(2, np.inf), np.zeros(2))
    assert free[0] == pytest.approx(3.0 * (1 - 0.5**4))
    assert free[1] == pytest.approx(0.0)
    close = idm_acceleration(np.array([20.0]), np.array([20.0]), np.array([5.0]), np.array([0.0]))
    assert close[0] == -6.0  # clipped to highway-env's ACC_MAX


def test_leader_gap_sees_the_box_ahead_in_the_path_only() -> None:
    cur = np.zeros((3, 8))
    cur[:, 5], cur[:, 6], cur[:, VALID] = 5.0, 2.0, 1.0
    cur[1, X] = 25.0  # ahead, same line: gap 25 - 5 = 20 m
    cur[1, VX] = 7.0
    cur[2, X], cur[2, 1] = 10.0, 4.0  # ahead but one lane over
    gap, lead_v = leader_gaps(cur, np.array([0, 2]))
    assert gap[0] == pytest.approx(20.0) and lead_v[0] == pytest.approx(7.0)
    assert np.isinf(gap[1])


def follower_scenario() -> Scenario:
    """Ego in lane 0 at 20 m/s, a background car 30 m behind it at 20 m/s, the adversary in lane 1."""
    road = sf.straight_road(2)
    lane0, lane1 = road.lanes[0].centerline, road.lanes[1].centerline
    ego = sf.simulate_track(lane0, 80.0, 20.0)
    adv = sf.simulate_track(lane1, 80.0, 20.0)
    follower = sf.simulate_track(lane0, 50.0, 20.0)
    return sf.make_scenario(road, [ego, adv, follower], "follower")


def test_idm_background_brakes_for_a_braking_ego() -> None:
    """The background car behind a braking ego stops in time with ``idm``; replayed, it drives into the ego."""
    crashes = {}
    for kind in ("replay", "idm"):
        env = ScenarioEnv([follower_scenario()], config={"background": kind, "terminate_on_crash": False})
        env.reset(seed=0)
        done = False
        while not done:
            _, _, term, trunc, _ = env.step(np.array([0.0, -0.5]))  # ego brakes at 3 m/s^2 to a stop
            done = term or trunc
        assert env.rollout is not None
        crashes[kind] = {i for _, i in env.rollout.ego_crashes}
    assert crashes["replay"] == {2}
    assert crashes["idm"] == set()


def test_roll_background_keeps_lifetime_and_replays_ego_and_adversary() -> None:
    sc = sf.highway_scenario(1)
    out = roll_background(sc, ConstantVelocityBackground(), np.random.default_rng(0))
    np.testing.assert_array_equal(out[:, :, VALID] > 0.5, sc.valid)
    np.testing.assert_array_equal(out[sc.ego_index], sc.tracks[sc.ego_index])
    other = [i for i in range(sc.n_agents) if i not in (sc.ego_index, sc.adv_index) and sc.valid[i, 20]]
    i = other[0]
    v = sc.tracks[i, CURRENT_STEP, VX]
    assert out[i, 20, X] == pytest.approx(sc.tracks[i, CURRENT_STEP, X] + 10 * 0.1 * v, abs=1e-6)
    assert out[i, 20, VY] == pytest.approx(sc.tracks[i, CURRENT_STEP, VY])


def test_intent_from_log_is_mean_future_speed_and_track_end() -> None:
    sc = sf.highway_scenario(2)
    intent = Intent.from_log(sc)
    i = 0
    speed = np.hypot(sc.tracks[i, CURRENT_STEP + 1:, VX], sc.tracks[i, CURRENT_STEP + 1:, VY])
    ok = sc.valid[i, CURRENT_STEP + 1:]
    assert intent.desired_speed_mps[i] == pytest.approx(speed[ok].mean(), rel=1e-5)
    last = np.flatnonzero(sc.valid[i])[-1]
    np.testing.assert_allclose(intent.destination_xy[i], sc.tracks[i, last, :2])
