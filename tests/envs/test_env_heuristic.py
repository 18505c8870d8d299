"""The heuristic driver: lane keeping along the route, car following, SB3-style batching."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf

from seal.core.scenario import CURRENT_STEP, N_STEPS, VX, Scenario, X, Y
from seal.envs.behaviors import ReplayBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.observation import OBS_DIM
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv


def _drive(env: ScenarioEnv, driver: HeuristicDriver | None = None) -> Rollout:
    driver = driver or HeuristicDriver()
    obs, _ = env.reset()
    while True:
        action, _ = driver.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return info["rollout"]


def test_follows_a_straight_road(stopped_adv: Scenario) -> None:
    ro = _drive(ScenarioEnv([stopped_adv]))
    assert ro.outcome == "success"
    assert np.abs(ro.ego_track[CURRENT_STEP : ro.last_step + 1, Y]).max() < 0.2


@pytest.mark.parametrize("name", ["curve", "lane_change"])
def test_follows_its_route(name: str, request: pytest.FixtureRequest) -> None:
    assert _drive(ScenarioEnv([request.getfixturevalue(name)])).outcome == "success"


def _leader(scenario: Scenario, gap_m: float, speed: float) -> ReplayBehavior:
    """The adversary ``gap_m`` ahead of the ego (centre to centre) in its lane at a constant ``speed``."""
    ego = scenario.track(scenario.ego_id)[CURRENT_STEP]
    track = np.zeros((N_STEPS + 20, 8))
    t = np.arange(N_STEPS + 20) - CURRENT_STEP
    track[:] = (0.0, ego[Y], 0.0, speed, 0.0, 5.0, 2.0, 1.0)
    track[:, X] = ego[X] + gap_m + speed * 0.1 * t
    return ReplayBehavior(track)


def test_brakes_behind_a_slow_leader(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv], adversary=_leader(stopped_adv, 40.0, 8.0))
    ro = _drive(env)
    assert not ro.ego_crashes and ro.outcome == "timeout"
    ego, adv = ro.ego_track, ro.adv_track
    steps = slice(CURRENT_STEP, ro.last_step + 1)
    gap = adv[steps, X] - ego[steps, X] - 5.0
    assert gap.min() > 3.0
    assert ego[ro.last_step, VX] == pytest.approx(8.0, abs=1.0)  # settled at the leader's speed


def test_stops_behind_a_stopped_car(stopped_adv: Scenario) -> None:
    ro = _drive(ScenarioEnv([stopped_adv], adversary=_leader(stopped_adv, 70.0, 0.0)))
    assert not ro.ego_crashes
    gap = ro.adv_track[ro.last_step, X] - ro.ego_track[ro.last_step, X] - 5.0
    assert 0.5 < gap < 8.0 and ro.ego_track[ro.last_step, VX] < 0.5


def test_mostly_succeeds_on_unperturbed_traffic() -> None:
    scenarios = [sf.highway_scenario(100 + i) for i in range(8)]
    env = ScenarioEnv(scenarios)
    outcomes = []
    for s in scenarios:
        obs, _ = env.reset(options={"scenario_id": s.scenario_id})
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(HeuristicDriver().predict(obs)[0])
            done = terminated or truncated
        outcomes.append(info["outcome"])
    assert outcomes.count("success") >= 7, outcomes


def test_predict_batches(lane_change: Scenario) -> None:
    env = ScenarioEnv([lane_change])
    obs, _ = env.reset()
    single, state = HeuristicDriver().predict(obs, deterministic=True)
    assert single.shape == (2,) and single.dtype == np.float32 and state is None
    batch, _ = HeuristicDriver().predict(np.stack([obs, obs]), episode_start=np.array([True, True]))
    assert batch.shape == (2, 2)
    np.testing.assert_array_equal(batch[0], single)
    assert obs.shape == (OBS_DIM,)
