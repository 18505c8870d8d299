"""Kinematic bicycle model, action scaling and inverse dynamics.

The model is highway-env's ``Vehicle.step`` (a kinematic bicycle with the reference point at the centre):

    beta     = arctan(0.5 * tan(delta))                      slip angle (rad)
    position += speed * [cos(heading + beta), sin(heading + beta)] * dt
    heading  += speed * sin(beta) / (length / 2) * dt
    speed    += acceleration * dt,  then clipped to [0, MAX_SPEED_MPS]

Differences from highway-env, on purpose: ``length`` is the agent's own length (highway-env uses the class
constant 5 m; the generated traffic uses each vehicle's own length too), and the speed is clipped to
``[0, 40]`` m/s instead of highway-env's soft clipping to ``[-40, 40]`` (no reversing on a highway).

Action scaling: a normalised action ``[steering, acceleration]`` in ``[-1, 1]^2`` (the order CAT / MetaDrive use;
highway-env's ``ContinuousAction`` is the other way round) maps to ``delta = steering * MAX_STEER_RAD``
(+-pi/3 rad, positive = left / counter-clockwise) and ``a = acceleration * MAX_ACCEL_MPS2`` (+-6 m/s^2).
Actions are held for one 10 Hz step (``DT_S = 0.1`` s). The steering range is that of highway-env's
``ControlledVehicle`` (``MAX_STEERING_ANGLE = pi/3``), which drives the generated traffic, so every logged
manoeuvre (e.g. slow, tight turns into a roundabout) is within the ego's reach; +-pi/4 (highway-env's
``ContinuousAction`` default) cannot reproduce some of them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from seal.core.geometry import wrap_angle_f
from seal.core.scenario import DT_S, HEADING, LENGTH, VALID, VX, VY, WIDTH, X, Y

MAX_STEER_RAD = math.pi / 3
MAX_ACCEL_MPS2 = 6.0
MAX_SPEED_MPS = 40.0
MAX_BETA_RAD = math.atan(0.5 * math.tan(MAX_STEER_RAD))
"""Largest slip angle reachable with full steering (rad)."""
_AIM_MIN_STEP_M = 0.2
"""`recover_actions` aims at the next logged position only when a step covers at least this distance."""


@dataclass(frozen=True, slots=True)
class AgentState:
    """Kinematic state of one vehicle at one step.

    Attributes:
        x, y: centre position (m, world frame).
        heading: rad, counter-clockwise from +x.
        speed: m/s (>= 0), along the heading.
        length, width: box size (m).
        steering: applied normalised steering in [-1, 1] during the step that led here (0 if unknown).
        accel: applied normalised acceleration in [-1, 1] during that step (0 if unknown).
        yaw_rate: heading change over that step divided by ``DT_S`` (rad/s).
    """

    x: float
    y: float
    heading: float
    speed: float
    length: float = 5.0
    width: float = 2.0
    steering: float = 0.0
    accel: float = 0.0
    yaw_rate: float = 0.0

    @property
    def vx(self) -> float:
        """World-frame velocity x (m/s), along the heading like highway-env's ``Vehicle.velocity``."""
        return self.speed * math.cos(self.heading)

    @property
    def vy(self) -> float:
        return self.speed * math.sin(self.heading)

    def to_track_row(self) -> np.ndarray:
        """``[8]`` float64 row in the scenario track layout (valid = 1)."""
        return np.array(
            [self.x, self.y, self.heading, self.vx, self.vy, self.length, self.width, 1.0], dtype=np.float64
        )

    @classmethod
    def from_track_row(cls, row: np.ndarray) -> AgentState:
        """State from one ``[8]`` track row (speed = norm of vx, vy; controls unknown = 0)."""
        return cls(
            x=float(row[X]),
            y=float(row[Y]),
            heading=float(row[HEADING]),
            speed=math.hypot(float(row[VX]), float(row[VY])),
            length=float(row[LENGTH]),
            width=float(row[WIDTH]),
        )


def bicycle_step(state: AgentState, steering: float, accel: float, dt: float = DT_S) -> AgentState:
    """Integrate one step from normalised controls (clipped to [-1, 1]); returns the next state.

    Scalar ``math`` on purpose: for one vehicle it is ~10x faster than numpy.
    """
    steering = min(1.0, max(-1.0, float(steering)))
    accel = min(1.0, max(-1.0, float(accel)))
    delta = steering * MAX_STEER_RAD
    beta = math.atan(0.5 * math.tan(delta))
    v = state.speed
    heading_rate = v * math.sin(beta) / (state.length / 2.0)
    speed = min(MAX_SPEED_MPS, max(0.0, v + accel * MAX_ACCEL_MPS2 * dt))
    return AgentState(
        state.x + v * math.cos(state.heading + beta) * dt,
        state.y + v * math.sin(state.heading + beta) * dt,
        state.heading + heading_rate * dt,
        speed,
        state.length,
        state.width,
        steering,
        accel,
        heading_rate,
    )


