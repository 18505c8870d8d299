"""Adversary behaviours: how the adversary moves in `ScenarioEnv`.

Each env step the env calls ``behavior.step(t, state, observation)`` to move the adversary from scenario step
``t`` to ``t + 1``. The behaviour answers with a `BehaviorOutput`: either a placement (the next state, or None
for "absent at t + 1") or a normalised action ``[steering, acceleration]`` that the env integrates with the
bicycle model (`seal.envs.kinematics`). The env builds the adversary's own observation (same builder as the ego's,
from the adversary's viewpoint, on the route `AdversaryBehavior.make_route` returns) only for behaviours with
``needs_observation = True``, and only on steps where `AdversaryBehavior.observes` says so.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar, Protocol

import numpy as np

from seal.core.scenario import CURRENT_STEP, DT_S, N_FUTURE, N_STEPS, VALID, Scenario
from seal.envs.kinematics import MAX_ACCEL_MPS2, MAX_BETA_RAD, MAX_STEER_RAD, AgentState, placement_state
from seal.envs.route import Route


@dataclass(frozen=True, slots=True)
class BehaviorOutput:
    """A behaviour's decision for one step: exactly one of ``state`` / ``action`` is set, or neither (absent).

    Attributes:
        state: placement at the next step (the env uses it as is).
        action: ``(steering, acceleration)`` normalised to [-1, 1], integrated by the bicycle model.
    """

    state: AgentState | None = None
    action: tuple[float, float] | None = None

    @classmethod
    def place(cls, state: AgentState) -> BehaviorOutput:
        return cls(state=state)

    @classmethod
    def absent(cls) -> BehaviorOutput:
        return cls()

    @classmethod
    def act(cls, steering: float, acceleration: float) -> BehaviorOutput:
        return cls(action=(float(steering), float(acceleration)))

class AdversaryBehavior(ABC):
    """How the adversary moves during one episode. `reset` is called at every env reset."""

    needs_observation: ClassVar[bool] = False
    """When True the env passes the adversary's own observation to `step` (else None)."""

    @abstractmethod
    def reset(self, scenario: Scenario, rng: np.random.Generator) -> None:
        """Prepare for an episode of ``scenario`` (the adversary starts at its logged state at CURRENT_STEP)."""

    @abstractmethod
    def step(self, t: int, state: AgentState | None, observation: np.ndarray | None) -> BehaviorOutput:
        """Decide the move from scenario step ``t`` to ``t + 1``.

        Args:
            t: current scenario step (``CURRENT_STEP`` on the first env step).
            state: the adversary's state at ``t``, None if it is absent.
            observation: its observation at ``t`` when `needs_observation` and `observes` (t), else None.
        """

    def observes(self, t: int) -> bool:
        """Whether `step` at scenario step ``t`` uses the observation (asked only when `needs_observation`);
        a behaviour that acts on it for part of the episode saves the cost of building it elsewhere."""
        return True

    def make_route(self, scenario: Scenario) -> Route:
        """Route used for the adversary's observation (default: its logged track)."""
        return Route.from_track(scenario.track(scenario.adv_id))

    @property
    def name(self) -> str:
        return type(self).__name__


class ReplayBehavior(AdversaryBehavior):
    """Replays a track exactly: the state at step ``t + 1`` is ``track[t + 1]``; absent where invalid or past
    the end of the track.

    Args:
        track: ``[T, 8]`` track in the scenario layout indexed by scenario step (T may differ from 91), or None
            for the scenario's logged adversary.
    """

    def __init__(self, track: np.ndarray | None = None) -> None:
        self._given = None if track is None else np.asarray(track, dtype=np.float64)
        self._track: np.ndarray | None = self._given

    def reset(self, scenario: Scenario, rng: np.random.Generator) -> None:
        self._track = (
            self._given if self._given is not None else scenario.track(scenario.adv_id).astype(np.float64)
        )

    def step(self, t: int, state: AgentState | None, observation: np.ndarray | None) -> BehaviorOutput:
        track = self._track
        assert track is not None, "reset() first"
        k = t + 1
        if k >= track.shape[0] or track[k, VALID] < 0.5:
            return BehaviorOutput.absent()
        return BehaviorOutput.place(placement_state(state, track[k]))


