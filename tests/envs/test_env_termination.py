"""Every way an episode ends, on hand-built scenarios, with the matching reward and info."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf

from seal.core.geometry import box_corners
from seal.core.outcome import Outcome
from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import CURRENT_STEP, DT_S, N_STEPS, Scenario, Y
from seal.envs.behaviors import ReplayBehavior
from seal.envs.kinematics import recover_actions
from seal.envs.scenario_env import ScenarioEnv
from seal.envs.sim_core import REWARD_TERMS


def _episode(env: ScenarioEnv, policy, **reset_options) -> tuple[list[float], list[dict], bool, bool]:
    obs, _ = env.reset(options=reset_options or None)
    rewards, infos, t = [], [], CURRENT_STEP
    while True:
        obs, r, terminated, truncated, info = env.step(policy(t, obs))
        rewards.append(r)
        infos.append(info)
        t += 1
        if terminated or truncated:
            return rewards, infos, terminated, truncated


def _parked_adversary(scenario: Scenario, gap_m: float) -> ReplayBehavior:
    """The adversary stopped in the ego's lane ``gap_m`` ahead of the ego (centre to centre)."""
    ego = scenario.track(scenario.ego_id)[CURRENT_STEP]
    track = np.zeros((N_STEPS, 8))
    track[:] = (ego[0] + gap_m, ego[1], 0.0, 0.0, 0.0, 5.0, 2.0, 1.0)
    return ReplayBehavior(track)


def test_arrival(lane_change: Scenario) -> None:
    actions = recover_actions(lane_change.track(lane_change.ego_id), CURRENT_STEP)
    rewards, infos, terminated, truncated = _episode(ScenarioEnv([lane_change]), lambda t, o: actions[t])
    last = infos[-1]
    assert terminated and not truncated
    assert last["is_success"] and last["outcome"] == "success" and last["route_completion"] > 0.95
    assert rewards[-1] == 10.0
    assert not any(i["is_success"] for i in infos[:-1])
    # +1 per metre: the ego drives at 25 m/s, 2.5 m per step.
    assert rewards[5] == pytest.approx(25.0 * DT_S, abs=0.05)
    assert sum(rewards[:-1]) == pytest.approx(infos[-2]["route_completion"] * _route_len(lane_change), rel=1e-6)
    assert last["rollout"].success_step == CURRENT_STEP + len(rewards)


def _route_len(s: Scenario) -> float:
    env = ScenarioEnv([s])
    env.reset()
    return env._route.length - env._route.start_s


def test_collision_with_adversary_terminates(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv], adversary=_parked_adversary(stopped_adv, 30.0))
    rewards, infos, terminated, _ = _episode(env, lambda t, o: np.zeros(2))
    last = infos[-1]
    assert terminated and last["crashed"] and last["outcome"] == "crash"
    assert last["crash_agent_id"] == stopped_adv.adv_id and last["crashed_with_adversary"]
    assert rewards[-1] == -1.0
    # 30 m centre gap - 5 m of car lengths = 25 m at 20 m/s: contact on the 13th step.
    assert len(rewards) == 13
    ro = last["rollout"]
    assert ro.ego_crashes == [(CURRENT_STEP + 13, stopped_adv.adv_id)] and ro.first_crash_step == CURRENT_STEP + 13
    assert not any(i["crashed"] for i in infos[:-1])


def test_collision_without_termination_keeps_going(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv], adversary=_parked_adversary(stopped_adv, 30.0),
                      config={"terminate_on_crash": False})
    rewards, infos, terminated, truncated = _episode(env, lambda t, o: np.zeros(2))
    crashed = [i["crashed"] for i in infos]
    first = crashed.index(True)
    n_contact = sum(crashed)
    assert n_contact >= 3  # driving through a parked car: several steps in contact, each costing -1
    assert all(rewards[k] == -1.0 for k in range(first, first + n_contact))
    assert infos[-1]["outcome"] == "success"  # the episode went on to the end of the route
    ro = infos[-1]["rollout"]
    assert [s for s, _ in ro.ego_crashes] == list(range(CURRENT_STEP + 1 + first, CURRENT_STEP + 1 + first + n_contact))


def test_leaving_the_road(stopped_adv: Scenario) -> None:
    rewards, infos, terminated, _ = _episode(ScenarioEnv([stopped_adv]), lambda t, o: np.array([-0.3, 0.0]))
    last = infos[-1]
    assert terminated and last["out_of_road"] and last["outcome"] == "out_of_road"
    assert rewards[-1] == -10.0
    ego = last["rollout"].ego_track
    lowest = box_corners(*ego[[CURRENT_STEP + len(rewards) - 1, CURRENT_STEP + len(rewards)]][:, [0, 1, 2, 5, 6]].T)
    assert lowest[1, :, 1].min() < -2.0 <= lowest[0, :, 1].min()  # a corner crossed the right edge at y = -2


