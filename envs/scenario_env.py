"""`ScenarioEnv`: closed-loop replay of a `Scenario` with a policy-driven ego and a behaviour-driven adversary.

Episode: starts at ``CURRENT_STEP`` (10) with every agent at its logged state. Each ``step(action)`` advances
scenario time by one 10 Hz step:

1. the ego integrates the policy's action ``[steering, acceleration]`` in ``[-1, 1]^2`` with the kinematic
   bicycle (`seal.envs.kinematics`: +-pi/3 rad steering, +-6 m/s^2, speed clipped to [0, 40] m/s);
2. the adversary moves as its `AdversaryBehavior` says (default: `ReplayBehavior` of its log);
3. every other agent is placed at its logged state of the new step (present while ``valid``; after its log
   ends - the 91 logged steps - it is gone) with ``background: replay`` (the default); with ``idm`` or ``rapid``
   it is moved by a `seal.envs.background.BackgroundController` from the box table of the step before (so it
   reacts to the ego and the adversary), with the same lifetime;
4. collisions (oriented-box overlap), road checks, reward and the ego's observation are computed (with the
   adversary's own, for a behaviour that acts on it next step, in the same pass: `ObservationBuilder.build_many`).

Route: the logged ego track (all valid steps) as a polyline. ``route_completion`` = arc-length progress from the
ego's start position (step 10) divided by the distance from there to the end of the logged track.

Reward (CAT / MetaDrive defaults, computed by `seal.envs.sim_core.reward_terms`): ``progress_reward`` (1) per metre
of progress along the route (negative when going back); on a step where something happens it is replaced by, in
this priority, ``-out_of_road_penalty`` (-10), ``-crash_penalty`` (-1, on every step the ego overlaps another agent),
``+success_reward`` (+10). The terms are reported by name in ``info["reward_terms"]``; the reward is their sum.

Termination (``terminated``): success when ``route_completion > success_completion`` (0.95) on a step without
crash or out-of-road; out of road when an ego box corner leaves the drivable area (union of lane polygons) by
more than ``offroad_tolerance_m`` (0.5 m: where consecutive lanes meet at an angle, e.g. roundabout entries,
their polygons leave a notch that logged vehicles cut by up to ~0.4 m; road edges painted ``continuous`` end
the episode at the line anyway), the box crosses a ``continuous`` line (except those the logged ego itself
crosses, so a route through a painted-solid junction is drivable), or the ego is more than ``max_lateral_m``
(10 m) from the route; a crash when ``terminate_on_crash`` (default True; when False the episode goes on and
every step in contact costs ``crash_penalty``). ``truncated`` after ``horizon_steps`` (default 90 = the 80
logged future steps + 1 s of grace for an ego that is slower than the log; agents without log beyond step 90
are gone by then).

``info`` on every step: ``is_success``, ``crashed``, ``out_of_road``, ``route_completion``, ``crash_agent_id``
(id of an agent the ego overlaps, -1 if none), ``crashed_with_adversary``, ``adversary_crashed`` (the adversary
overlaps a third agent), ``scenario_id``, ``step`` (scenario step); after a step also ``reward_terms``
(`seal.envs.sim_core.REWARD_TERMS` -> value). On the last step also ``rollout`` (`seal.envs.rollout.Rollout`) and
``outcome`` (a `seal.core.outcome.Outcome`).

This module is the Gymnasium adapter; placement, collisions, road checks, reward terms and outcomes are the
simulation core's (`seal.envs.sim_core`), shared with `seal.envs.multi_agent.MultiAgentSim`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from seal.core.outcome import Outcome
from seal.core.road_area import OFFROAD_TOLERANCE_M
from seal.core.scenario import CURRENT_STEP, VALID, Scenario
from seal.envs.background import BACKGROUND_KINDS, BackgroundController, IDMBackground
from seal.envs.behaviors import AdversaryBehavior, BehaviorOutput, ReplayBehavior
from seal.envs.deadline import deadline_features
from seal.envs.kinematics import AgentState, bicycle_step
from seal.envs.observation import ObservationBuilder, observation_space
from seal.envs.road_geometry import RoadGeometry, get_road_geometry
from seal.envs.rollout import Rollout
from seal.envs.route import Route, RouteProjection
from seal.envs.sim_core import (
    RewardConfig,
    RoadChecks,
    StepEvents,
    box_hits,
    episode_outcome,
    logged_rows,
    reward_terms,
    state_row,
    total_reward,
)

DEFAULT_CONFIG: dict[str, Any] = {
    "horizon_steps": 90,
    "terminate_on_crash": True,
    "success_completion": 0.95,
    "max_lateral_m": 10.0,
    "progress_reward": 1.0,
    "success_reward": 10.0,
    "out_of_road_penalty": 10.0,
    "crash_penalty": 1.0,
    "check_continuous_lines": True,
    "offroad_tolerance_m": OFFROAD_TOLERANCE_M,
    "split": None,
    "background": "replay",
}
"""Config keys (see the module docstring):

