"""The closed loop (ARCHITECTURE.md, Closed loop) inside one env process: a generator perturbs episodes from the
scenario's roll-out queue and every finished ego roll-out goes back into that queue.

`ClosedLoopEnv` wraps a `ScenarioEnv`; it owns the process's `RolloutHistory`. For several processes (SB3
``SubprocVecEnv``) `closed_loop_env_fns` partitions the scenarios across the workers (`partition_scenarios`), so
each scenario is always played, and its queue kept, by one worker: a roll-out produced in a worker is the newest
entry of the queue that worker's generator reads the next time the scenario comes up.

Every reset's ``info["adversary"]`` says what drove the adversary (generator name or ``"log"``, chosen candidate,
predicted step, generation time) and ``history``: the `rollout_digest` of each roll-out in the queue the generator
saw (oldest first); the last step of an episode adds ``info["rollout_digest"]`` of the roll-out just appended and
``info["episode_adversary"]``: that episode's reset metadata again (what a vectorised trainer sees at an episode's
end, when the reset info already belongs to the next episode).

`ClosedLoopEnv.get_state` / `set_state` save and restore a worker's queues and the env's rng (numpy arrays and
JSON only) so that a training run resumes with the queues it had at its checkpoint.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from typing import Any, SupportsFloat, cast

import gymnasium as gym
import numpy as np

from seal.adversaries.base import K_ROLLOUTS, AdversaryGenerator, make_generator
from seal.adversaries.history import LOGGED_ADVERSARY, RolloutHistory, rollout_digest
from seal.core.scenario import Scenario
from seal.envs.behaviors import AdversaryBehavior, ReplayBehavior
from seal.envs.road_geometry import get_road_geometry, reserve_road_cache
from seal.envs.scenario_env import ScenarioEnv


class ClosedLoopAdversary:
    """`ScenarioEnv` adversary factory: with probability ``perturb_prob`` the generator's behaviour for the
    scenario's current queue, else the logged adversary. ``last`` holds the metadata of the latest call."""

    def __init__(
        self, generator: AdversaryGenerator | None, history: RolloutHistory, perturb_prob: float = 1.0
    ) -> None:
        self.generator = generator
        self.history = history
        self.perturb_prob = float(perturb_prob)
        self.last: dict[str, Any] = {}

    def __call__(self, scenario: Scenario, rng: np.random.Generator) -> AdversaryBehavior:
        queue = self.history.queue(scenario)
        digests = [rollout_digest(r) for r in queue]
        generator = self.generator
        if generator is None or not (self.perturb_prob >= 1.0 or rng.random() < self.perturb_prob):
            self.last = {"generator": "log", "perturbed": False, "history": digests}
            return ReplayBehavior()
        generation = generator.generate(scenario, queue, rng)
        self.last = {
            "generator": generator.name,
            "perturbed": True,
            "chosen_candidate": generation.chosen_candidate,
            "predicted_step": generation.predicted_step,
            "generation_time_s": generation.generation_time_s,
            "history": digests,
            # the generator aims at the newest roll-out: the logged ego until the scenario has been played
            "targets_log": not queue or queue[-1].adversary == LOGGED_ADVERSARY,
        }
        return generation.behavior


