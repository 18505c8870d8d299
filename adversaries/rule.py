"""``rule``: a cubic Bezier from the adversary into the ego's logged path, timed to get there with the ego.

For every target step ``T`` of the ego's logged future (from `MIN_ARRIVAL_S` on) the curve runs from the
adversary's current position ``P0`` (tangent: its heading) to the ego's logged position ``P3`` at ``T`` (tangent:
the ego's logged heading there), with the inner control points a third of the chord along those tangents. The
adversary drives it at the constant acceleration ``a = 2 (L - v0 tau) / tau^2`` that covers the curve length
``L`` in ``tau = (T - CURRENT_STEP) dt``, then follows the ego's logged path at the speed it arrived with.

The chosen target is the feasible one (``|a| <= max_accel_mps2``, peak lateral acceleration
``v^2 kappa <= max_lat_accel_mps2``, no reversing, target ahead) with the smallest ``|a|``: the most ordinary
driving that still meets the ego. With no feasible target the least infeasible one (largest of the two limit
ratios) is taken. Deterministic: the rng is not used. The adversary replays the path (`ReplayBehavior`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from seal.adversaries.base import AdversaryGenerator, Generation, register
from seal.adversaries.candidate_path import candidate_track
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, N_FUTURE, VALID, VX, VY, Scenario, X, Y
from seal.envs.behaviors import ReplayBehavior
from seal.envs.rollout import Rollout

MIN_ARRIVAL_S = 1.0
_N_CURVE = 64
"""Curve parameter samples for arc length and curvature."""


def bezier_points(ctrl: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Points ``[..., U, 2]`` of cubic Bezier curves with control points ``ctrl [..., 4, 2]`` at parameters ``u``."""
    b = np.stack([(1 - u) ** 3, 3 * u * (1 - u) ** 2, 3 * u**2 * (1 - u), u**3], axis=-1)  # [U, 4]
    return np.einsum("uk,...kd->...ud", b, ctrl)


