"""Replay fidelity: background agents follow their logs exactly, the kinematic ego reproduces its log from
recovered actions, and the adversary behaviours do what they say."""

from __future__ import annotations

import numpy as np
import pytest

from seal.core.scenario import CURRENT_STEP, N_STEPS, VALID, Scenario, X, Y
from seal.envs.behaviors import PolicyBehavior, ReplayBehavior, TrackingBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import MAX_ACCEL_MPS2, MAX_STEER_RAD, AgentState, bicycle_step, recover_actions
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv


def _run(env: ScenarioEnv, actions: np.ndarray | None = None, **reset_options) -> Rollout:
    env.reset(options=reset_options or None)
    t = CURRENT_STEP
    while True:
        a = actions[t] if actions is not None and t < len(actions) else np.zeros(2)
        *_, terminated, truncated, info = env.step(a)
        t += 1
        if terminated or truncated:
            return info["rollout"]


def test_bicycle_matches_highway_env() -> None:
    from highway_env.road.road import Road, RoadNetwork
    from highway_env.vehicle.kinematics import Vehicle

    road = Road(RoadNetwork.straight_road_network(2))
    v = Vehicle(road, [10.0, 2.0], heading=0.3, speed=20.0)
    s = AgentState(x=10.0, y=2.0, heading=0.3, speed=20.0, length=Vehicle.LENGTH)
    for steer, acc in [(0.3, 0.5), (-0.7, -0.2), (1.0, 1.0), (0.0, -1.0)]:
        v.act({"steering": steer * MAX_STEER_RAD, "acceleration": acc * MAX_ACCEL_MPS2})
        v.step(0.1)
        s = bicycle_step(s, steer, acc)
        assert (s.x, s.y, s.heading, s.speed) == pytest.approx((*v.position, v.heading, v.speed), abs=1e-9)


def test_speed_is_clipped() -> None:
    s = AgentState(0.0, 0.0, 0.0, speed=0.2)
    assert bicycle_step(s, 0.0, -1.0).speed == 0.0
    assert bicycle_step(AgentState(0.0, 0.0, 0.0, speed=39.9), 0.0, 1.0).speed == 40.0


def test_background_agents_replay_their_logs_exactly(lane_change: Scenario, highway: list[Scenario]) -> None:
    for scenario in [lane_change, *highway]:
        env = ScenarioEnv([scenario])
        actions = recover_actions(scenario.track(scenario.ego_id), CURRENT_STEP)
        ro = _run(env, actions)
        end = min(ro.last_step, N_STEPS - 1) + 1
        others = [i for i in range(scenario.n_agents) if i != scenario.ego_index]
        # Background and the replayed adversary: bit-exact, including appearing / disappearing with `valid`.
        np.testing.assert_array_equal(ro.tracks[others, :end], scenario.tracks[others, :end])
    # The lane-change scenario has an agent appearing at step 20 and one leaving at step 60.
    valid = lane_change.tracks[:, :, VALID] > 0.5
    assert not valid[2, 19] and valid[2, 20] and valid[3, 59] and not valid[3, 60]


def test_agents_vanish_after_their_log(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv], config={"horizon_steps": 85, "success_completion": 2.0})
    ro = _run(env)  # constant speed, never "arrives": runs past the end of the log
    assert ro.last_step == CURRENT_STEP + 85
    assert ro.adv_track[N_STEPS - 1, VALID] == 1 and (ro.adv_track[N_STEPS:, VALID] == 0).all()
    assert (ro.ego_track[N_STEPS:ro.last_step + 1, VALID] == 1).all()


@pytest.mark.parametrize("name", ["lane_change", "curve", "highway"])
def test_recovered_actions_reproduce_the_logged_ego(name: str, request: pytest.FixtureRequest) -> None:
    scenario = request.getfixturevalue(name)
    scenario = scenario[0] if isinstance(scenario, list) else scenario
    track = scenario.track(scenario.ego_id)
    actions = recover_actions(track, CURRENT_STEP)
    assert actions.shape == (N_STEPS - 1, 2) and np.abs(actions).max() <= 1.0
    env = ScenarioEnv([scenario], config={"success_completion": 2.0, "horizon_steps": 80})  # the full 8 s
    ro = _run(env, actions)
    assert ro.outcome == "timeout" and not ro.ego_crashes
    err = np.hypot(*(ro.ego_track[CURRENT_STEP:N_STEPS, [X, Y]] - track[CURRENT_STEP:, [X, Y]]).T)
    assert err.max() < 0.5, err.max()


def test_recovered_actions_are_open_loop_consistent_for_model_tracks() -> None:
    """On a track produced by the 10 Hz model itself the recovered actions are the ones that made it."""
    rng = np.random.default_rng(0)
    truth = np.clip(rng.normal(0, 0.1, (N_STEPS - 1, 2)), -1, 1)
    s = AgentState(0.0, 0.0, 0.1, 15.0)
    track = np.zeros((N_STEPS, 8))
    for k in range(N_STEPS):
        track[k] = s.to_track_row()
        if k < N_STEPS - 1:
            s = bicycle_step(s, *truth[k])
    got = recover_actions(track)
    np.testing.assert_allclose(got[:, 0], truth[:, 0], atol=1e-6)
    np.testing.assert_allclose(got[:-1, 1], truth[:-1, 1], atol=1e-6)


def test_replay_behavior_replays_a_given_track(stopped_adv: Scenario) -> None:
    track = stopped_adv.track(stopped_adv.adv_id).copy()
    track[:, Y] += np.linspace(0.0, 3.0, N_STEPS)  # drift left
    ro = _run(ScenarioEnv([stopped_adv], adversary=ReplayBehavior(track)))
    steps = slice(CURRENT_STEP + 1, ro.last_step + 1)
    np.testing.assert_allclose(ro.adv_track[steps], track[steps])


def test_tracking_behavior_follows_its_trajectory(lane_change: Scenario) -> None:
    """Tracking the ego's logged lane change (given to the adversary, shifted 30 m ahead in time-space)."""
    target = lane_change.track(lane_change.ego_id)[:, :2].copy()
    target[:, 0] += 30.0
    adv0 = lane_change.track(lane_change.adv_id)[CURRENT_STEP]
    # Start the trajectory at the adversary's current position so the test measures tracking, not catch-up.
    target += adv0[:2] - target[CURRENT_STEP]
    ro = _run(ScenarioEnv([lane_change], adversary=TrackingBehavior(target), config={"success_completion": 2.0}),
              recover_actions(lane_change.track(lane_change.ego_id), CURRENT_STEP))
    err = np.hypot(*(ro.adv_track[CURRENT_STEP:N_STEPS, :2] - target[CURRENT_STEP:]).T)
    assert err.max() < 1.0, err.max()


def test_policy_behavior_drives_the_adversary_reactively(stopped_adv: Scenario) -> None:
    """A heuristic adversary on its logged route stays on it and sees its own observation."""
    seen: list[np.ndarray] = []

    class Spy(HeuristicDriver):
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            seen.append(observation)
            return super().predict(observation, state, episode_start, deterministic)

    ro = _run(ScenarioEnv([stopped_adv], adversary=PolicyBehavior(Spy()), config={"success_completion": 2.0}),
              recover_actions(stopped_adv.track(stopped_adv.ego_id), CURRENT_STEP))
    assert len(seen) == ro.n_steps and seen[0].shape == (100,)
    adv = ro.adv_track[CURRENT_STEP : ro.last_step + 1]
    assert np.abs(adv[:, Y]).max() < 0.3  # stays in its lane (centre y = 0)
    assert adv[-1, X] - adv[0, X] > 150  # and drives on