class ClosedLoopEnv(gym.Wrapper):
    """A `ScenarioEnv` whose adversary comes from ``generator`` and whose roll-outs feed the scenario queues.

    Args:
        env: the env (its adversary spec is replaced).
        generator: the generator, or None for the logged adversary only (queues are still kept).
        k: queue length.
        perturb_prob: share of episodes the generator perturbs (the curriculum sets it with `set_perturb_prob`).
        revisit_prob: probability that an episode replays the scenario of the episode before it (drawn at each
            reset without a ``scenario_id`` option, from the env's generator). Why: the generator targets the
            newest roll-out in the scenario's queue, and with a training pool much larger than the run's episode
            count most scenarios are played about once, so without revisits most perturbed episodes target the
            logged ego or a roll-out of a much older policy; with ``revisit_prob`` r the scenario is played in runs
            of 1 / (1 - r) episodes on average, each perturbed one against the ego's roll-out just before it, as
            the evaluation's K passes do. 0 (the default) draws every scenario afresh.
    """

    def __init__(
        self, env: ScenarioEnv, generator: AdversaryGenerator | None, k: int = K_ROLLOUTS, perturb_prob: float = 1.0,
        revisit_prob: float = 0.0,
    ) -> None:
        super().__init__(env)
        if not 0.0 <= revisit_prob < 1.0:
            raise ValueError(f"revisit_prob must be in [0, 1), got {revisit_prob}")
        self.history = RolloutHistory(k)
        self.adversary = ClosedLoopAdversary(generator, self.history, perturb_prob)
        self.revisit_prob = float(revisit_prob)
        self._last_scenario_id: str | None = None
        self._episode_adversary: dict[str, Any] = {}
        env.set_adversary(self.adversary)

    @property
    def _scenario_env(self) -> ScenarioEnv:
        return cast(ScenarioEnv, self.env.unwrapped)

    def set_perturb_prob(self, perturb_prob: float) -> None:
        self.adversary.perturb_prob = float(perturb_prob)

    def get_perturb_prob(self) -> float:
        return self.adversary.perturb_prob

    def warm_up(self) -> int:
        """Build what the first episode of each scenario would otherwise build (its road geometry, its queue of
        logged roll-outs), so timings see the steady state of a long run; returns the number of scenarios."""
        scenarios = self._scenario_env.scenarios
        reserve_road_cache(len({id(s.road) for s in scenarios}))
        for scenario in scenarios:
            get_road_geometry(scenario.road)
            self.history.queue(scenario)
        return len(scenarios)

    def get_state(self) -> dict[str, np.ndarray]:
        """This worker's roll-out queues (`RolloutHistory.get_state`) plus ``rng_state`` (0-d str: JSON of the
        env's numpy bit-generator state, which picks scenarios, curriculum draws and generator randomness) and
        ``last_scenario`` (0-d str: the scenario of the last episode, '' before the first; what a revisit replays)."""
        state = self.history.get_state()
        state["rng_state"] = np.array(json.dumps(self.env.unwrapped.np_random.bit_generator.state))
        state["last_scenario"] = np.array(self._last_scenario_id or "")
        return state

    def set_state(self, state: Mapping[str, np.ndarray], source: str = "closed-loop state") -> None:
        """Restore what `get_state` returned (queues in place, so the adversary keeps reading them)."""
        self.history.set_state(state, source)
        if "rng_state" in state:
            rng = self.env.unwrapped.np_random  # property: seeds a fresh generator when none exists yet
            rng.bit_generator.state = json.loads(str(np.asarray(state["rng_state"])))
        if "last_scenario" in state:
            self._last_scenario_id = str(np.asarray(state["last_scenario"])) or None

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        self.adversary.last = {}
        if (self.revisit_prob > 0.0 and self._last_scenario_id is not None and seed is None
                and "scenario_id" not in (options or {})
                and self._scenario_env.np_random.random() < self.revisit_prob):
            options = {**(options or {}), "scenario_id": self._last_scenario_id}
        obs, info = self.env.reset(seed=seed, options=options)
        scenario = self._scenario_env.scenario
        self._last_scenario_id = None if scenario is None else scenario.scenario_id
        info["adversary"] = dict(self.adversary.last) or {"generator": "given", "perturbed": False}
        self._episode_adversary = info["adversary"]
        return obs, info

    def step(self, action: Any) -> tuple[Any, SupportsFloat, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        rollout = info.get("rollout")
        scenario = self._scenario_env.scenario  # set by every reset, so present whenever an episode ends
        if rollout is not None and scenario is not None:
            self.history.append(scenario, rollout)
            info["rollout_digest"] = rollout_digest(rollout)
            info["episode_adversary"] = self._episode_adversary
        return obs, reward, terminated, truncated, info


def partition_scenarios(scenarios: Sequence[Scenario], n_workers: int) -> list[list[Scenario]]:
    """Deal ``scenarios`` round-robin to ``n_workers`` disjoint, non-empty parts (each scenario in exactly one)."""
    if n_workers < 1:
        raise ValueError(f"n_workers must be >= 1, got {n_workers}")
    if len(scenarios) < n_workers:
        raise ValueError(f"cannot split {len(scenarios)} scenarios across {n_workers} workers (each needs one)")
    return [list(scenarios[w::n_workers]) for w in range(n_workers)]


def closed_loop_env_fns(
    scenarios: Sequence[Scenario],
    n_workers: int,
    generator: str | None,
    generator_kwargs: Mapping[str, Any] | None = None,
    env_config: Mapping[str, Any] | None = None,
    k: int = K_ROLLOUTS,
    perturb_prob: float = 1.0,
    revisit_prob: float = 0.0,
) -> list[Callable[[], ClosedLoopEnv]]:
    """One env constructor per worker (for SB3 ``SubprocVecEnv`` / ``DummyVecEnv``), worker ``w`` playing only
    its part of `partition_scenarios`; the generator is built by name inside the worker."""
    parts = partition_scenarios(scenarios, n_workers)
    kwargs = dict(generator_kwargs or {})
    config = dict(env_config or {})

    def make(part: list[Scenario]) -> Callable[[], ClosedLoopEnv]:
        def build() -> ClosedLoopEnv:
            reserve_road_cache(len({id(s.road) for s in part}))  # every reset would else miss the cache
            gen = make_generator(generator, **kwargs) if generator is not None else None
            return ClosedLoopEnv(ScenarioEnv(part, config=config), gen, k=k, perturb_prob=perturb_prob,
                                 revisit_prob=revisit_prob)

        return build

    return [make(part) for part in parts]
