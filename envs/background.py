"""Background traffic: how the agents other than the ego and the adversary move in `ScenarioEnv`.

``background: replay`` (the default) places every background agent at its logged row (`ScenarioEnv` does not
call this module at all then, so replay is unchanged bit for bit). The other kinds are `BackgroundController`
objects that move all background agents at once, one 10 Hz step at a time, from the box table of the current step
(``cur [A, 8]``, track layout, the ego and the adversary included, so background traffic reacts to both):

* `IDMBackground` (``idm``): each agent follows its logged route (`seal.envs.route.Route`) with IDM+
  longitudinal control (`seal.envs.car_following.idm_plus_acceleration`: highway-env's ``IDMVehicle`` constants),
  braking for its obstacles (`seal.envs.car_following.obstacle_gaps`: the box ahead, a car cutting in or crossing
  first, the ego included). Its desired speed follows the log step by step (`Intent.desired_at`) and its time
  headway is the one it keeps in its log (`seal.envs.car_following.logged_time_headway`, at most highway-env's
  1.5 s), so that, with nothing unusual ahead, it drives like the logged car it replaces; and once it has
  braked for something the log did not have, its desired speed is raised toward its logged schedule
  (`SCHEDULE_GAIN_PER_S`, at most `SCHEDULE_MAX_MPS`) so that it, and the queue behind it, do not stay behind
  their logs for the rest of the episode. On 100 validation
  scenarios (pool2500 train split 300-399, not used to fit anything) the Replay ego (the logged ego, open loop)
  crashed in 0.07 of the episodes with replayed background and, with IDM background, in 0.22 with a constant
  desired speed (mean logged speed: a car that stops later in its log brakes at once), 0.16 with the step-wise
  one, 0.13 with the logged headway, 0.09 with IDM+ (plain IDM's equilibrium gap runs away near the desired
  speed, so followers drop back from their logged queue and the ego behind runs into them), 0.08 with the schedule
  correction; the heuristic ego 0.09 (replay) and 0.14 / 0.12 / 0.10 / 0.07 / 0.06. On the decisive run's 300
  eval scenarios the Replay ego's crash rate with IDM background fell from 0.137 to 0.107 with the correction
  (0.087 with replayed background), its crashes into background cars from 26 to 15 (9);
* `ConstantVelocityBackground`: keeps each agent's velocity (the reference of `seal eval background`);
* ``rapid``: `seal.models.rapid.RapidBackground`, the learned next-step acceleration model (a subclass of
  `SimulatedBackground`, passed to the env as ``background_model``).

Lifetime is the log's in every kind: a simulated agent is present at step ``t`` while its log is valid at ``t``;
it enters at its logged row of the first valid step and is gone after its last one. Intent (`Intent`): a desired
speed (m/s) and a destination (map frame, m) per agent, by default the agent's logged speed (the mean over the
next 3 s of its log at each step, `logged_desired_speed`: what the RAPID model is trained with) and the end of
its logged track; `SimulatedBackground.set_intent` overrides them per agent.

The adversary is not background: in the Normal setting (and ``normal-reactive``) it replays its log whatever the
``background`` option. It is the scenario's designated interaction partner, the same track every generator's
perturbation replaces, so its crashes stay comparable between the replay and the reactive settings and between
Normal and the generator settings; a reactive adversary would also change what "Normal" measures against. Its
hits on the ego are reported apart from the background's (`seal.envs.rollout.Rollout.rear_end_by_background`
leaves the adversary out). Measured on the 100 eval scenarios, the adversary's hits on the Replay ego were the
same with replayed and reactive background (9 vs 8-9), so the reactive background does not cause them.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, LENGTH, N_STEPS, VALID, VX, VY, WIDTH, Scenario, X, Y
from seal.envs.car_following import (  # noqa: F401  (leader_gaps, idm_acceleration: re-exported)
    IDM_TIME_WANTED_S,
    LEADER_RANGE_M,
    PATH_MARGIN_M,
    idm_acceleration,
    idm_plus_acceleration,
    leader_gaps,
    logged_time_headway,
    obstacle_gaps,
)
from seal.envs.kinematics import MAX_SPEED_MPS
from seal.envs.route import Route

BACKGROUND_KINDS = ("replay", "idm", "rapid")
"""Values of `ScenarioEnv`'s ``background`` option."""

