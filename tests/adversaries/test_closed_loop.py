"""The closed-loop wrapper's contract in detail (issue 24: each test here kills a mutant of
`seal.adversaries.closed_loop` that the other tests let live): the curriculum draw's rng use, what ``last`` and the
episode infos carry, the worker state round trip with the env rng, and the per-worker env constructors."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest
import scenario_factory as sf

from seal.adversaries.closed_loop import (
    ClosedLoopAdversary,
    ClosedLoopEnv,
    closed_loop_env_fns,
    partition_scenarios,
)
from seal.adversaries.history import RolloutHistory
from seal.adversaries.rule import RuleGenerator
from seal.envs.behaviors import ReplayBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.scenario_env import ScenarioEnv


class _FixedGenerator:
    """Draws nothing from the rng; reports fixed generation facts."""

    name = "fixed"

    def generate(self, scenario, queue, rng):  # noqa: ANN001, ANN201
        return types.SimpleNamespace(behavior=object(), chosen_candidate=7, predicted_step=33, generation_time_s=0.25)


def test_an_always_perturbing_curriculum_draws_nothing_from_the_rng() -> None:
    """p >= 1 needs no coin: the rng stream (scenario choice, generator randomness) is the same as without the
    curriculum; p < 1 draws exactly one number per episode."""
    scenario = sf.highway_scenario(0)
    adversary = ClosedLoopAdversary(_FixedGenerator(), RolloutHistory(2), perturb_prob=1.0)  # type: ignore[arg-type]
    rng, untouched = np.random.default_rng(5), np.random.default_rng(5)
    adversary(scenario, rng)
    assert rng.random() == untouched.random()
    adversary.perturb_prob = 0.5
    rng, reference = np.random.default_rng(5), np.random.default_rng(5)
    adversary(scenario, rng)
    reference.random()
    assert rng.random() == reference.random()


def test_last_names_the_generation_facts() -> None:
    scenario = sf.highway_scenario(0)
    adversary = ClosedLoopAdversary(_FixedGenerator(), RolloutHistory(2))  # type: ignore[arg-type]
    assert adversary.last == {}
    adversary(scenario, np.random.default_rng(0))
    digests = adversary.history.digests(scenario)
    assert adversary.last == {"generator": "fixed", "perturbed": True, "chosen_candidate": 7, "predicted_step": 33,
                              "generation_time_s": 0.25, "history": digests, "targets_log": True}
    played = dataclasses.replace(adversary.history.queue(scenario)[-1], adversary="ReplayBehavior")
    adversary.history.append(scenario, played)  # as if the ego had played the scenario once
    adversary(scenario, np.random.default_rng(0))
    assert adversary.last["targets_log"] is False


def _play_episode(env: ClosedLoopEnv, seed: int) -> tuple[dict, dict]:
    obs, reset_info = env.reset(seed=seed)
    driver = HeuristicDriver()
    while True:
        obs, _, terminated, truncated, info = env.step(driver.predict(obs)[0])
        if terminated or truncated:
            return reset_info, info


def test_a_given_adversary_and_the_episode_end_info() -> None:
    """No generator: the reset reports the given (logged) adversary; the last step of an episode repeats what the
    reset reported, with the digest of the roll-out just queued."""
    scenario = sf.highway_scenario(1)
    env = ClosedLoopEnv(ScenarioEnv(scenario), None, k=2)
    reset_info, end_info = _play_episode(env, seed=0)
    assert reset_info["adversary"]["generator"] == "log" and reset_info["adversary"]["perturbed"] is False
    assert end_info["episode_adversary"] == reset_info["adversary"]
    assert env.history.digests(scenario)[-1] == end_info["rollout_digest"]
    env.adversary.last = {}
    env.env.unwrapped.set_adversary(lambda scenario, rng: ReplayBehavior())  # an adversary that reports nothing
    assert env.reset(seed=0)[1]["adversary"] == {"generator": "given", "perturbed": False}


def _facts(env: ClosedLoopEnv) -> tuple:
    """What decides an episode: its scenario and what the adversary chose (timings left out)."""
    _play_episode(env, seed=None)  # type: ignore[arg-type]
    last = env.adversary.last
    return (env.env.unwrapped.scenario.scenario_id, last["perturbed"], last.get("predicted_step"), last["history"])


def test_worker_state_round_trip_restores_queues_and_the_env_rng() -> None:
    scenarios = [sf.highway_scenario(i) for i in range(3)]
    env = ClosedLoopEnv(ScenarioEnv(scenarios), RuleGenerator(), k=2, perturb_prob=0.5)
    _play_episode(env, seed=3)
    state = env.get_state()
    assert "rng_state" in state
    expected_next = [_facts(env) for _ in range(2)]

    other = ClosedLoopEnv(ScenarioEnv(scenarios), RuleGenerator(), k=2, perturb_prob=0.5)
    other.set_state(state)
    assert {s.scenario_id: other.history.digests(s) for s in scenarios} == \
        {s.scenario_id: RolloutHistory.from_state(state).digests(s) for s in scenarios}
    replayed = [_facts(other) for _ in range(2)]
    assert replayed == expected_next  # same scenarios, same coin flips, same queues seen


def _reset_ids(env: ClosedLoopEnv, n: int) -> list[str]:
    ids = []
    for _ in range(n):  # ScenarioEnv allows a reset before an episode ends: only the scenario choice matters here
        env.reset()
        ids.append(env.env.unwrapped.scenario.scenario_id)
    return ids


def test_revisits_replay_the_last_scenario_at_their_rate() -> None:
    """revisit_prob r: the next episode replays the last scenario with probability r (plus 1 / n when the fresh
    draw hits it again); 0 draws every scenario afresh from the same rng stream as before the option existed."""
    scenarios = [sf.highway_scenario(i) for i in range(8)]
    plain = ClosedLoopEnv(ScenarioEnv(scenarios), None, k=2)
    plain.reset(seed=1)
    reference = ScenarioEnv(scenarios)
    reference.reset(seed=1)
    ids = _reset_ids(plain, 60)
    assert ids == [reference.reset()[1]["scenario_id"] for _ in range(60)]  # r = 0: untouched stream

    env = ClosedLoopEnv(ScenarioEnv(scenarios), None, k=2, revisit_prob=0.8)
    env.reset(seed=1)
    ids = _reset_ids(env, 400)
    repeats = np.mean([a == b for a, b in zip(ids, ids[1:], strict=False)])
    assert abs(repeats - (0.8 + 0.2 / 8)) < 0.06  # 0.825 expected; binomial sd over 399 pairs ~0.02
    assert len(set(ids)) == 8
    assert env.reset(options={"scenario_id": scenarios[3].scenario_id})[1]["scenario_id"] == scenarios[3].scenario_id
    with pytest.raises(ValueError, match="revisit_prob"):
        ClosedLoopEnv(ScenarioEnv(scenarios), None, revisit_prob=1.0)


def test_worker_state_round_trip_keeps_the_scenario_a_revisit_replays() -> None:
    scenarios = [sf.highway_scenario(i) for i in range(5)]
    env = ClosedLoopEnv(ScenarioEnv(scenarios), None, k=2, revisit_prob=0.5)
    env.reset(seed=4)
    _reset_ids(env, 3)
    state = env.get_state()
    assert str(state["last_scenario"]) == env.env.unwrapped.scenario.scenario_id
    expected = _reset_ids(env, 20)
    other = ClosedLoopEnv(ScenarioEnv(scenarios), None, k=2, revisit_prob=0.5)
    other.set_state(state)
    assert _reset_ids(other, 20) == expected


def test_partition_edges() -> None:
    scenarios = [sf.highway_scenario(i) for i in range(3)]
    assert partition_scenarios(scenarios, 1) == [scenarios]
    assert partition_scenarios(scenarios, 3) == [[s] for s in scenarios]
    with pytest.raises(ValueError, match="n_workers must be >= 1"):
        partition_scenarios(scenarios, 0)
    with pytest.raises(ValueError, match="cannot split 3 scenarios across 4 workers"):
        partition_scenarios(scenarios, 4)


def test_env_fns_build_each_worker_with_its_part_the_generator_and_the_config() -> None:
    scenarios = [sf.highway_scenario(i) for i in range(4)]
    fns = closed_loop_env_fns(scenarios, 2, "rule", {}, env_config={"horizon_steps": 17}, k=3, perturb_prob=0.25)
    envs = [fn() for fn in fns]
    assert [[s.scenario_id for s in e.env.unwrapped.scenarios] for e in envs] == \
        [[s.scenario_id for s in part] for part in partition_scenarios(scenarios, 2)]
    for env in envs:
        assert isinstance(env.adversary.generator, RuleGenerator)
        assert env.history.k == 3 and env.get_perturb_prob() == 0.25
        assert env.env.unwrapped.config["horizon_steps"] == 17
    logged = closed_loop_env_fns(scenarios, 1, None)[0]()
    assert logged.adversary.generator is None and logged.get_perturb_prob() == 1.0


def test_warm_up_builds_every_queue() -> None:
    scenarios = [sf.highway_scenario(i) for i in range(3)]
    env = ClosedLoopEnv(ScenarioEnv(scenarios), None, k=2)
    assert len(env.history) == 0
    assert env.warm_up() == 3
    assert sorted(env.history) == sorted(s.scenario_id for s in scenarios)
