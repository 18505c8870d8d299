"""`GooseEnv`: the goal-conditioned Gymnasium env GOOSE's agent is trained in (SB3 + HER).

One episode = one scenario. On reset the scenario's logged adversary path gets its NURBS fit (`GooseCurve`) and
the agent observes a roll-out of the reactive heuristic ego (`seal.envs.heuristic.HeuristicDriver`) against the
logged (replayed) adversary, as a generator does after an unperturbed episode. Each step = one curve update:
the 12-d action edits control points 1..4, the adversary replays the re-timed curve in a full `ScenarioEnv`
episode against the heuristic ego, and the agent observes that roll-out. The achieved goal is measured on it
(`seal.adversaries.goose.goals`); the episode ends when the desired goal is reached (``terminated``) or after
``spec.max_updates`` updates (``truncated``).

The reset roll-out of a scenario is deterministic (deterministic ego, log replay), so it is computed once per
scenario and cached; with ``skip_solved`` scenarios whose logged adversary already reaches the goal are not
drawn (nothing to learn from them).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from seal.adversaries.goose.curve import N_ACTION, GooseCurve
from seal.adversaries.goose.goals import achieved_goal, goal_reached, goal_reward
from seal.adversaries.goose.obs import build_observation, observation_space
from seal.adversaries.goose.spec import GooseSpec
from seal.core.scenario import Scenario
from seal.envs.behaviors import AdversaryBehavior, ReplayBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv

_MAX_DRAWS = 1000


def simulate(sim: ScenarioEnv, driver: HeuristicDriver, scenario_id: str, adversary: AdversaryBehavior) -> Rollout:
    """One full episode of ``scenario_id`` in ``sim`` with ``driver`` as the ego; returns its `Rollout`."""
    obs, _ = sim.reset(options={"scenario_id": scenario_id, "adversary": adversary})
    done = False
    while not done:
        action, _ = driver.predict(obs, deterministic=True)
        obs, _, terminated, truncated, _ = sim.step(action)
        done = terminated or truncated
    assert sim.rollout is not None
    return sim.rollout


@dataclass(frozen=True)
class ScenarioStart:
    """How a GOOSE episode of one scenario starts.

    Attributes:
        curve: the NURBS fit of the logged adversary path (no edit).
        rollout: the heuristic ego's roll-out against the replayed logged adversary.
        achieved: its achieved goal ``[3]``.
        solved: whether that already reaches the desired goal.
    """

    curve: GooseCurve
    rollout: Rollout
    achieved: np.ndarray
    solved: bool


class GooseEnv(gym.Env):
    """GOOSE training env (see the module docstring).

    Args:
        scenarios: the scenarios episodes are drawn from (uniformly).
        spec: goal, action limits and observation layout.
        sim_config: overrides of the inner `ScenarioEnv` config (default: crash ends the episode).
        skip_solved: do not draw scenarios whose logged adversary already reaches the goal.
    """

    metadata = {"render_modes": []}

    def __init__(
        self, scenarios: Sequence[Scenario], spec: GooseSpec | None = None, sim_config: dict[str, Any] | None = None,
        skip_solved: bool = True,
    ) -> None:
        super().__init__()
        self.goose_spec = spec or GooseSpec()
        self.scenarios = list(scenarios)
        self._by_id = {s.scenario_id: s for s in self.scenarios}
        if not self.scenarios:
            raise ValueError("GooseEnv needs at least one scenario")
        self.sim = ScenarioEnv(self.scenarios, config={"terminate_on_crash": True, **(sim_config or {})})
        self.driver = HeuristicDriver()
        self.skip_solved = skip_solved
        self.observation_space = observation_space(self.goose_spec)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(N_ACTION,), dtype=np.float32)
        self._starts: dict[str, ScenarioStart] = {}
        self._started: dict[str, bool] = {}
        """Every scenario started so far: whether its logged adversary reached the goal (`start_counts`)."""
        self._curve: GooseCurve | None = None
        self._updates = 0
        self.last_rollout: Rollout | None = None

    # ------------------------------------------------------------------------------------------ scenarios
    def start(self, scenario_id: str) -> ScenarioStart:
        """Fitted curve and the reset roll-out (log replay) of a scenario, cached."""
        hit = self._starts.get(scenario_id)
        if hit is None:
            if scenario_id not in self._by_id:
                raise KeyError(f"GooseEnv has no scenario {scenario_id!r}")
            scenario = self._by_id[scenario_id]
            curve = GooseCurve.from_scenario(scenario, self.goose_spec.timing)
            rollout = simulate(self.sim, self.driver, scenario_id, ReplayBehavior())
            achieved = achieved_goal(rollout)
            hit = ScenarioStart(curve, rollout, achieved, bool(goal_reached(achieved, self.goose_spec.goal_array)))
            self._starts[scenario_id] = hit
            self._started[scenario_id] = hit.solved
        return hit

    def _draw(self) -> str:
        for _ in range(_MAX_DRAWS):
            sid = self.scenarios[int(self.np_random.integers(len(self.scenarios)))].scenario_id
            if not (self.skip_solved and self.start(sid).solved):
                return sid
        raise RuntimeError(f"GooseEnv: no unsolved scenario found in {_MAX_DRAWS} draws (all reach the goal already?)")

    # ------------------------------------------------------------------------------------------ gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        sid = (options or {}).get("scenario_id") or self._draw()
        start = self.start(sid)
        self._curve = start.curve
        self._updates = 0
        self.last_rollout = start.rollout
        obs = build_observation(self.goose_spec, start.curve, start.rollout, 0, start.achieved)
        return obs, {"scenario_id": sid, "is_success": start.solved, "solved_at_start": start.solved}

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._curve is None:
            raise RuntimeError("GooseEnv.step() before reset()")
        spec = self.goose_spec
        self._curve = self._curve.edited(action, spec)
        self._updates += 1
        rollout = simulate(self.sim, self.driver, self._curve.scenario_id, ReplayBehavior(self._curve.track()))
        self.last_rollout = rollout
        achieved = achieved_goal(rollout)
        obs = build_observation(spec, self._curve, rollout, self._updates, achieved)
        success = bool(goal_reached(achieved, spec.goal_array))
        reward = float(goal_reward(achieved, spec.goal_array, spec.reward))
        truncated = not success and self._updates >= spec.max_updates
        info = {
            "is_success": success, "scenario_id": self._curve.scenario_id, "updates": self._updates,
            "outcome": rollout.outcome, "achieved_goal": achieved.tolist(),
        }
        return obs, reward, success, truncated, info

    def compute_reward(
        self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any
    ) -> np.ndarray:
        """Vectorised goal reward (HER relabelling calls it with batches ``[B, 3]``)."""
        return goal_reward(achieved_goal, desired_goal, self.goose_spec.reward)

    @property
    def start_counts(self) -> tuple[int, int]:
        """(scenarios started so far, of which the logged adversary already reached the goal)."""
        return len(self._started), sum(self._started.values())

    @property
    def curve(self) -> GooseCurve | None:
        """The current curve of the running episode."""
        return self._curve

    # ------------------------------------------------------------------------------------------ resume
    def get_state(self) -> dict[str, np.ndarray]:
        """What `set_state` needs to go on exactly from here (``seal fit goose`` checkpoints): the env rng, the
        running episode (scenario, edited control points and weights, updates made) and which scenarios were
        started (solved or not, for `start_counts`). Numpy arrays only (saved with ``allow_pickle=False``)."""
        meta = {
            "rng": self.np_random.bit_generator.state, "updates": self._updates,
            "scenario_id": None if self._curve is None else self._curve.scenario_id,
            "started": self._started,
        }
        curve = self._curve
        return {
            "meta": np.array(json.dumps(meta)),
            "ctrl": np.zeros((0, 2)) if curve is None else np.asarray(curve.ctrl, dtype=np.float64),
            "weights": np.zeros(0) if curve is None else np.asarray(curve.weights, dtype=np.float64),
        }

    def set_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore `get_state`'s arrays. Start roll-outs are recomputed when a scenario comes up (deterministic)."""
        meta = json.loads(str(state["meta"]))
        self.np_random.bit_generator.state = meta["rng"]
        self._started.update({str(k): bool(v) for k, v in meta["started"].items()})
        self._updates = int(meta["updates"])
        sid = meta["scenario_id"]
        self._curve = None if sid is None else replace(
            self.start(sid).curve, ctrl=np.array(state["ctrl"], dtype=np.float64),
            weights=np.array(state["weights"], dtype=np.float64))