INTENT_SPEED_WINDOW = 30
"""Steps (3 s) over which the logged desired speed of a step is averaged (the RAPID model's training intent)."""
INTENT_MIN_STEPS = 5
"""Fewer logged steps than this in the window: no logged desired speed for that step."""


def logged_desired_speed(log: np.ndarray, valid: np.ndarray, t: int, rows: np.ndarray) -> np.ndarray:
    """``[len(rows)]`` mean logged speed (m/s) of each agent over steps ``t + 1 .. t + INTENT_SPEED_WINDOW``
    (NaN where fewer than `INTENT_MIN_STEPS` of them are logged): the desired speed the RAPID model is trained
    with at step ``t`` and that `Intent.desired_at` gives a background agent whose speed nobody set."""
    window = slice(t + 1, min(t + 1 + INTENT_SPEED_WINDOW, N_STEPS))
    spd = np.hypot(log[rows, window, VX], log[rows, window, VY])
    ok = valid[rows, window]
    n = ok.sum(axis=1)
    return np.where(n >= INTENT_MIN_STEPS, (spd * ok).sum(axis=1) / np.maximum(n, 1), np.nan)


@dataclass
class Intent:
    """Per-agent intent of one episode (rows of the scenario's tracks).

    Attributes:
        desired_speed_mps: ``[A]`` desired speed (m/s) for the whole episode; NaN where unknown. Used as given
            where `speed_set`; otherwise `desired_at` follows the log step by step and falls back to it.
        destination_xy: ``[A, 2]`` destination in the map frame (m); NaN where unknown.
        log: ``[A, T, 8]`` the logged tracks the step-wise desired speed is read from (None: none); valid:
            their ``[A, T]`` validity.
        speed_set: ``[A]`` True where a user set the desired speed (`SimulatedBackground.set_intent`).
    """

    desired_speed_mps: np.ndarray
    destination_xy: np.ndarray
    log: np.ndarray | None = None
    speed_set: np.ndarray | None = None
    valid: np.ndarray | None = None
    _logged: np.ndarray | None = field(default=None, repr=False, compare=False)

    @classmethod
    def from_log(cls, scenario: Scenario) -> Intent:
        """The logged intent: mean logged speed after `CURRENT_STEP` (all valid steps when none) and the last
        valid position of each agent's track; step by step, `logged_desired_speed`."""
        tracks = scenario.tracks.astype(np.float64)
        valid = tracks[:, :, VALID] > 0.5
        speed = np.hypot(tracks[:, :, VX], tracks[:, :, VY])
        future = valid.copy()
        future[:, : CURRENT_STEP + 1] = False
        use = np.where(future.any(axis=1, keepdims=True), future, valid)
        n = np.maximum(use.sum(axis=1), 1)
        desired = np.where(use.any(axis=1), (speed * use).sum(axis=1) / n, np.nan)
        last = np.where(valid.any(axis=1), valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1), 0)
        dest = tracks[np.arange(len(tracks)), last][:, [X, Y]]
        dest[~valid.any(axis=1)] = np.nan
        return cls(desired, dest, tracks, np.zeros(len(tracks), dtype=bool), valid)

    def set_speed(self, row: int, desired_speed_mps: float) -> None:
        """Command agent ``row``'s desired speed (m/s) for the rest of the episode."""
        self.desired_speed_mps[row] = float(desired_speed_mps)
        if self.speed_set is not None:
            self.speed_set[row] = True

    def desired_at(self, t: int, rows: np.ndarray) -> np.ndarray:
        """``[len(rows)]`` desired speed (m/s) at step ``t``: the commanded one where set, else the log's
        (`logged_desired_speed`: a car that stops at a junction in its log wants to stop there, one that speeds
        up wants to speed up), else `desired_speed_mps`; NaN where none is known."""
        fixed = self.desired_speed_mps[rows]
        if self.log is None or self.speed_set is None or self.valid is None:
            return fixed
        if self._logged is None:
            # every step's logged desired speed at once, on the first call: the per-step window average was a
            # per-agent cost of every env step (the same numbers, `logged_desired_speed` per step)
            every = np.arange(len(self.log))
            self._logged = np.stack([logged_desired_speed(self.log, self.valid, k, every)
                                     for k in range(self.log.shape[1])], axis=1)
        logged = self._logged[rows, t]
        out = np.where(np.isfinite(logged), logged, fixed)
        return np.where(self.speed_set[rows], fixed, out)