def placement_state(prev: AgentState | None, row: np.ndarray, dt: float = DT_S) -> AgentState:
    """State for an agent placed at a track ``row`` (replay), with the controls implied by the move from ``prev``.

    The implied controls invert the bicycle model (heading change -> slip angle -> steering, speed change ->
    acceleration) so a placed agent's observation slots (steering, last action, yaw rate) are meaningful.
    """
    new = AgentState.from_track_row(row)
    if prev is None:
        return new
    dh = wrap_angle_f(new.heading - prev.heading)
    steering = 0.0
    if prev.speed > 0.1:
        sin_beta = dh * (prev.length / 2.0) / (prev.speed * dt)
        beta = math.asin(min(1.0, max(-1.0, sin_beta)))
        steering = math.atan(2.0 * math.tan(beta)) / MAX_STEER_RAD
    accel = (new.speed - prev.speed) / (dt * MAX_ACCEL_MPS2)
    return AgentState(
        new.x, new.y, new.heading, new.speed, new.length, new.width,
        min(1.0, max(-1.0, steering)), min(1.0, max(-1.0, accel)), dh / dt,
    )


def recover_actions(track: np.ndarray, start_step: int | None = None, dt: float = DT_S) -> np.ndarray:
    """Normalised actions ``[T-1, 2]`` (steering, acceleration) that make the bicycle model follow ``track``.

    Closed loop: the model is simulated from the logged state at ``start_step`` (default: the first valid
    step) and each action is computed from the *simulated* state, so model mismatch (e.g. a log recorded at a
    different rate, or crash impulses) does not accumulate. Row ``k`` moves step ``k`` to ``k + 1``:

    * steering aims the direction of motion (heading + slip angle) at the logged position of step ``k + 1``;
      with the simulated speed this lands on it (exactly, for a track produced by this model); below 2 m/s
      (steps under 0.2 m, where small position errors would swing the aim around) it matches the logged heading
      of step ``k + 1`` instead (also when the target lies behind: the log braked harder than +-6 m/s^2);
    * acceleration sets the speed of step ``k + 1`` to the distance from the predicted position to the logged
      position of step ``k + 2`` divided by ``dt`` (0 when that lies behind; the logged speed on the last step).

    Rows before ``start_step`` and from the last valid step on are 0.

    Args:
        track: ``[T, 8]`` scenario track of one agent (valid steps contiguous).
        start_step: step at which the simulation starts from the log.
        dt: step length (s).
    """
    track = np.asarray(track, dtype=np.float64)
    n = track.shape[0]
    actions = np.zeros((max(n - 1, 0), 2), dtype=np.float64)
    valid = np.flatnonzero(track[:, VALID] > 0.5)
    if valid.size < 2:
        return actions
    first, last = int(valid[0]), int(valid[-1])
    start = first if start_step is None else max(int(start_step), first)
    if start >= last:
        return actions
    state = AgentState.from_track_row(track[start])
    pos = track[:, [X, Y]]
    logged_speed = np.hypot(track[:, VX], track[:, VY])
    for k in range(start, last):
        dx, dy = float(pos[k + 1, 0] - state.x), float(pos[k + 1, 1] - state.y)
        ahead = dx * math.cos(state.heading) + dy * math.sin(state.heading)
        if state.speed * dt > _AIM_MIN_STEP_M and ahead > 0.5 * state.speed * dt:
            # Aim the direction of motion at the next logged position.
            beta = wrap_angle_f(math.atan2(dy, dx) - state.heading)
        elif state.speed > 1e-3:
            # Creeping: position errors swamp the step, so match the logged heading instead.
            dh = wrap_angle_f(float(track[k + 1, HEADING]) - state.heading)
            beta = math.asin(min(1.0, max(-1.0, dh * (state.length / 2.0) / (state.speed * dt))))
        else:
            beta = 0.0
        beta = min(MAX_BETA_RAD, max(-MAX_BETA_RAD, beta))
        steering = math.atan(2.0 * math.tan(beta)) / MAX_STEER_RAD
        # Predict where this step lands, then choose the speed that covers the next logged displacement.
        nx = state.x + state.speed * math.cos(state.heading + beta) * dt
        ny = state.y + state.speed * math.sin(state.heading + beta) * dt
        if k + 2 <= last:
            ex, ey = float(pos[k + 2, 0] - nx), float(pos[k + 2, 1] - ny)
            h_next = state.heading + state.speed * math.sin(beta) / (state.length / 2.0) * dt
            # A target behind (the log braked harder than the model can) means stop, not drive on to it.
            behind = ex * math.cos(h_next) + ey * math.sin(h_next) < 0.0
            v_next = 0.0 if behind else math.hypot(ex, ey) / dt
        else:
            v_next = float(logged_speed[k + 1])
        accel = (v_next - state.speed) / (dt * MAX_ACCEL_MPS2)
        actions[k] = (steering, min(1.0, max(-1.0, accel)))
        state = bicycle_step(state, actions[k, 0], actions[k, 1], dt)
    return actions
