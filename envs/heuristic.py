"""`HeuristicDriver`: a reactive rule-based driver that works from the observation vector alone.

Steering: pure pursuit along the route, reconstructed from the observation as the circle tangent to the route
at the projection point (lateral offset, heading error) through a navigation checkpoint; the target is pushed
away from a road edge that comes too close to the car's side (road-edge rays).

Longitudinal, IDM-style: a proportional controller toward a desired speed (by default the route's reference
speed slot, i.e. the speed the route's owner drove there, floored at `min_desired_mps`) minus IDM's interaction
term for the closest vehicle in its predicted path, found from the vehicle-lidar hits and the nearest-vehicle
slots (which also give the leader's relative speed).

It keeps no memory, so one instance can drive any number of vehicles (SB3 VecEnv batches, the ego and a
reactive adversary at once).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from seal.envs import observation as ob
from seal.envs.kinematics import MAX_ACCEL_MPS2, MAX_BETA_RAD, MAX_SPEED_MPS, MAX_STEER_RAD

_LIDAR_ANG = ob._LIDAR_ANG
_EDGE_COS, _EDGE_SIN = np.cos(ob._EDGE_ANG), np.sin(ob._EDGE_ANG)


class HeuristicDriver:
    """Rule-based driver with SB3's ``predict`` interface (see the module docstring).

    Args:
        desired_speed: ``"reference"`` (route reference speed slot), ``"limit"`` (lane speed limit slot) or a
            speed in m/s.
        min_desired_mps: floor of the desired speed, so a route that stopped (e.g. waiting at a junction) does
            not freeze the driver.
        time_headway_s, min_gap_m, max_accel_mps2, comfort_decel_mps2: IDM parameters.
        path_half_width_m: lateral distance from the predicted path within which a vehicle centre counts as
            being in the path.
        length_m: assumed own length (m) for the steering geometry and gaps.
        lookahead_s, min_lookahead_m: pure-pursuit look-ahead ``clip(speed * lookahead_s, min, 16 m)``.
        speed_gain: free-road acceleration per m/s of speed below the desired speed (1/s).
        edge_margin_m: clearance (m) to a road edge beside the car below which it steers away from it.
    """

    def __init__(
        self,
        desired_speed: str | float = "reference",
        min_desired_mps: float = 3.0,
        time_headway_s: float = 1.0,
        min_gap_m: float = 2.5,
        max_accel_mps2: float = 3.0,
        comfort_decel_mps2: float = 4.0,
        path_half_width_m: float = 2.3,
        length_m: float = 5.0,
        lookahead_s: float = 0.4,
        min_lookahead_m: float = 3.0,
        speed_gain: float = 1.5,
        edge_margin_m: float = 0.8,
    ) -> None:
        self.desired_speed = desired_speed
        self.min_desired_mps = min_desired_mps
        self.time_headway_s = time_headway_s
        self.min_gap_m = min_gap_m
        self.max_accel = max_accel_mps2
        self.comfort_decel = comfort_decel_mps2
        self.path_half_width = path_half_width_m
        self.length = length_m
        self.lookahead_s = lookahead_s
        self.min_lookahead_m = min_lookahead_m
        self.speed_gain = speed_gain
        self.edge_margin_m = edge_margin_m

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """Actions ``[2]`` (or ``[n, 2]`` for a batch ``[n, OBS_DIM]``) as float32, and ``state`` unchanged."""
        obs = np.asarray(observation, dtype=np.float64)
        if obs.ndim == 1:
            return self.act(obs).astype(np.float32), state
        return np.stack([self.act(o) for o in obs]).astype(np.float32), state

    # ---------------------------------------------------------------------------------------------- rules
    def act(self, obs: np.ndarray) -> np.ndarray:
        """Normalised ``[steering, acceleration]`` for one observation ``[OBS_DIM]``."""
        v = obs[ob.SPEED] * MAX_SPEED_MPS
        steering, curvature = self._steer(obs, v)
        accel = self._idm(obs, v, curvature)
        return np.array([steering, np.clip(accel / MAX_ACCEL_MPS2, -1.0, 1.0)])

    def _steer(self, obs: np.ndarray, v: float) -> tuple[float, float]:
        """Pure pursuit on the route point ``lookahead`` metres ahead of the projection, the route being the
        circle tangent to it at the projection point (from the lateral offset and heading error) through the
        first checkpoint (8 m) - or the second (16 m) for look-aheads beyond 8 m. Following the arc rather than
        the chord to a checkpoint keeps the car from cutting tight corners."""
        nav = obs[ob.NAV] * ob.NAV_SCALE_M
        d = obs[ob.LATERAL] * ob.LATERAL_SCALE_M
        herr = obs[ob.HEADING_ERROR] * math.pi
        tx, ty = math.cos(herr), math.sin(herr)  # route tangent at the projection, vehicle frame
        px, py = d * ty, -d * tx  # the projection point (the vehicle is d metres left of it)
        lookahead = min(2 * ob.CHECKPOINT_SPACING_M, max(self.min_lookahead_m, self.lookahead_s * v))
        cx, cy = nav[:2] if lookahead <= ob.CHECKPOINT_SPACING_M else nav[2:]
        rx, ry = cx - px, cy - py
        kappa = 2.0 * (tx * ry - ty * rx) / max(rx * rx + ry * ry, 1e-6)  # circle tangent at p through c
        if abs(kappa) < 1e-6:
            along, left = lookahead, 0.0
        else:
            along, left = math.sin(kappa * lookahead) / kappa, (1.0 - math.cos(kappa * lookahead)) / kappa
        gx, gy = px + along * tx - left * ty, py + along * ty + left * tx
        gy += self._edge_push(obs)
        dist = max(math.hypot(gx, gy), 1.0)
        curvature = 2.0 * gy / (dist * dist)  # = 2 sin(alpha) / dist
        lim = math.sin(MAX_BETA_RAD)
        sin_beta = min(lim, max(-lim, curvature * self.length / 2))
        delta = math.atan(2.0 * math.tan(math.asin(sin_beta)))
        return min(1.0, max(-1.0, delta / MAX_STEER_RAD)), curvature

    def _edge_push(self, obs: np.ndarray) -> float:
        """Lateral shift (m, + left) of the steering target away from a road edge closer than `edge_margin_m`
        to the car's side: logged routes through tight turns hug the kerb, and following them a little wide
        or tight would touch it."""
        d = obs[ob.EDGE_RAYS] * ob.EDGE_RANGE_M
        x, y = d * _EDGE_COS, d * _EDGE_SIN
        beside = (d < ob.EDGE_RANGE_M - 1e-3) & (np.abs(x) < self.length / 2 + 1.0)
        if not beside.any():
            return 0.0
        yb = y[beside]
        half_width = 1.0
        push = 0.0
        if (yb > 0).any():
            push -= max(0.0, self.edge_margin_m - (float(yb[yb > 0].min()) - half_width))
        if (yb < 0).any():
            push += max(0.0, self.edge_margin_m - (float(-yb[yb < 0].max()) - half_width))
        return push

    def _desired(self, obs: np.ndarray) -> float:
        if self.desired_speed == "reference":
            v0 = obs[ob.REF_SPEED] * MAX_SPEED_MPS
        elif self.desired_speed == "limit":
            v0 = obs[ob.SPEED_LIMIT] * MAX_SPEED_MPS
        else:
            v0 = float(self.desired_speed)
        return max(v0, self.min_desired_mps)

    def _leader(self, obs: np.ndarray, curvature: float) -> tuple[float, float]:
        """(gap m, closing speed m/s) of the closest vehicle in the predicted path; (inf, 0) if none."""
        gap, closing = math.inf, 0.0
        half = self.length / 2
        # Nearest-vehicle slots: centre positions and relative velocities.
        near = obs[ob.NEAREST].reshape(ob.N_NEAREST, ob.NEAREST_SLOTS)
        for present, dx, dy, dvx, _ in near:
            if present < 0.5:
                continue
            x, y = dx * ob.LIDAR_RANGE_M, dy * ob.LIDAR_RANGE_M
            if x > 0 and abs(y - 0.5 * curvature * x * x) < self.path_half_width:
                g = x - 2 * half  # centre distance minus both half lengths (assumed equal)
                if g < gap:
                    gap, closing = g, -dvx * ob.REL_SPEED_SCALE
        # Lidar hits on boxes: exact surface points, no speed (taken from the slots above when closer).
        d = obs[ob.LIDAR] * ob.LIDAR_RANGE_M
        hit = d < ob.LIDAR_RANGE_M - 1e-3
        if hit.any():
            hx, hy = d[hit] * np.cos(_LIDAR_ANG[hit]), d[hit] * np.sin(_LIDAR_ANG[hit])
            ok = (hx > 0) & (np.abs(hy - 0.5 * curvature * hx * hx) < self.path_half_width - 1.0)
            if ok.any():
                g = float(hx[ok].min()) - half
                if g < gap - 3.0:  # a car not among the nearest three (or bigger than assumed): no speed known
                    closing = 0.0
                gap = min(gap, g)
        return gap, closing

    def _idm(self, obs: np.ndarray, v: float, curvature: float) -> float:
        v0 = self._desired(obs)
        # Free road: a proportional speed controller rather than IDM's (1 - (v/v0)^4) term, which approaches
        # v0 slowly at highway speeds and would let the car fall behind the route's logged timing.
        a = min(self.max_accel, max(-self.comfort_decel, self.speed_gain * (v0 - v)))
        gap, closing = self._leader(obs, curvature)
        if math.isfinite(gap):
            s_star = self.min_gap_m + max(
                0.0, v * self.time_headway_s + v * closing / (2 * math.sqrt(self.max_accel * self.comfort_decel))
            )
            a -= self.max_accel * (s_star / max(gap, 0.1)) ** 2
        return max(-MAX_ACCEL_MPS2, a)