class BackgroundController(ABC):
    """Moves the background agents of one episode. `reset` is called at every env reset."""

    name: str = "background"

    @abstractmethod
    def reset(self, scenario: Scenario, rng: np.random.Generator, driven: np.ndarray) -> None:
        """Prepare an episode of ``scenario``; ``driven`` ``[A]`` bool marks the rows this controller moves."""

    @abstractmethod
    def step(self, t: int, cur: np.ndarray) -> np.ndarray:
        """Rows ``[A, 8]`` (track layout) of the driven agents at step ``t + 1``, from the box table ``cur``
        ``[A, 8]`` at step ``t`` (every agent; absent rows have valid = 0). Rows of agents not driven are ignored."""


class SimulatedBackground(BackgroundController):
    """A controller that integrates a per-agent acceleration with the log's lifetime (module docstring).

    Subclasses implement `accelerations`; the state update is the finite-difference one the logs satisfy:
    ``v(t+1) = v(t) + a dt``, ``p(t+1) = p(t) + v(t+1) dt``, heading along the velocity (kept below 0.5 m/s).
    """

    def reset(self, scenario: Scenario, rng: np.random.Generator, driven: np.ndarray) -> None:
        self.scenario = scenario
        self.rng = rng
        self.driven = np.asarray(driven, dtype=bool)
        self.log = scenario.tracks.astype(np.float64)
        self.intent = Intent.from_log(scenario)

    def set_intent(self, row: int, desired_speed_mps: float | None = None,
                   destination_xy: tuple[float, float] | None = None) -> None:
        """Override the intent of the agent in row ``row`` for the rest of the episode (after `reset`)."""
        if desired_speed_mps is not None:
            self.intent.set_speed(row, desired_speed_mps)
        if destination_xy is not None:
            self.intent.destination_xy[row] = destination_xy

    @abstractmethod
    def accelerations(self, t: int, cur: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``[len(rows), 2]`` map-frame accelerations (m/s^2) of the agents ``rows`` (present at ``t`` in ``cur``)."""

    def step(self, t: int, cur: np.ndarray) -> np.ndarray:
        out = np.zeros_like(cur)
        if t + 1 >= N_STEPS:
            return out
        alive = self.driven & (self.log[:, t + 1, VALID] > 0.5)
        moving = np.flatnonzero(alive & (cur[:, VALID] > 0.5))
        entering = alive & ~(cur[:, VALID] > 0.5)
        out[entering] = self.log[entering, t + 1]
        if moving.size:
            out[moving] = integrate_rows(cur[moving], self.accelerations(t, cur, moving))
        return out


def integrate_rows(rows: np.ndarray, accel: np.ndarray) -> np.ndarray:
    """Next rows ``[n, 8]`` after one step of map-frame acceleration ``accel [n, 2]`` (m/s^2): semi-implicit Euler,
    speed capped at `MAX_SPEED_MPS`, heading along the new velocity above 0.5 m/s."""
    new = rows.copy()
    v = rows[:, [VX, VY]] + accel * DT_S
    speed = np.hypot(v[:, 0], v[:, 1])
    v *= (np.minimum(speed, MAX_SPEED_MPS) / np.maximum(speed, 1e-9))[:, None]
    new[:, [VX, VY]] = v
    new[:, X] += v[:, 0] * DT_S
    new[:, Y] += v[:, 1] * DT_S
    moving = speed > 0.5
    new[moving, HEADING] = np.arctan2(v[moving, 1], v[moving, 0])
    new[:, VALID] = 1.0
    return new


class ConstantVelocityBackground(SimulatedBackground):
    """Every agent keeps its velocity (zero acceleration): the reference of `seal eval background`."""

    name = "constant_velocity"

    def accelerations(self, t: int, cur: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.zeros((rows.size, 2))


SCHEDULE_GAIN_PER_S = 0.5
"""`IDMBackground`: desired-speed correction (m/s per m, i.e. 1/s) per metre an agent is behind (or ahead of) its
logged position along its route: with nothing in the way it closes about half its lag each second."""
SCHEDULE_MAX_MPS = 5.0
"""`IDMBackground`: largest schedule correction of the desired speed (m/s), either way."""


class IDMBackground(BackgroundController):
    """IDM along the logged route (module docstring): each agent's arc length on its route advances by its IDM
    speed; its box is placed on the route, heading along it. Desired speed: the agent's `Intent`, corrected toward
    its logged schedule (where the log has it at this step): + ``schedule_gain_per_s`` x its lag (m) behind its
    logged arc length, within +/- ``schedule_max_mps``. Without the correction a car that braked for something
    (the ego, a car cutting in) stays behind its log for the rest of the episode, and so does every car queued
    behind it: measured on the decisive run's 300 eval scenarios, the background cars the Replay ego ran into with
    ``idm`` were 4-34 m behind their logged positions. IDM still brakes for whatever is ahead; a commanded desired
    speed (`SimulatedBackground.set_intent`-style, ``Intent.speed_set``) is not corrected.

    Args:
        schedule_gain_per_s: gain of the schedule correction (1/s); 0 turns it off.
        schedule_max_mps: bound of the correction (m/s).
    """

    name = "idm"

    def __init__(self, schedule_gain_per_s: float = SCHEDULE_GAIN_PER_S,
                 schedule_max_mps: float = SCHEDULE_MAX_MPS) -> None:
        if schedule_gain_per_s < 0 or schedule_max_mps < 0:
            raise ValueError(f"IDMBackground: schedule_gain_per_s and schedule_max_mps must be >= 0, got "
                             f"{schedule_gain_per_s}, {schedule_max_mps}")
        self.schedule_gain_per_s = float(schedule_gain_per_s)
        self.schedule_max_mps = float(schedule_max_mps)

    def reset(self, scenario: Scenario, rng: np.random.Generator, driven: np.ndarray) -> None:
        self.driven = np.asarray(driven, dtype=bool)
        self.log = scenario.tracks.astype(np.float64)
        self.intent = Intent.from_log(scenario)
        self._routes: dict[int, Route] = {}
        self._s = np.zeros(scenario.n_agents)
        self._schedule = np.full(self.log.shape[:2], np.nan)
        """``[A, T]`` logged arc length (m) of each agent on its own route per step; NaN where not logged."""
        self._hint: dict[int, int] = {}
        self._headway = np.full(scenario.n_agents, IDM_TIME_WANTED_S)
        rows = np.flatnonzero(self.driven)
        self._headway[rows] = logged_time_headway(self.log, rows)

    def set_intent(self, row: int, desired_speed_mps: float | None = None,
                   destination_xy: tuple[float, float] | None = None) -> None:
        """Command agent ``row``'s desired speed (m/s) for the rest of the episode (after `reset`), as
        `SimulatedBackground.set_intent` does; it is not corrected toward the logged schedule. IDM follows each
        agent's logged route, so a destination cannot be commanded (a `ValueError`)."""
        if destination_xy is not None:
            raise ValueError("IDMBackground follows each agent's logged route: a destination cannot be commanded "
                             "(RAPID's can)")
        if desired_speed_mps is not None:
            self.intent.set_speed(row, desired_speed_mps)

    def _route(self, row: int) -> Route:
        route = self._routes.get(row)
        if route is None:
            route = self._routes[row] = Route.from_track(self.log[row], 0)
            self._schedule[row, self.log[row, :, VALID] > 0.5] = route.input_s
        return route

    def _start(self, row: int, x: float, y: float) -> Route:
        """The agent's route, its arc length set from (x, y) on the first call."""
        route = self._route(row)
        if row not in self._hint:
            proj = route.project(x, y)
            self._s[row], self._hint[row] = proj.s, proj.segment
        return route

    def _desired(self, t: int, moving: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Desired speeds (m/s) of ``moving``: the intent's, corrected toward the logged schedule (class docstring)."""
        wanted = self.intent.desired_at(t, moving)
        desired = np.where(np.isfinite(wanted), wanted, speed)  # unknown: keep the current speed
        lag = self._schedule[moving, t] - self._s[moving]
        correct = np.isfinite(lag)
        if self.intent.speed_set is not None:
            correct &= ~self.intent.speed_set[moving]
        shift = np.clip(self.schedule_gain_per_s * np.nan_to_num(lag), -self.schedule_max_mps, self.schedule_max_mps)
        return np.maximum(desired + np.where(correct, shift, 0.0), 0.0)

    def step(self, t: int, cur: np.ndarray) -> np.ndarray:
        out = np.zeros_like(cur)
        if t + 1 >= N_STEPS:
            return out
        alive = self.driven & (self.log[:, t + 1, VALID] > 0.5)
        present = cur[:, VALID] > 0.5
        entering = np.flatnonzero(alive & ~present)
        for row in entering.tolist():
            out[row] = self.log[row, t + 1]
            self._hint.pop(row, None)
            self._start(row, out[row, X], out[row, Y])
        moving = np.flatnonzero(alive & present)
        if not moving.size:
            return out
        routes = [self._start(row, cur[row, X], cur[row, Y]) for row in moving.tolist()]
        speed = np.hypot(cur[moving, VX], cur[moving, VY])
        gap, lead_v = obstacle_gaps(cur, moving, self.log[:, t])
        acc = idm_plus_acceleration(speed, self._desired(t, moving, speed), gap, lead_v, self._headway[moving])
        new_speed = np.clip(speed + acc * DT_S, 0.0, MAX_SPEED_MPS)
        for k, (row, route) in enumerate(zip(moving.tolist(), routes, strict=True)):
            self._s[row] += new_speed[k] * DT_S
            x, y = route.point_at(self._s[row])
            ax, ay = route.point_at(self._s[row] - 1.0)
            heading = math.atan2(y - ay, x - ax)
            v = new_speed[k]
            out[row] = (x, y, heading, v * math.cos(heading), v * math.sin(heading),
                        cur[row, LENGTH], cur[row, WIDTH], 1.0)
        return out


def roll_background(scenario: Scenario, controller: BackgroundController, rng: np.random.Generator,
                    last_step: int = N_STEPS - 1, setup: Callable[[BackgroundController], None] | None = None
                    ) -> np.ndarray:
    """Tracks ``[A, last_step + 1, 8]`` where the background moves by ``controller`` from `CURRENT_STEP` on and
    the ego and the adversary replay their logs (the open-loop roll-out of `seal eval background`); ``setup`` is
    called with the controller after its reset (e.g. to set intents)."""
    log = scenario.tracks.astype(np.float64)
    driven = np.ones(scenario.n_agents, dtype=bool)
    driven[[scenario.ego_index, scenario.adv_index]] = False
    controller.reset(scenario, rng, driven)
    if setup is not None:
        setup(controller)
    out = np.zeros((scenario.n_agents, last_step + 1, 8))
    out[:, : CURRENT_STEP + 1] = log[:, : CURRENT_STEP + 1]
    cur = log[:, CURRENT_STEP].copy()
    for t in range(CURRENT_STEP, last_step):
        rows = controller.step(t, cur)
        cur = log[:, t + 1].copy()
        cur[driven] = rows[driven]
        out[:, t + 1] = cur
    return out