def _solid_middle_road() -> RoadDescription:
    """Two lanes (y = 0 and 4) separated by a continuous line at y = 2."""
    c = "continuous"
    return RoadDescription(
        layout="polylines",
        lanes=(
            LaneSpec("m:0", np.array([[-100.0, 0.0], [700.0, 0.0]]), 4.0, (c, c)),
            LaneSpec("m:1", np.array([[-100.0, 4.0], [700.0, 4.0]]), 4.0, (c, c)),
        ),
    )


def test_crossing_a_continuous_line() -> None:
    road = _solid_middle_road()
    ego = sf.simulate_track(road.lanes[0].centerline, 50.0, 20.0)
    adv = sf.simulate_track(road.lanes[1].centerline, 20.0, 20.0)
    scenario = sf.make_scenario(road, [ego, adv], "solid")
    rewards, infos, terminated, _ = _episode(ScenarioEnv([scenario]), lambda t, o: np.array([0.02, 0.0]))
    assert terminated and infos[-1]["out_of_road"] and rewards[-1] == -10.0
    y = infos[-1]["rollout"].ego_track[CURRENT_STEP + len(rewards), Y]
    assert 0.3 < y < 2.0  # the box reached the line at y = 2 while still on the drivable area
    # The same check off: the ego drifts on into the other lane without ending the episode there.
    rewards, infos, *_ = _episode(ScenarioEnv([scenario], config={"check_continuous_lines": False}),
                                  lambda t, o: np.array([0.02, 0.0]))
    assert infos[-1]["rollout"].ego_track[CURRENT_STEP + len(rewards), Y] > 2.0


def test_logged_crossings_of_solid_lines_are_allowed() -> None:
    """A logged ego that changes lanes over a solid line can be replayed: the log defines the route."""
    road = _solid_middle_road()
    ego = sf.simulate_track(road.lanes[0].centerline, 50.0, 20.0, offset_fn=sf._smoothstep(2.0, 3.0, 4.0))
    adv = sf.simulate_track(road.lanes[1].centerline, 160.0, 20.0)
    scenario = sf.make_scenario(road, [ego, adv], "solid_lc")
    actions = recover_actions(ego, CURRENT_STEP)
    _, infos, *_ = _episode(ScenarioEnv([scenario]), lambda t, o: actions[t])
    assert infos[-1]["outcome"] == "success"


def test_too_far_from_the_route() -> None:
    road = sf.straight_road(n_lanes=6)  # 24 m wide, striped lines inside: only the route distance ends it
    ego = sf.simulate_track(road.lanes[0].centerline, 50.0, 20.0)
    adv = sf.simulate_track(road.lanes[5].centerline, 50.0, 20.0)
    scenario = sf.make_scenario(road, [ego, adv], "wide")
    rewards, infos, terminated, _ = _episode(
        ScenarioEnv([scenario]), lambda t, o: np.array([0.1 if t < CURRENT_STEP + 3 else 0.0, 0.0])
    )
    y = infos[-1]["rollout"].ego_track[CURRENT_STEP + len(rewards), Y]
    assert terminated and infos[-1]["out_of_road"] and rewards[-1] == -10.0
    assert 10.0 < y < 12.0


def test_time_limit(stopped_adv: Scenario) -> None:
    rewards, infos, terminated, truncated = _episode(
        ScenarioEnv([stopped_adv], config={"horizon_steps": 40}), lambda t, o: np.array([0.0, -1.0])
    )
    assert truncated and not terminated and len(rewards) == 40 and infos[-1]["outcome"] == "timeout"
    assert rewards[-1] == 0.0  # standing still: no progress


def test_reward_terms_name_every_step_reward(stopped_adv: Scenario) -> None:
    """``info["reward_terms"]`` sums to the step reward, with the event's term replacing progress."""
    env = ScenarioEnv([stopped_adv], adversary=_parked_adversary(stopped_adv, 30.0),
                      config={"terminate_on_crash": False})
    rewards, infos, _, _ = _episode(env, lambda t, o: np.zeros(2))
    for r, info in zip(rewards, infos, strict=True):
        terms = info["reward_terms"]
        assert tuple(terms) == REWARD_TERMS and sum(terms.values()) == r
        expected = "out_of_road" if info["out_of_road"] else "crash" if info["crashed"] else (
            "arrival" if info["is_success"] else "progress")
        assert all(v == 0.0 for k, v in terms.items() if k != expected)
    crash_steps = [i["reward_terms"]["crash"] for i in infos if i["crashed"]]
    assert crash_steps and all(v == -1.0 for v in crash_steps)
    assert infos[-1]["reward_terms"]["arrival"] == 10.0 and infos[-1]["outcome"] is Outcome.SUCCESS
    assert sum(i["reward_terms"]["progress"] for i in infos) > 0.0