* ``horizon_steps``: env steps before ``truncated`` (90 = 8 s of log + 1 s grace).
* ``terminate_on_crash``: end the episode on an ego crash (evaluation) or go on with the penalty (CAT training).
* ``success_completion``: route completion above which the ego has arrived (0.95).
* ``max_lateral_m``: distance from the route beyond which the ego is out of road (10 m).
* ``progress_reward``, ``success_reward``, ``out_of_road_penalty``, ``crash_penalty``: reward terms (1, 10, 10, 1).
* ``check_continuous_lines``: crossing a ``continuous`` line is out of road (True).
* ``offroad_tolerance_m``: how far a box corner may stick out of the drivable area (0.5 m).
* ``split``: dataset split to load when ``scenarios`` is a dataset path (None = all).
* ``background``: how the agents other than the ego and the adversary move: ``replay`` (their log, the default),
  ``idm`` (`seal.envs.background.IDMBackground`) or ``rapid`` (the learned model given as ``background_model``).
"""

AdversarySpec = AdversaryBehavior | Callable[[Scenario, np.random.Generator], AdversaryBehavior] | None
"""An adversary for every episode: a behaviour (reset each episode), a factory ``(scenario, rng) -> behaviour``
called at each reset (e.g. a generator with a curriculum), or None for `ReplayBehavior` of the log."""

def _checked_action(action: Any) -> tuple[float, float]:
    """The action as (steering, acceleration). Finite values outside [-1, 1] are clipped by
    the kinematic step (Gymnasium's convention for Box actions); a wrong shape, or NaN / inf, raises ValueError
    (they used to become full lock and full brake without a word)."""
    try:
        a = np.asarray(action, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"ScenarioEnv.step: action must be 2 numbers [steering, acceleration], got {action!r}"
        ) from None
    if a.size != 2 or a.ndim > 2:
        raise ValueError(f"ScenarioEnv.step: action must have shape (2,) [steering, acceleration], got shape {a.shape}")
    steering, acceleration = a.flat  # two scalar checks: cheaper than an array reduction on every step
    if not (math.isfinite(steering) and math.isfinite(acceleration)):
        raise ValueError(f"ScenarioEnv.step: action must be finite, got {a.reshape(2).tolist()}")
    return float(steering), float(acceleration)


def _background_controller(kind: object, model: BackgroundController | None) -> BackgroundController | None:
    """The controller of the ``background`` option (None for replay); a clear error for a wrong combination."""
    if kind not in BACKGROUND_KINDS:
        raise ValueError(f"ScenarioEnv config background must be one of {list(BACKGROUND_KINDS)}, got {kind!r}")
    if kind == "rapid":
        if model is None:
            raise ValueError("ScenarioEnv background 'rapid' needs background_model (seal.models.rapid.load_rapid)")
        return model
    if model is not None:
        raise ValueError(f"ScenarioEnv background_model is only used with background 'rapid', not {kind!r}")
    return IDMBackground() if kind == "idm" else None


class ScenarioEnv(gym.Env):
    """Gymnasium env over a set of scenarios (see the module docstring).

    Args:
        scenarios: scenarios to play, a single scenario, or a dataset directory (loaded with `seal.core.dataset`,
            ``config["split"]`` selecting a split).
        config: overrides of `DEFAULT_CONFIG`.
        adversary: see `AdversarySpec`; change it later with `set_adversary`, or for one episode with
            ``reset(options={"adversary": behavior})``.
        render_mode: None or ``"rgb_array"`` (top-down frame following the ego, `seal.envs.render`).
        background_model: the controller of ``background: rapid`` (`seal.models.rapid.RapidBackground`); with
            another ``background`` it must be None.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    # Episode state, set by `_setup` at every reset (declared here for the type checker).
    _scen: Scenario
    """The scenario of the current episode (`scenario` without the None of before the first reset)."""
    _t: int
    """Current scenario step."""
    _ego: AgentState
    _adv: AgentState | None
    """None once the adversary's behaviour has removed it."""
    _adv_route: Route | None
    """The adversary's route, when its behaviour acts on its own observation."""
    _out_of_road_step: int | None
    _success_step: int | None
    _return: float
    _done: bool

    def __init__(
        self,
        scenarios: Sequence[Scenario] | Scenario | str | Path,
        config: dict[str, Any] | None = None,
        adversary: AdversarySpec = None,
        render_mode: str | None = None,
        background_model: BackgroundController | None = None,
    ) -> None:
        super().__init__()
        unknown = set(config or {}) - set(DEFAULT_CONFIG)
        if unknown:
            raise ValueError(f"unknown ScenarioEnv config keys {sorted(unknown)}; known: {sorted(DEFAULT_CONFIG)}")
        self.config = {**DEFAULT_CONFIG, **(config or {})}
        self._background = _background_controller(self.config["background"], background_model)
        if isinstance(scenarios, str | Path):
            from seal.core.dataset import load_scenarios

            scenarios = load_scenarios(scenarios, split=self.config["split"])
        elif isinstance(scenarios, Scenario):
            scenarios = [scenarios]
        self.scenarios: list[Scenario] = list(scenarios)
        if not self.scenarios:
            raise ValueError("ScenarioEnv needs at least one scenario")
        self._by_id = {s.scenario_id: s for s in self.scenarios}
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.observation_space = observation_space()
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self._adversary: AdversarySpec = adversary
        self._exempt_cache: dict[tuple[str, int], np.ndarray] = {}
        self._route_cache: dict[int, tuple[Scenario, Route]] = {}
        """Ego routes by scenario object identity (the entry keeps the object, so its id is not reused)."""
        self._renderer: Any = None
        self.scenario: Scenario | None = None
        self.rollout: Rollout | None = None
        """The `Rollout` of the last finished episode."""

    # ----------------------------------------------------------------------------------------- public API
    @property
    def scenario_ids(self) -> list[str]:
        return [s.scenario_id for s in self.scenarios]

    def set_adversary(self, adversary: AdversarySpec) -> None:
        """Adversary used from the next reset on (see `AdversarySpec`)."""
        self._adversary = adversary

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        sid = options.get("scenario_id")
        if sid is not None:
            if sid not in self._by_id:
                raise KeyError(f"ScenarioEnv has no scenario {sid!r}")
            scenario = self._by_id[sid]
        else:
            scenario = self.scenarios[int(self.np_random.integers(len(self.scenarios)))]
        adversary = options.get("adversary")
        if adversary is None:
            spec = self._adversary
            if spec is None:
                adversary = ReplayBehavior()
            elif isinstance(spec, AdversaryBehavior):
                adversary = spec
            else:
                adversary = spec(scenario, self.np_random)
        self._setup(scenario, adversary)
        obs = self._observe()
        return obs, self._info(StepEvents())

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError("step() called on a finished episode; call reset()")
        cfg = self.config
        steering, acceleration = _checked_action(action)
        ego = bicycle_step(self._ego, steering, acceleration)
        adv = self._move_adversary(self._t)
        background = None if self._background is None else self._background.step(self._t, self._cur)
        self._t = t = self._t + 1
        self._ego, self._adv = ego, adv
        self._place_agents(t, background)
        crashed, crash_id = self._ego_collisions(t, ego)
        adv_crashed = self._adv_collisions(t, adv)
        progress, out_of_road = self._road_progress(ego)
        success = self._route.completion(self._proj.s) > cfg["success_completion"] and not crashed and not out_of_road
        events = StepEvents(crashed, crash_id, adv_crashed, out_of_road, success)
        terms = reward_terms(self._weights, progress, events)
        reward = total_reward(terms)
        if out_of_road:
            self._out_of_road_step = t
        elif success:
            self._success_step = t
        terminated = bool(out_of_road or success or (crashed and cfg["terminate_on_crash"]))
        truncated = bool(not terminated and t - CURRENT_STEP >= cfg["horizon_steps"])
        self._return += reward

        obs = self._observe(last=terminated or truncated)
        info = self._info(events)
        info["reward_terms"] = terms
        if terminated or truncated:
            self._done = True
            info["rollout"] = self.rollout = self._finish(episode_outcome(events))
            info["outcome"] = self.rollout.outcome
        return obs, reward, terminated, truncated, info

    def deadline_features(self) -> np.ndarray:
        """The ego's time left and required speed ``[2]`` (`seal.envs.deadline`) at the current step."""
        cfg = self.config
        return deadline_features(self._route, self._proj.s, self._t, cfg["horizon_steps"], cfg["success_completion"])

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        from seal.envs.render import FrameRenderer

        if self._renderer is None or self._renderer.road is not self._scen.road:
            self._renderer = FrameRenderer(self._scen.road)
        return self._renderer.draw_state(
            self._cur, self._ego_idx, self._adv_idx, follow=(self._ego.x, self._ego.y),
            text=f"step {self._t}  speed {self._ego.speed:.1f} m/s",
        )

    # ----------------------------------------------------------------------------------------- internals
    def _setup(self, scenario: Scenario, behavior: AdversaryBehavior) -> None:
        self.scenario = self._scen = scenario
        self._geom: RoadGeometry = get_road_geometry(scenario.road)
        cfg = self.config
        self._road = RoadChecks(
            self._geom, cfg["max_lateral_m"], cfg["offroad_tolerance_m"], bool(cfg["check_continuous_lines"])
        )
        self._weights = RewardConfig(
            cfg["progress_reward"], cfg["success_reward"], cfg["out_of_road_penalty"], cfg["crash_penalty"]
        )
        self._builder = ObservationBuilder(self._geom)
        self._log = scenario.tracks.astype(np.float64)
        n_agents = scenario.n_agents
        self._agent_ids = scenario.agent_ids
        self._ego_idx = scenario.ego_index
        self._adv_idx = scenario.adv_index
        idx = np.arange(n_agents)
        self._not_ego = idx != self._ego_idx
        self._not_ego_adv = self._not_ego & (idx != self._adv_idx)
        ego_track = self._log[self._ego_idx]
        self._route = self._ego_route(scenario, ego_track)
        self._exempt = self._exempt_for(scenario, ego_track) if self.config["check_continuous_lines"] else None

        if self._background is not None:
            self._background.reset(scenario, self.np_random, self._not_ego_adv)
        self._behavior = behavior
        behavior.reset(scenario, self.np_random)
        self._adv_route = behavior.make_route(scenario) if behavior.needs_observation else None
        self._adv_hint: int | None = None
        self._adv_obs: np.ndarray | None = None
        """The adversary's observation of the current step, built with the ego's (`_observe`)."""

        t = CURRENT_STEP
        self._t = t
        self._ego = AgentState.from_track_row(self._log[self._ego_idx, t])
        self._adv = AgentState.from_track_row(self._log[self._adv_idx, t])
        self._proj: RouteProjection = self._route.project(self._ego.x, self._ego.y, self._route.start_segment)
        if self._adv_route is not None:
            self._adv_hint = self._adv_route.project(self._adv.x, self._adv.y).segment

        n_cols = CURRENT_STEP + 1 + int(self.config["horizon_steps"])
        self._roll = np.zeros((n_agents, n_cols, 8), dtype=np.float32)
        self._roll[:, : t + 1] = scenario.tracks[:, : t + 1]
        self._cur = self._log[:, t].copy()
        self._present = self._cur[:, VALID] > 0.5
        self._others_ego = np.flatnonzero(self._present & self._not_ego)
        self._ego_crashes: list[tuple[int, int]] = []
        self._adv_crashes: list[tuple[int, int]] = []
        self._out_of_road_step = None
        self._success_step = None
        self._return = 0.0
        self._done = False

    def _ego_route(self, scenario: Scenario, ego_track: np.ndarray) -> Route:
        """The ego's route (its logged track from `CURRENT_STEP`), cached per scenario: a route is immutable and
        building one walks the track in Python (most of a reset's cost otherwise)."""
        key = id(scenario)
        hit = self._route_cache.get(key)
        if hit is None or hit[0] is not scenario:
            if len(self._route_cache) > 4096:
                self._route_cache.clear()
            hit = (scenario, Route.from_track(ego_track, CURRENT_STEP))
            self._route_cache[key] = hit
        return hit[1]

    def _exempt_for(self, scenario: Scenario, ego_track: np.ndarray) -> np.ndarray | None:
        """Solid-line segments the logged ego box crosses (cached per scenario and road)."""
        key = (scenario.scenario_id, id(self._geom))
        hit = self._exempt_cache.get(key)
        if hit is None:
            v = ego_track[:, VALID] > 0.5
            hit = self._geom.continuous_hits_along(ego_track[v][:, [0, 1, 2, 5, 6]])
            if len(self._exempt_cache) > 4096:
                self._exempt_cache.clear()
            self._exempt_cache[key] = hit
        return hit if hit.any() else None

    def _move_adversary(self, t: int) -> AgentState | None:
        behavior, adv = self._behavior, self._adv
        obs = None
        if behavior.needs_observation and adv is not None and behavior.observes(t):
            obs = self._adv_obs
            if obs is None:
                raise RuntimeError(f"ScenarioEnv: no adversary observation was built for step {t}")
        self._adv_obs = None
        out: BehaviorOutput = behavior.step(t, adv, obs)
        if out.action is not None:
            return None if adv is None else bicycle_step(adv, out.action[0], out.action[1])
        return out.state

    def _place_agents(self, t: int, background: np.ndarray | None = None) -> None:
        """The box table of step ``t``: logged rows, the background controller's ``background`` rows ``[A, 8]``
        for the agents it drives (None: replay), the ego's and the adversary's states."""
        cur = logged_rows(self._log, t)
        if background is not None:
            cur[self._not_ego_adv] = background[self._not_ego_adv]
        cur[self._ego_idx] = state_row(self._ego)
        cur[self._adv_idx] = state_row(self._adv) if self._adv is not None else 0.0
        self._cur = cur
        self._present = cur[:, VALID] > 0.5
        self._others_ego = np.flatnonzero(self._present & self._not_ego)
        if t < self._roll.shape[1]:
            self._roll[:, t] = cur

    def _ego_collisions(self, t: int, ego: AgentState) -> tuple[bool, int]:
        """(crashed, crash id: the adversary's when among the agents hit, else the first one's); logs the hits."""
        hits = box_hits(ego, self._cur, self._others_ego)
        if not hits.size:
            return False, -1
        ids = self._agent_ids[hits]
        adv_hit = np.flatnonzero(hits == self._adv_idx)
        crash_id = int(self._agent_ids[self._adv_idx]) if adv_hit.size else int(ids[0])
        self._ego_crashes.extend((t, int(i)) for i in ids)
        return True, crash_id

    def _adv_collisions(self, t: int, adv: AgentState | None) -> bool:
        """Whether the adversary hit a third agent (not the ego; never without an adversary); logs the hits."""
        if adv is None:
            return False
        hits = box_hits(adv, self._cur, np.flatnonzero(self._present & self._not_ego_adv))
        if hits.size:
            self._adv_crashes.extend((t, int(i)) for i in self._agent_ids[hits])
        return bool(hits.size)

    def _road_progress(self, ego: AgentState) -> tuple[float, bool]:
        """(route progress of this step in m, out of road); advances the ego's route projection."""
        proj = self._route.project(ego.x, ego.y, self._proj.segment)
        progress = proj.s - self._proj.s
        self._proj = proj
        road = self._road
        out_of_road = (
            road.too_far(proj.lateral) or not road.corners_on_road(ego) or road.crosses_solid(ego, self._exempt)
        )
        return progress, out_of_road

    def _finish(self, outcome: Outcome) -> Rollout:
        """The `Rollout` of the episode that ends now with ``outcome``."""
        return Rollout(
            scenario_id=self._scen.scenario_id,
            tracks=self._roll,
            agent_ids=self._agent_ids.copy(),
            ego_id=self._scen.ego_id,
            adv_id=self._scen.adv_id,
            last_step=self._t,
            outcome=outcome,
            ego_crashes=self._ego_crashes,
            adv_crashes=self._adv_crashes,
            out_of_road_step=self._out_of_road_step,
            success_step=self._success_step,
            route_completion=float(self._route.completion(self._proj.s)),
            episode_return=float(self._return),
            adversary=self._behavior.name,
        )

    def _observe(self, last: bool = False) -> np.ndarray:
        """The ego's observation of the current step; when the adversary will act on its own observation this
        step (not on the ``last`` step of an episode), that one too, kept for `_move_adversary`. Both read the whole
        box table (`build_many`: absent rows and each viewer's own row are left out)."""
        adv, behavior, adv_route = self._adv, self._behavior, self._adv_route
        builder, cur = self._builder, self._cur
        if adv is not None and adv_route is not None:  # an adversary that observes (`_setup`)
            # Project every step (cheap) so the hinted projection keeps up with the adversary even on steps that
            # skip its observation.
            proj = adv_route.project(adv.x, adv.y, self._adv_hint)
            self._adv_hint = proj.segment
            if not last and behavior.observes(self._t):
                both = builder.build_many(
                    (self._ego, adv), (self._route, adv_route), (self._proj, proj), cur,
                    (self._ego_idx, self._adv_idx),
                )
                self._adv_obs = both[1]
                return both[0]
        return builder.build_many((self._ego,), (self._route,), (self._proj,), cur, (self._ego_idx,))[0]

    def _info(self, events: StepEvents) -> dict[str, Any]:
        return {
            "is_success": bool(events.success),
            "crashed": bool(events.crashed),
            "out_of_road": bool(events.out_of_road),
            "route_completion": float(self._route.completion(self._proj.s)),
            "crash_agent_id": int(events.crash_id),
            "crashed_with_adversary": bool(events.crashed and events.crash_id == int(self._agent_ids[self._adv_idx])),
            "adversary_crashed": bool(events.adv_crashed),
            "scenario_id": self._scen.scenario_id,
            "step": int(self._t),
        }