def bezier_curvature(ctrl: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Unsigned curvature ``[..., U]`` (1/m) of cubic Bezier curves at parameters ``u``."""
    d1 = np.stack([(1 - u) ** 2, 2 * u * (1 - u), u**2], axis=-1)  # derivative basis [U, 3]
    d2 = np.stack([1 - u, u], axis=-1)
    first = 3 * np.einsum("uk,...kd->...ud", d1, np.diff(ctrl, axis=-2))
    second = 6 * np.einsum("uk,...kd->...ud", d2, np.diff(ctrl, n=2, axis=-2))
    cross = np.abs(first[..., 0] * second[..., 1] - first[..., 1] * second[..., 0])
    return cross / np.maximum(np.hypot(first[..., 0], first[..., 1]) ** 3, 1e-9)


def _unit(h: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(h), np.sin(h)], axis=-1)


@register("rule")
class RuleGenerator(AdversaryGenerator):
    """Rule-based adversary (see the module docstring).

    Args:
        max_accel_mps2: longitudinal acceleration limit for a feasible target.
        max_lat_accel_mps2: lateral acceleration limit on the curve.
        min_arrival_s: earliest target time after the current step (s).
    """

    def __init__(
        self, max_accel_mps2: float = 4.0, max_lat_accel_mps2: float = 6.0, min_arrival_s: float = MIN_ARRIVAL_S
    ) -> None:
        self.max_accel = float(max_accel_mps2)
        self.max_lat = float(max_lat_accel_mps2)
        self.min_arrival_steps = max(1, round(min_arrival_s / DT_S))

    def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        ego = scenario.track(scenario.ego_id).astype(np.float64)
        adv_i = scenario.adv_index
        adv = scenario.tracks[adv_i, CURRENT_STEP].astype(np.float64)
        steps = np.arange(CURRENT_STEP + self.min_arrival_steps, ego.shape[0])
        steps = steps[ego[steps, VALID] > 0.5]
        if steps.size == 0:
            raise ValueError(f"rule: the ego of scenario {scenario.scenario_id!r} has no logged future to aim at")
        p0, h0, v0 = adv[[X, Y]], float(adv[HEADING]), float(np.hypot(adv[VX], adv[VY]))
        p3, h3 = ego[steps][:, [X, Y]], ego[steps, HEADING]
        chord = np.hypot(*(p3 - p0).T)
        ctrl = np.stack(
            [np.broadcast_to(p0, p3.shape), p0 + chord[:, None] / 3 * _unit(np.full(len(steps), h0)),
             p3 - chord[:, None] / 3 * _unit(h3), p3], axis=1,
        )  # [N, 4, 2]
        u = np.linspace(0.0, 1.0, _N_CURVE)
        pts = bezier_points(ctrl, u)  # [N, U, 2]
        cum = np.concatenate([np.zeros((len(steps), 1)), np.cumsum(np.hypot(*np.diff(pts, axis=1).T).T, 1)], 1)
        length = cum[:, -1]
        tau = (steps - CURRENT_STEP) * DT_S
        accel = 2 * (length - v0 * tau) / tau**2
        v_end = v0 + accel * tau
        peak_lat = (np.maximum(v0, v_end) ** 2 * bezier_curvature(ctrl, u).max(-1))
        ahead = (p3 - p0) @ _unit(np.array(h0)) > 0
        violation = np.maximum(np.abs(accel) / self.max_accel, peak_lat / self.max_lat)
        violation = np.where(ahead & (v_end >= 0), violation, np.inf)
        feasible = violation <= 1.0
        if feasible.any():
            best = int(np.flatnonzero(feasible)[np.argmin(np.abs(accel[feasible]))])
        elif np.isfinite(violation).any():
            best = int(np.argmin(violation))
        else:
            best = int(np.argmin(np.abs(accel)))
        future = self._future(pts[best], cum[best], ego, int(steps[best]), v0, float(accel[best]))
        track = candidate_track(scenario, adv_i, future)
        return Generation(
            behavior=ReplayBehavior(track),
            predicted_step=int(steps[best]),
            extra={
                "target_step": int(steps[best]),
                "accel_mps2": float(accel[best]),
                "peak_lat_accel_mps2": float(peak_lat[best]),
                "feasible": bool(feasible[best]),
            },
        )

    @staticmethod
    def _future(
        curve: np.ndarray, cum: np.ndarray, ego: np.ndarray, target: int, v0: float, accel: float
    ) -> np.ndarray:
        """``[N_FUTURE, 2]`` positions: along the curve at constant acceleration until ``target``, then along the
        ego's logged path (straight past its end) at the arrival speed."""
        t = DT_S * np.arange(1, N_FUTURE + 1)
        tau = (target - CURRENT_STEP) * DT_S
        on_curve = t <= tau + 1e-9
        s_curve = np.clip(v0 * t + 0.5 * accel * t**2, 0.0, cum[-1])
        out = np.empty((N_FUTURE, 2))
        out[:, 0] = np.interp(s_curve, cum, curve[:, 0])
        out[:, 1] = np.interp(s_curve, cum, curve[:, 1])
        if on_curve.all():
            return out
        path = ego[target:][ego[target:, VALID] > 0.5][:, [X, Y]]
        if len(path) < 2 or np.hypot(*(path[-1] - path[0])) < 1e-3:
            d = _unit(np.array(ego[target, HEADING]))
            path = np.vstack([path[:1], path[:1] + d])
        seg = np.hypot(*np.diff(path, axis=0).T)
        keep = np.concatenate([[True], seg > 1e-6])
        path = path[keep]
        pcum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(path, axis=0).T))])
        v_arrive = max(0.0, v0 + accel * tau)
        s_path = v_arrive * (t[~on_curve] - tau)
        direction = (path[-1] - path[-2]) / max(pcum[-1] - pcum[-2], 1e-9)
        past = np.maximum(s_path - pcum[-1], 0.0)[:, None]
        out[~on_curve, 0] = np.interp(s_path, pcum, path[:, 0])
        out[~on_curve, 1] = np.interp(s_path, pcum, path[:, 1])
        out[~on_curve] += past * direction
        return out
