"""`GooseSpec`: the settings GOOSE's environment, agent file and generator must agree on (goal, action limits,
observation layout), kept in one place so a trained agent carries them with it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from seal.adversaries.base import K_ROLLOUTS
from seal.core.config import check_keys

GOAL_NAMES = ("min_gap_m", "max_abs_acc_mps2", "max_abs_yaw_rate_radps")
"""Goal components: the smallest ego-adversary body gap, the adversary's largest |acceleration| (time derivative
of its speed) and largest |yaw rate| over a roll-out."""

DECELERATION_GOAL = (0.0, 8.0, 0.7)
"""GOOSE's "deceleration" goal: contact (gap 0) with |acc| <= 8 m/s^2 and |yaw rate| <= 0.7 rad/s."""

TIMINGS = ("curve", "log")
"""How the adversary moves along its curve: ``"curve"``: the curve is a trajectory, its parameter is time (GOOSE's
NURBS trajectories carry the time at each control point, as OpenSCENARIO's timed NURBS do), so an edit changes
where *and when* the adversary is; ``"log"``: the path only, driven with the logged speed profile re-mapped to
the curve's length (agents trained before the option existed)."""


@dataclass(frozen=True)
class GooseSpec:
    """GOOSE settings.

    Attributes:
        desired_goal: target ``(min_gap_m, max_abs_acc_mps2, max_abs_yaw_rate_radps)``; reached when the
            achieved gap is at most the target gap and both kinematic maxima are at most their targets.
        max_updates: curve updates (policy steps, i.e. observed roll-outs) per scenario (K).
        shift_m: largest move of a control point's x or y per update (m, adversary's initial frame).
        max_offset_m: largest total move of a control point's x or y from the fitted curve (m).
        point_scale: factors on ``shift_m`` and ``max_offset_m`` for control points 1..4. Point 1 sets the
            curve's initial direction (C'(0) = 6 (P1 - P0)), so a sideways move of it turns the adversary at once:
            4 m at 12 m ahead is ~0.3 rad in 0.1 s (3 rad/s); smaller moves there keep edits feasible.
        weight_factor: largest multiplicative change of a weight per update (weights scale by
            ``weight_factor ** a``, ``a`` in [-1, 1]).
        weight_min, weight_max: weight bounds.
        reward: ``"dense"`` (minus the normalised goal violation, 0 on success) or ``"sparse"`` (-1 / 0).
        obs_stride: the roll-out is sampled every ``obs_stride`` steps for the GRU (10 = 1 s: the GRU's cost grows
            with the sequence length; the closest approach is given exactly besides).
        obs_horizon: steps after the current step covered by the roll-out observation (the env horizon, 90).
        timing: ``"curve"`` or ``"log"`` (see `TIMINGS`).
        obs_targets: observe the ego relative to each control point at the point's time in the last roll-out
            (`seal.adversaries.goose.obs.TARGET_FEATURES`).
    """

    desired_goal: tuple[float, float, float] = DECELERATION_GOAL
    max_updates: int = K_ROLLOUTS
    shift_m: float = 4.0
    max_offset_m: float = 20.0
    point_scale: tuple[float, float, float, float] = (0.25, 0.5, 1.0, 1.0)
    weight_factor: float = 2.0
    weight_min: float = 0.2
    weight_max: float = 5.0
    reward: str = "dense"
    obs_stride: int = 10
    obs_horizon: int = 90
    timing: str = "curve"
    obs_targets: bool = True

    def __post_init__(self) -> None:
        goal = tuple(float(g) for g in self.desired_goal)
        if len(goal) != len(GOAL_NAMES) or min(goal) < 0:
            raise ValueError(f"desired_goal must be {len(GOAL_NAMES)} non-negative numbers {GOAL_NAMES}, got {goal}")
        object.__setattr__(self, "desired_goal", goal)
        scale = tuple(float(v) for v in self.point_scale)
        if len(scale) != 4 or min(scale) <= 0:
            raise ValueError(f"point_scale must be 4 positive numbers (control points 1..4), got {scale}")
        object.__setattr__(self, "point_scale", scale)
        if self.timing not in TIMINGS:
            raise ValueError(f"timing must be one of {TIMINGS}, got {self.timing!r}")
        if self.reward not in ("dense", "sparse"):
            raise ValueError(f"reward must be 'dense' or 'sparse', got {self.reward!r}")
        for name in ("max_updates", "obs_stride", "obs_horizon"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("shift_m", "max_offset_m", "weight_factor", "weight_min", "weight_max"):
            if not float(getattr(self, name)) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)}")
        if not self.weight_min <= 1.0 <= self.weight_max:
            raise ValueError(f"weight bounds must contain 1, got [{self.weight_min}, {self.weight_max}]")

    @property
    def goal_array(self) -> np.ndarray:
        return np.asarray(self.desired_goal, dtype=np.float32)

    @property
    def n_time(self) -> int:
        """Roll-out samples in the observation."""
        return self.obs_horizon // self.obs_stride

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["desired_goal"] = list(self.desired_goal)
        d["point_scale"] = list(self.point_scale)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "goose spec") -> GooseSpec:
        """Build from a plain dict; unknown keys raise an error naming them and ``where``."""
        check_keys(cls, d, f"{where}: GOOSE spec")
        d = dict(d)
        for key in ("desired_goal", "point_scale"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**d)
