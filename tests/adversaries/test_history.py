"""Roll-out queue semantics: K bound, initialisation from the log, per-scenario queues, the closed-loop wrapper
in one process (the multi-process hand-off is in test_history_multiprocess.py)."""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
import scenario_factory as sf

from seal.adversaries.closed_loop import ClosedLoopEnv, partition_scenarios
from seal.adversaries.history import RolloutHistory, logged_rollout, rollout_digest
from seal.adversaries.rule import RuleGenerator
from seal.core.scenario import CURRENT_STEP, N_STEPS, X
from seal.envs.heuristic import HeuristicDriver
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv


def fake_rollout(scenario, tag: float) -> Rollout:
    tracks = scenario.tracks.copy()
    tracks[scenario.ego_index, CURRENT_STEP + 1 :, X] += tag
    return Rollout(scenario.scenario_id, tracks, scenario.agent_ids.copy(), scenario.ego_id, scenario.adv_id,
                   last_step=N_STEPS - 1, outcome="success")


def test_logged_rollout_is_the_log() -> None:
    scenario = sf.lane_change_scenario()
    r = logged_rollout(scenario)
    np.testing.assert_array_equal(r.tracks, scenario.tracks)
    assert r.last_step == N_STEPS - 1 and r.ego_id == scenario.ego_id and r.adv_id == scenario.adv_id
    assert r.ego_crashes == [] and r.adversary == "log" and r.route_completion == 1.0


def test_logged_rollout_finds_logged_contacts() -> None:
    road = sf.straight_road(2)
    lane = road.lanes[0].centerline
    ego = sf.simulate_track(lane, 50.0, 20.0)
    adv = sf.simulate_track(lane, 80.0, 10.0)  # 30 m ahead, 10 m/s slower: boxes (5 m) touch after 2.5 s
    scenario = sf.make_scenario(road, [ego, adv], "rear_end")
    r = logged_rollout(scenario)
    steps = [t for t, other in r.ego_crashes if other == scenario.adv_id]
    assert steps and steps[0] == 25  # gap 30 - 10 t <= 5 m at t = 2.5 s
    assert r.crashed and r.adv_crashes == []


def test_queue_starts_with_k_logged_copies_and_is_bounded() -> None:
    scenario = sf.lane_change_scenario()
    other = sf.curve_scenario()
    history = RolloutHistory(k=5)
    queue = history.queue(scenario)
    assert len(queue) == 5 and len(set(map(id, queue))) == 1
    assert rollout_digest(queue[0]) == rollout_digest(logged_rollout(scenario))
    added = [fake_rollout(scenario, float(i + 1)) for i in range(7)]
    for i, r in enumerate(added):
        history.append(scenario, r)
        q = history.queue(scenario)
        assert len(q) == 5 and q[-1] is r
        n_logged = max(0, 5 - (i + 1))
        assert [x.adversary for x in q[:n_logged]] == ["log"] * n_logged
    assert list(history.queue(scenario)) == added[-5:]
    # Other scenarios keep their own queues.
    assert all(r.adversary == "log" for r in history.queue(other))
    assert set(history) == {scenario.scenario_id, other.scenario_id} and len(history) == 2
    # Plain data: survives pickling (what crossing a process boundary does), digests identify roll-outs.
    clone = pickle.loads(pickle.dumps(history))
    assert clone.digests(scenario) == history.digests(scenario)
    assert len(set(history.digests(scenario))) == 5
    copy = history.copy()
    copy.append(scenario, fake_rollout(scenario, 99.0))
    assert history.digests(scenario) != copy.digests(scenario)


def test_append_checks_the_scenario() -> None:
    history = RolloutHistory(k=3)
    with pytest.raises(ValueError, match="lane_change"):
        history.append(sf.curve_scenario(), fake_rollout(sf.lane_change_scenario(), 1.0))
    with pytest.raises(ValueError, match="k must be"):
        RolloutHistory(k=0)


def test_closed_loop_env_feeds_its_queue_and_the_generator_reads_it() -> None:
    scenario = sf.highway_scenario(0)
    env = ClosedLoopEnv(ScenarioEnv(scenario), RuleGenerator(), k=3)
    driver = HeuristicDriver()
    expected = env.history.digests(scenario)
    for _ in range(4):
        obs, info = env.reset(seed=0)
        assert info["adversary"]["generator"] == "rule" and info["adversary"]["perturbed"]
        assert info["adversary"]["history"] == expected  # the queue the generator saw
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(driver.predict(obs)[0])
            done = terminated or truncated
        expected = expected[1:] + [info["rollout_digest"]]
        assert env.history.digests(scenario) == expected
    env.set_perturb_prob(0.0)
    _, info = env.reset(seed=1)
    assert info["adversary"] == {"generator": "log", "perturbed": False, "history": expected}


def test_partition_is_disjoint_and_covering() -> None:
    base = sf.curve_scenario()
    items = [dataclasses.replace(base, scenario_id=f"s{i}") for i in range(7)]
    parts = partition_scenarios(items, 3)
    ids = [s.scenario_id for part in parts for s in part]
    assert sorted(ids) == sorted(s.scenario_id for s in items) and len(set(ids)) == 7
    assert [len(p) for p in parts] == [3, 2, 2]
    with pytest.raises(ValueError, match="workers"):
        partition_scenarios(items[:2], 3)


# ------------------------------------------------------------- edges that mutation testing found untested
def test_a_queue_of_one_and_membership() -> None:
    scenario = sf.highway_scenario(0)
    history = RolloutHistory(1)
    assert scenario.scenario_id not in history
    assert len(history.queue(scenario)) == 1 and scenario.scenario_id in history
    history.append(scenario, fake_rollout(scenario, 1.0))
    ego = scenario.ego_index
    assert history.queue(scenario)[0].tracks[ego, -1, X] == scenario.tracks[ego, -1, X] + 1  # only the newest
    with pytest.raises(ValueError, match="k must be >= 1, got 0"):
        RolloutHistory(0)


def test_a_contact_at_the_current_step_is_not_a_logged_crash() -> None:
    """Only overlaps after `CURRENT_STEP` count (the episode starts there); one step later they do."""
    scenario = sf.highway_scenario(0)
    other = next(i for i in range(scenario.n_agents) if i not in (scenario.ego_index, scenario.adv_index))
    for step, counted in ((CURRENT_STEP, False), (CURRENT_STEP + 1, True)):
        tracks = scenario.tracks.copy()
        tracks[other, step] = tracks[scenario.ego_index, step]  # the same box: a contact at that step only
        crashes = logged_rollout(dataclasses.replace(scenario, tracks=tracks)).ego_crashes
        assert ((step, int(scenario.agent_ids[other])) in crashes) == counted


def test_state_round_trip_keeps_crashes_and_names_a_missing_array() -> None:
    scenario = sf.highway_scenario(0)
    history = RolloutHistory(2)
    played = dataclasses.replace(fake_rollout(scenario, 2.0), ego_crashes=[(40, 3)], adv_crashes=[(55, 9), (56, 9)])
    history.append(scenario, played)
    back = RolloutHistory.from_state(history.get_state()).queue(scenario)[-1]
    assert back.ego_crashes == [(40, 3)] and back.adv_crashes == [(55, 9), (56, 9)]
    state = history.get_state()
    del state["tracks_1"]
    with pytest.raises(ValueError, match=r"w.npz: roll-out 1 has no 'tracks_1' array"):
        RolloutHistory.from_state(state, "w.npz")