class TrackingBehavior(AdversaryBehavior):
    """Follows a timed xy trajectory with the bicycle model: pure pursuit for steering, a speed controller that
    keeps the vehicle on the trajectory's schedule for acceleration.

    After the trajectory ends the vehicle keeps following its last direction at its last speed.

    Args:
        trajectory: ``[T, >=2]`` positions (m), row ``k`` is the target position at scenario step
            ``start_step + k``.
        start_step: scenario step of row 0; default: 0 for 91-row trajectories, ``CURRENT_STEP + 1`` for 80-row
            trajectories (a predicted future), else ``CURRENT_STEP``.
        lookahead_s: pure-pursuit look-ahead time (s); the look-ahead distance is ``max(4 m, speed * it)``.
        schedule_tau_s: time constant (s) for catching up with the schedule.
    """

    def __init__(
        self, trajectory: np.ndarray, start_step: int | None = None, lookahead_s: float = 0.5,
        schedule_tau_s: float = 1.0,
    ) -> None:
        xy = np.asarray(trajectory, dtype=np.float64)[:, :2]
        if xy.shape[0] < 2:
            raise ValueError("a tracking trajectory needs at least 2 rows")
        if start_step is None:
            start_step = {N_STEPS: 0, N_FUTURE: CURRENT_STEP + 1}.get(xy.shape[0], CURRENT_STEP)
        self.xy = xy
        self.start_step = int(start_step)
        self.lookahead_s = lookahead_s
        self.tau = schedule_tau_s
        step_len = np.hypot(*np.diff(xy, axis=0).T)
        self._s_rows = np.concatenate([[0.0], np.cumsum(step_len)])
        self._v_last = float(step_len[-1] / DT_S)
        self._path = Route(xy, np.concatenate([step_len, step_len[-1:]]) / DT_S)
        self._hint: int | None = None

    def reset(self, scenario: Scenario, rng: np.random.Generator) -> None:
        self._hint = None

    def _s_ref(self, step: int) -> float:
        k = step - self.start_step
        last = len(self._s_rows) - 1
        if k <= 0:
            return float(self._s_rows[0]) + min(k, 0) * float(self._s_rows[1] - self._s_rows[0])
        if k >= last:
            return float(self._s_rows[-1]) + (k - last) * self._v_last * DT_S
        return float(self._s_rows[k])

    def step(self, t: int, state: AgentState | None, observation: np.ndarray | None) -> BehaviorOutput:
        if state is None:
            return BehaviorOutput.absent()
        return BehaviorOutput.act(*self.control(t, state))

    def control(self, t: int, state: AgentState) -> tuple[float, float]:
        """Normalised (steering, acceleration) moving ``state`` from step ``t`` toward the trajectory."""
        proj = self._path.project(state.x, state.y, self._hint)
        self._hint = proj.segment
        # Route arc length starts at the first row, as `_s_rows` does (the route dedups repeated rows, which
        # changes neither).
        s_now = proj.s
        v = state.speed
        v_ref = (self._s_ref(t + 2) - self._s_ref(t + 1)) / DT_S
        err = self._s_ref(t + 1) - (s_now + v * DT_S)
        v_cmd = max(0.0, v_ref + err / self.tau)
        accel = (v_cmd - v) / (DT_S * MAX_ACCEL_MPS2)
        steering = pure_pursuit_steering(self._path, proj.s, state, max(4.0, v * self.lookahead_s))
        return steering, min(1.0, max(-1.0, accel))


def pure_pursuit_steering(path: Route, s: float, state: AgentState, lookahead_m: float) -> float:
    """Normalised steering that puts the bicycle's path through the route point ``lookahead_m`` ahead of ``s``.

    With constant steering the heading turns at ``sin(beta) / (length / 2)`` per metre; pure pursuit asks for
    curvature ``2 sin(alpha) / L_d`` (alpha: bearing of the look-ahead point from the heading).
    """
    px, py = path.point_at(s + lookahead_m)
    dx, dy = px - state.x, py - state.y
    dist = max(math.hypot(dx, dy), 1e-3)
    alpha = math.atan2(dy, dx) - state.heading
    curvature = 2.0 * math.sin(alpha) / dist
    sin_beta = min(math.sin(MAX_BETA_RAD), max(-math.sin(MAX_BETA_RAD), curvature * state.length / 2))
    delta = math.atan(2.0 * math.tan(math.asin(sin_beta)))
    return min(1.0, max(-1.0, delta / MAX_STEER_RAD))


class Policy(Protocol):
    """SB3-style policy: ``predict(obs, deterministic=True) -> (action, state)``."""

    def predict(self, observation: np.ndarray, *args: Any, **kwargs: Any) -> tuple[np.ndarray, Any]: ...


class PolicyBehavior(AdversaryBehavior):
    """A reactive adversary: ``policy`` sees the adversary's own observation and returns a normalised action.

    Args:
        policy: anything with SB3's ``predict(obs, deterministic=True)`` (an SB3 model, `HeuristicDriver`).
        route_track: ``[T, >=2]`` route for the adversary's observation (navigation, route slots); default its
            logged track.
        deterministic: passed to ``predict``.
    """

    needs_observation = True

    def __init__(self, policy: Policy, route_track: np.ndarray | None = None, deterministic: bool = True) -> None:
        self.policy = policy
        self.route_track = None if route_track is None else np.asarray(route_track, dtype=np.float64)
        self.deterministic = deterministic
        self._state: Any = None
        self._start = True

    def reset(self, scenario: Scenario, rng: np.random.Generator) -> None:
        self._state = None
        self._start = True

    def make_route(self, scenario: Scenario) -> Route:
        if self.route_track is None:
            return super().make_route(scenario)
        if self.route_track.shape[1] >= 8:
            return Route.from_track(self.route_track)
        return Route(self.route_track[:, :2])

    def step(self, t: int, state: AgentState | None, observation: np.ndarray | None) -> BehaviorOutput:
        if state is None or observation is None:
            return BehaviorOutput.absent()
        action, self._state = self.policy.predict(
            observation, state=self._state, episode_start=np.array([self._start]), deterministic=self.deterministic
        )
        self._start = False
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        return BehaviorOutput.act(a[0], a[1])
