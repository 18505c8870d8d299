"""The adversary's trajectory as GOOSE edits it: a degree-3, 5-point NURBS in the adversary's initial frame, and the
timed track the adversary replays along it. Two timings (`GooseSpec.timing`):

``"curve"`` (default): the NURBS is a trajectory, its parameter is time, as in GOOSE, whose scenario-level
actions edit OpenSCENARIO NURBS trajectories whose control points carry a time besides position and weight. Time
is a third coordinate of the control points, at their Greville abscissae ``xi = [0, 1/6, 1/2, 5/6, 1]`` of the
logged duration ``T``, so the zero edit with unit weights runs the clock ``t = u T``; x / y edits move the
adversary in space *and* time (a point pulled back = braking, pushed ahead = accelerating), and a heavier point
pulls position and time towards it. This is what makes the "deceleration" goal (contact with |acc| <= 8 m/s^2)
something the agent can reach: with the logged speed profile, an adversary cannot brake or hurry to meet the ego,
only move sideways or stretch its path (measured on the decisive pool: a hand-written rule that moves points
2..4 to the ego's positions at their times reached the goal in 47 % of 60 held-out scenarios with timed curves,
40 % with the logged profile; random edits 15 %). Fit: least squares at ``u = k / K`` for logged step ``k``
of ``K`` (`seal.adversaries.goose.nurbs.fit_timed_nurbs`), point 0 at the current position, point 4 at the
logged end, point 1 at ``P0 + v0 T / 6`` along the heading (``C'(0) / T`` is the current velocity). A log that
stops is sometimes overshot and driven back by 5 points; then the fit keeps the log-ordered Greville polygon.
Replay: step ``k`` is at the ``u`` whose clock reads ``k / K``; velocity ``C'(u) / (T t'(u))``; the heading
follows it above `HOLD_SPEED_MPS` and is held below.

``"log"``: the path only (agents trained before the option). The logged adversary path gets a least-squares
NURBS with unit weights and chord-length parameters (`seal.adversaries.goose.nurbs.fit_nurbs`). Control points 0
and 4 are pinned to the path's ends, so the zero action reproduces the logged path and its length. Point 1 lies
on the +x axis: the curve leaves the current pose along the current heading (GOOSE's trajectories start from the
vehicle's state; without this the replay turned from the logged heading to the fit's tangent within one 0.1 s
step, a yaw-rate spike of ~1-3 rad/s that broke the goal's 0.7 rad/s bound in most roll-outs whatever the agent did).

Edit (one GOOSE action, 12-d in [-1, 1]): control point ``i`` = 1..4 moves by ``a[2i-2], a[2i-1]`` x ``shift_m``
x ``point_scale[i-1]`` (x, y) and its weight scales by ``weight_factor ** a[7 + i]``; totals stay within
``max_offset_m`` x ``point_scale[i-1]`` of the fitted points and within the weight bounds. Point 0 never moves.
Point 1 moves along the heading only (``a[1]`` has no effect) with ``"log"`` timing; with ``"curve"`` timing it is
the current velocity and does not move (``a[0]``, ``a[1]`` have no effect).

Timing ``"log"``: the logged speed profile is kept and re-mapped to the new curve length ``L`` (logged length
``L0``, ratio ``r = L / L0``). With ``x = s0 / L0`` the logged share of the path covered at a step, the distance
along the new curve is

    s = L0 f(x),     f(x) = x (1 + (r - 1) g(x)),     g(x) = 3x^2 - 2x^3 (smoothstep),

so ``f(1) = r`` (the end of the log maps to the end of the curve) and the speed is the logged one times
``f'(x) = 1 + (r - 1)(9x^2 - 8x^3)``: 1 at the start, so it is continuous with the current logged speed (a plain
``r * s0`` would jump by ``(r - 1) v`` in the first 0.1 s), and 0 wherever the log stands still. ``f`` is
monotone for ``r > 0.41``; below that (a curve pulled back to less than 41 % of the log) the adversary is held in
place where it would go back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from seal.adversaries.goose.nurbs import (
    NurbsCurve,
    distance_to_curve,
    fit_nurbs,
    fit_timed_nurbs,
    greville_abscissae,
    nurbs_derivatives,
    nurbs_points,
)
from seal.adversaries.goose.spec import TIMINGS, GooseSpec
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, VALID, VX, VY, Scenario, X, Y

N_ACTION = 12
"""x, y of control points 1..4 (8) and their weights (4)."""
POS_SCALE_M = 50.0
"""Position scale of the observation features (m)."""
MIN_PATH_M = 1.0
"""Logged paths shorter than this are treated as this long when computing the length ratio."""
START_DIRECTION = np.array([1.0, 0.0])
"""The adversary's heading in its initial frame: the curve leaves the current pose along it (tangent continuity;
control point 1 stays on this ray, in the fit and in every edit)."""
N_CURVE_FEATURES = 22
"""Length of `GooseCurve.features`."""
HOLD_SPEED_MPS = 0.5
"""Timed curves: below this speed the heading is held (a near-standing fit drifts by centimetres in arbitrary
directions; a car's heading does not follow that drift)."""
TIME_SAMPLES = 1024
"""Timed curves: parameter grid on which the curve's clock ``t(u)`` is inverted before the Newton refinement."""


@dataclass(frozen=True)
class Frame:
    """The adversary's initial frame: origin ``(x0, y0)`` (m, world) and heading ``h0`` (rad, world)."""

    x0: float
    y0: float
    h0: float

    def to_local(self, xy: np.ndarray) -> np.ndarray:
        """World ``[..., 2]`` -> frame ``[..., 2]``."""
        c, s = math.cos(self.h0), math.sin(self.h0)
        d = np.asarray(xy, dtype=np.float64) - (self.x0, self.y0)
        return np.stack([d[..., 0] * c + d[..., 1] * s, -d[..., 0] * s + d[..., 1] * c], axis=-1)

    def to_world(self, xy: np.ndarray) -> np.ndarray:
        """Frame ``[..., 2]`` -> world ``[..., 2]``."""
        c, s = math.cos(self.h0), math.sin(self.h0)
        p = np.asarray(xy, dtype=np.float64)
        return np.stack([self.x0 + p[..., 0] * c - p[..., 1] * s, self.y0 + p[..., 0] * s + p[..., 1] * c], axis=-1)


def _smoothstep(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``g(x) = 3x^2 - 2x^3`` and ``g'(x)`` on [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x), 6.0 * x * (1.0 - x)


@dataclass(frozen=True)
class GooseCurve:
    """One scenario's adversary curve: the fitted start point and the current edit.

    Attributes:
        scenario_id: the scenario.
        frame: the adversary's initial frame.
        log_track: ``[N_STEPS, 8]`` logged adversary track (float64, world frame).
        n_future: logged future steps used (the contiguous valid run after `CURRENT_STEP`), >= 0.
        s_log: ``[n_future + 1]`` logged distance along the path (m) at steps ``CURRENT_STEP ..``; ``s_log[0] = 0``.
        v_log: ``[n_future + 1]`` logged speed (m/s) at the same steps.
        fitted: the least-squares fit (frame coordinates).
        fit_error_m: largest distance from a logged path point to the fitted curve (m).
        ctrl: ``[5, 2]`` current control points (frame, m).
        weights: ``[5]`` current weights.
        timing: ``"curve"`` (the parameter is time) or ``"log"`` (logged speed profile), see `TIMINGS`.
    """

    scenario_id: str
    frame: Frame
    log_track: np.ndarray
    n_future: int
    s_log: np.ndarray
    v_log: np.ndarray
    fitted: NurbsCurve
    fit_error_m: float
    ctrl: np.ndarray
    weights: np.ndarray
    timing: str = "curve"

    @classmethod
    def from_scenario(cls, scenario: Scenario, timing: str = "curve") -> GooseCurve:
        """Fit the curve to the scenario's logged adversary path (see the module docstring). ``fit_error_m`` is
        the largest distance from a logged point to the curve (``"log"``) or to the curve's point at the same time
        (``"curve"``: timing errors count too)."""
        if timing not in TIMINGS:
            raise ValueError(f"timing must be one of {TIMINGS}, got {timing!r}")
        track = scenario.track(scenario.adv_id).astype(np.float64)
        valid = track[CURRENT_STEP:, VALID] > 0.5
        if not valid[0]:
            raise ValueError(f"scenario {scenario.scenario_id!r}: adversary {scenario.adv_id} is not valid at the "
                             f"current step {CURRENT_STEP}")
        run = int(np.argmin(valid)) if not valid.all() else len(valid)  # contiguous valid steps from CURRENT_STEP
        n_future = run - 1
        rows = track[CURRENT_STEP : CURRENT_STEP + run]
        frame = Frame(float(rows[0, X]), float(rows[0, Y]), float(rows[0, HEADING]))
        path = frame.to_local(rows[:, [X, Y]])
        s_log = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
        v_log = np.hypot(rows[:, VX], rows[:, VY])
        if n_future == 0:
            # No logged future: a 1 m stub along the heading gives the curve a shape; nothing is replayed on it.
            fitted = fit_nurbs(np.array([[0.0, 0.0], [MIN_PATH_M, 0.0]]), start_direction=START_DIRECTION)
            fit_error = 0.0
        elif timing == "curve":
            # Starts with the current velocity: along the heading at the logged speed (dC/du = v T).
            start = START_DIRECTION * v_log[0] * n_future * DT_S
            fitted = fit_timed_nurbs(path, start)
            probe = cls(scenario.scenario_id, frame, track, n_future, s_log, v_log, fitted, 0.0, fitted.ctrl,
                        fitted.weights, timing)
            if probe.reverses():
                # Least squares overshot a stop and comes back (5 points cannot bend sharply enough); the Greville
                # guess keeps the control polygon in the log's order.
                fitted = fit_timed_nurbs(path, start, least_squares=False)
            fit_error = float(np.hypot(*(fitted.points(np.linspace(0.0, 1.0, run)) - path).T).max())
        else:
            fitted = fit_nurbs(path, start_direction=START_DIRECTION)
            fit_error = float(distance_to_curve(path, fitted).max())
        return cls(scenario.scenario_id, frame, track, n_future, s_log, v_log, fitted, fit_error,
                   fitted.ctrl.copy(), fitted.weights.copy(), timing)

    # ------------------------------------------------------------------------------------------ editing
    @property
    def curve(self) -> NurbsCurve:
        return NurbsCurve(self.ctrl, self.weights)

    def edited(self, action: np.ndarray, spec: GooseSpec) -> GooseCurve:
        """The curve after one GOOSE action ``[12]`` (clipped to [-1, 1]; see the module docstring)."""
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        if a.shape != (N_ACTION,):
            raise ValueError(f"a GOOSE action has {N_ACTION} values, got {a.shape[0]}")
        ctrl = self.ctrl.copy()
        scale = np.asarray(spec.point_scale)[:, None]
        lo = self.fitted.ctrl[1:] - spec.max_offset_m * scale
        hi = self.fitted.ctrl[1:] + spec.max_offset_m * scale
        ctrl[1:] = np.clip(ctrl[1:] + a[:8].reshape(4, 2) * spec.shift_m * scale, lo, hi)
        if self.timing == "curve":
            # Point 1 is the adversary's current velocity (C'(0) = (P1 - P0) / xi_1, whatever the weights, since
            # position and time share them): moving it would change the speed or heading within 0.1 s.
            ctrl[1] = self.fitted.ctrl[1]
        else:
            # Point 1 slides along the start heading only (a[1] has no effect): a sideways move would turn the
            # adversary within its first 0.1 s, a yaw-rate step no vehicle makes (and one the goal's bound fails).
            ctrl[1, 1] = self.fitted.ctrl[1, 1]
            ctrl[1, 0] = max(float(ctrl[1, 0]), 1e-3)
        weights = self.weights.copy()
        weights[1:] = np.clip(weights[1:] * spec.weight_factor ** a[8:], spec.weight_min, spec.weight_max)
        return replace(self, ctrl=ctrl, weights=weights)

    def reset_edit(self) -> GooseCurve:
        """Back to the fitted curve."""
        return replace(self, ctrl=self.fitted.ctrl.copy(), weights=self.fitted.weights.copy())

    # ------------------------------------------------------------------------------------------ outputs
    @property
    def log_length_m(self) -> float:
        return float(self.s_log[-1])

    def length_ratio(self) -> float:
        """Current curve length over the logged path length."""
        return self.curve.length() / max(self.log_length_m, MIN_PATH_M)

    def track(self) -> np.ndarray:
        """``[N_STEPS, 8]`` adversary track: the log up to `CURRENT_STEP`, then the re-timed curve for the
        logged future steps (invalid after them). Heading is the curve tangent, velocity along it."""
        out = self.log_track.copy()
        out[CURRENT_STEP + 1 :, :] = 0.0
        if self.n_future == 0:
            return out
        if self.timing == "curve":
            pts, heading, speed_f = self._timed_motion()
            return self._write_track(out, pts, heading, speed_f)
        curve = self.curve
        length = curve.length()
        base = max(self.log_length_m, MIN_PATH_M)
        r = length / base
        x = self.s_log / base
        g, dg = _smoothstep(x)
        raw = base * x * (1.0 + (r - 1.0) * g)
        peak = np.maximum.accumulate(raw)
        s = np.clip(peak, 0.0, length)  # a shrunken curve must not make it reverse
        held = (peak > raw + 1e-9) | (raw > length + 1e-9)  # where the warp is not monotone
        speed = np.where(held, 0.0, np.maximum(self.v_log * (1.0 + (r - 1.0) * (g + x * dg)), 0.0))
        pts, heading = curve.at_arc_length(s[1:])
        return self._write_track(out, pts, heading, speed[1:])

    def _write_track(self, out: np.ndarray, pts: np.ndarray, heading: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Fill the future rows of ``out`` from frame points ``[n_future, 2]``, frame headings and speeds (m/s)."""
        rows = slice(CURRENT_STEP + 1, CURRENT_STEP + 1 + self.n_future)
        world = self.frame.to_world(pts)
        h = heading + self.frame.h0
        out[rows, X], out[rows, Y] = world[:, 0], world[:, 1]
        out[rows, HEADING] = np.arctan2(np.sin(h), np.cos(h))
        out[rows, VX], out[rows, VY] = speed * np.cos(h), speed * np.sin(h)
        out[rows, 5:7] = self.log_track[CURRENT_STEP, 5:7]
        out[rows, VALID] = 1.0
        return out

    def reverses(self) -> bool:
        """Timed curves: whether the replay turns by more than 90 degrees within one step anywhere (the curve
        drives back over itself)."""
        _, heading, _ = self._timed_motion()
        turn = np.diff(np.concatenate([[0.0], heading]))
        return bool(np.any(np.cos(turn) < 0.0))

    def clock(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Timed curves: the curve's clock ``t(u)`` as a share of the logged duration and ``dt/du``, ``[M]`` each.
        Time is a third coordinate of the control points, at their Greville abscissae (so unit weights give
        ``t = u``), interpolated with the same rational basis as the position: a heavier point pulls the
        curve's position *and* its time towards it, so the adversary lingers near it."""
        times = greville_abscissae(len(self.ctrl))[:, None]
        t = nurbs_points(times, self.weights, u)[:, 0]
        dt = nurbs_derivatives(times, self.weights, u)[:, 0]
        return t, dt

    def _timed_motion(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Timed curves: frame points ``[n_future, 2]``, headings (rad) and speeds (m/s) at future steps
        1..n_future. ``t(u)`` is monotone (positive weights, increasing control times), so it is inverted on a grid,
        then refined by Newton steps. Velocity is ``C'(u) / (T t'(u))``, ``T`` the logged duration; the heading is
        its direction, held where the speed is below `HOLD_SPEED_MPS` (the current heading before any motion)."""
        duration = self.n_future * DT_S
        target = np.arange(1, self.n_future + 1) / self.n_future
        grid = np.linspace(0.0, 1.0, TIME_SAMPLES)
        u = np.interp(target, self.clock(grid)[0], grid)
        for _ in range(2):
            t, dt = self.clock(u)
            u = np.clip(u - (t - target) / np.maximum(dt, 1e-9), 0.0, 1.0)
        _, dt = self.clock(u)
        vel = self.curve.derivatives(u) / (duration * np.maximum(dt, 1e-9))[:, None]
        speed = np.hypot(vel[:, 0], vel[:, 1])
        raw = np.arctan2(vel[:, 1], vel[:, 0])
        moving = speed >= HOLD_SPEED_MPS
        last = np.maximum.accumulate(np.where(moving, np.arange(len(u)), -1))
        heading = np.where(last >= 0, raw[np.maximum(last, 0)], 0.0)
        return self.curve.points(u), heading, speed

    def features(self, spec: GooseSpec) -> np.ndarray:
        """Curve state ``[22]`` float32: control points 1..4 (frame, / `POS_SCALE_M`), their offsets from the fit
        (/ their largest offset, so in [-1, 1]), log weights 1..4 (/ log ``weight_max``), log length ratio, log
        logged length."""
        offset = (self.ctrl[1:] - self.fitted.ctrl[1:]) / (spec.max_offset_m * np.asarray(spec.point_scale)[:, None])
        logw = np.log(self.weights[1:]) / math.log(spec.weight_max)
        extra = [math.log(max(self.length_ratio(), 1e-3)), math.log(max(self.log_length_m, MIN_PATH_M)) / 5.0]
        return np.concatenate([(self.ctrl[1:] / POS_SCALE_M).ravel(), offset.ravel(), logw, extra]).astype(np.float32)

