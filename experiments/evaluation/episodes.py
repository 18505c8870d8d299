"""Running evaluation episodes: one episode of a scenario with a given ego and adversary behaviour, and the
"X-Gen" protocol (DESIGN section 4): a normal episode, then K sequential perturbation passes of generator X
against the same ego, every roll-out appended to the scenario's queue; the last pass is the one scored."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.adversaries.base import AdversaryGenerator, Generation
from seal.adversaries.history import RolloutHistory
from seal.core.scenario import Scenario
from seal.envs.behaviors import AdversaryBehavior, ReplayBehavior
from seal.envs.deadline import with_deadline
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.training.egos import Ego


@dataclass
class PassRecord:
    """One perturbation pass: what the generator produced, the episode that followed and its env seed (playing
    ``generation.behavior`` from that seed again gives the same episode for a deterministic ego)."""

    generation: Generation
    rollout: Rollout
    seed: int


def run_episode(
    env: ScenarioEnv, scenario: Scenario, ego: Ego, behavior: AdversaryBehavior | None = None, seed: int = 0
) -> Rollout:
    """Play one episode of ``scenario`` (adversary: ``behavior``, default its replayed log); returns its roll-out."""
    options = {"scenario_id": scenario.scenario_id, "adversary": behavior or ReplayBehavior()}
    obs, info = env.reset(seed=seed, options=options)
    ego.reset(scenario)
    deadline = bool(getattr(ego, "deadline_obs", False))  # a time-aware ego (`seal.envs.deadline`)
    done = False
    while not done:
        action = ego.act(with_deadline(obs, env) if deadline else obs, info["step"])
        obs, _, terminated, truncated, info = env.step(action)
        done = terminated or truncated
    return info["rollout"]


def perturbation_passes(
    env: ScenarioEnv,
    scenario: Scenario,
    ego: Ego,
    generator: AdversaryGenerator,
    history: RolloutHistory,
    rng: np.random.Generator,
    n_passes: int,
    seed: int = 0,
) -> list[PassRecord]:
    """``n_passes`` sequential passes: generate from the scenario's current queue, play, append the roll-out."""
    records = []
    for i in range(n_passes):
        generation = generator.generate(scenario, history.queue(scenario), rng)
        rollout = run_episode(env, scenario, ego, generation.behavior, seed=seed + 1 + i)
        history.append(scenario, rollout)
        records.append(PassRecord(generation, rollout, seed + 1 + i))
    return records
