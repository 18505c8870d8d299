"""Metrics of multimodal predictions: minADE / minFDE at k candidates, miss rate, and drivability.

Definitions (all in metres, seconds, radians):

* ADE of a candidate: mean over the valid future steps of the distance to the logged position; FDE: the
  distance at the last valid future step. minADE@k / minFDE@k: the smallest over the k most probable
  candidates (so @1 is the most probable candidate alone).
* Miss: minFDE@6 above a threshold (default 2 m, Argoverse / Waymo style, here at the 8 s horizon).
* Drivable candidate: every step has |longitudinal acceleration| <= 8 m/s^2 (speed change between steps / dt),
  |yaw rate| <= 1 rad/s (heading change between steps / dt, counted only where the speed is above 1 m/s on both
  steps, because the heading of a near-stopped vehicle from position differences is noise), and every 0.5 s
  sample lies within one lane width of the nearest lane centreline ("on or near the road"). A scenario's map is
  a crop, so lanes that run off its edge are continued straight (`seal.models.prior.lanes.open_map_edges`); the
  "strict" variant measures against the cropped map as stored, where a fast agent's futures can pass a lane's
  end at the map edge.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from seal.core.geometry import wrap_angle
from seal.core.road import RoadDescription
from seal.core.scenario import DT_S

ACC_LIMIT_MPS2 = 8.0
YAW_RATE_LIMIT_RPS = 1.0
YAW_RATE_MIN_SPEED_MPS = 1.0
ROAD_CHECK_EVERY = 5  # steps between "on or near the road" samples (0.5 s)


def displacement_errors(
    pred_xy: torch.Tensor, future_xy: torch.Tensor, future_valid: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """ADE and FDE of every candidate.

    Args:
        pred_xy: ``[B, K, T, 2]`` candidates (m).
        future_xy: ``[B, T, 2]`` logged future (m).
        future_valid: ``[B, T]`` bool; each row needs at least one valid step.

    Returns:
        ``ade`` and ``fde``, each ``[B, K]`` (m).
    """
    dist = torch.linalg.norm(pred_xy - future_xy[:, None], dim=-1)  # [B, K, T]
    m = future_valid[:, None].to(dist.dtype)
    ade = (dist * m).sum(-1) / m.sum(-1).clamp(min=1.0)
    t = future_valid.shape[1]
    last = t - 1 - torch.argmax(future_valid.flip(-1).to(torch.int8), dim=-1)  # [B]
    fde = torch.gather(dist, 2, last.view(-1, 1, 1).expand(-1, dist.shape[1], 1)).squeeze(-1)
    return ade, fde


def top_k_min(errors: torch.Tensor, logits: torch.Tensor, k: int) -> torch.Tensor:
    """Per row, the smallest of ``errors`` ``[B, K]`` over the ``k`` largest ``logits`` ``[B, K]``."""
    k = min(k, errors.shape[1])
    top = torch.topk(logits, k, dim=1).indices
    return torch.gather(errors, 1, top).min(dim=1).values


@dataclass(frozen=True)
class Drivability:
    """Per candidate: maximum |acceleration| (m/s^2), maximum |yaw rate| (rad/s, above 1 m/s), maximum distance to
    the road beyond one lane width (m, <= 0 means on or near the road) with the map edges opened and on the
    stored (strict) map. Arrays ``[N]``."""

    max_acc_mps2: np.ndarray
    max_yaw_rate_rps: np.ndarray
    max_road_excess_m: np.ndarray
    max_road_excess_strict_m: np.ndarray

    @property
    def within_acc(self) -> np.ndarray:
        return self.max_acc_mps2 <= ACC_LIMIT_MPS2

    @property
    def within_yaw(self) -> np.ndarray:
        return self.max_yaw_rate_rps <= YAW_RATE_LIMIT_RPS

    @property
    def on_road(self) -> np.ndarray:
        return self.max_road_excess_m <= 0.0

    @property
    def on_road_strict(self) -> np.ndarray:
        return self.max_road_excess_strict_m <= 0.0

    @property
    def drivable(self) -> np.ndarray:
        return self.within_acc & self.within_yaw & self.on_road

    @property
    def drivable_strict(self) -> np.ndarray:
        return self.within_acc & self.within_yaw & self.on_road_strict


def kinematic_limits(
    xy: np.ndarray, start_xy: np.ndarray, start_heading: float, dt_s: float = DT_S
) -> tuple[np.ndarray, np.ndarray]:
    """Maximum |acceleration| and |yaw rate| of trajectories ``[K, T, 2]`` that start at ``start_xy``.

    Speed and heading follow from position differences (the point before step 0 is ``start_xy``); a step
    shorter than 1 mm keeps the previous heading.
    """
    xy = np.asarray(xy, dtype=np.float64)
    prev = np.concatenate([np.broadcast_to(np.asarray(start_xy, np.float64), (xy.shape[0], 1, 2)), xy[:, :-1]], 1)
    delta = xy - prev
    speed = np.linalg.norm(delta, axis=-1) / dt_s
    heading = np.arctan2(delta[..., 1], delta[..., 0])
    heading = np.where(speed * dt_s > 1e-3, heading, np.nan)
    heading[:, 0] = np.where(np.isnan(heading[:, 0]), start_heading, heading[:, 0])
    for j in range(1, heading.shape[1]):  # carry the heading over stops
        heading[:, j] = np.where(np.isnan(heading[:, j]), heading[:, j - 1], heading[:, j])
    acc = np.abs(np.diff(speed, axis=1)) / dt_s
    yaw = np.abs(wrap_angle(np.diff(heading, axis=1))) / dt_s
    fast = (speed[:, 1:] > YAW_RATE_MIN_SPEED_MPS) & (speed[:, :-1] > YAW_RATE_MIN_SPEED_MPS)
    return acc.max(axis=1, initial=0.0), np.where(fast, yaw, 0.0).max(axis=1, initial=0.0)


def drivability(
    xy: np.ndarray, start_xy: np.ndarray, start_heading: float, road: RoadDescription
) -> Drivability:
    """`Drivability` of candidates ``[K, T, 2]`` (world frame) that start at ``start_xy`` on ``road``."""
    from seal.models.prior.lanes import distance_to_lanes, open_map_edges

    acc, yaw = kinematic_limits(xy, start_xy, start_heading)
    samples = np.asarray(xy)[:, ROAD_CHECK_EVERY - 1 :: ROAD_CHECK_EVERY]
    dist, width = distance_to_lanes(open_map_edges(road), samples)
    dist_strict, width_strict = distance_to_lanes(road, samples)
    return Drivability(
        max_acc_mps2=acc, max_yaw_rate_rps=yaw, max_road_excess_m=(dist - width).max(axis=1),
        max_road_excess_strict_m=(dist_strict - width_strict).max(axis=1),
    )
