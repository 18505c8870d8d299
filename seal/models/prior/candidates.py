"""Candidate adversary futures: the contract between the trajectory prior and the generators that use it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from seal.core.scenario import DT_S


@dataclass(frozen=True)
class Candidates:
    """K candidate futures of one agent, in the scenario's world frame.

    Step ``j`` of a candidate is scenario step ``CURRENT_STEP + 1 + j`` (so 80 steps cover the 8 s future at
    10 Hz). Candidates are sorted by probability, most likely first.

    Attributes:
        xy: ``[K, T, 2]`` positions in metres.
        heading: ``[K, T]`` headings in radians, derived from the positions.
        speed: ``[K, T]`` speeds in m/s, derived from the positions.
        probs: ``[K]`` probabilities (non-negative, summing to 1).
        agent_index: index of the agent in ``scenario.tracks``.
        fallback: ``None`` when the trajectory prior's network produced the candidates, else why a fallback
            (constant velocity, see `seal.models.prior.constant_velocity_candidates`) was used instead.
    """

    xy: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    probs: np.ndarray
    agent_index: int
    fallback: str | None = None

    def __post_init__(self) -> None:
        k, t, two = self.xy.shape
        if two != 2 or self.heading.shape != (k, t) or self.speed.shape != (k, t) or self.probs.shape != (k,):
            raise ValueError(
                f"Candidates: inconsistent shapes xy {self.xy.shape}, heading {self.heading.shape}, "
                f"speed {self.speed.shape}, probs {self.probs.shape}"
            )

    @property
    def n_candidates(self) -> int:
        return int(self.xy.shape[0])

    @property
    def n_steps(self) -> int:
        return int(self.xy.shape[1])

    @classmethod
    def from_positions(
        cls, xy: np.ndarray, probs: np.ndarray, start_xy: np.ndarray, start_heading: float, agent_index: int,
        fallback: str | None = None,
    ) -> Candidates:
        """Build candidates from positions alone: heading and speed follow from the finite differences.

        Args:
            xy: ``[K, T, 2]`` future positions (m).
            probs: ``[K]`` probabilities; sorted here, most likely first.
            start_xy: ``[2]`` the agent's current position (m), the point before step 0.
            start_heading: the agent's current heading (rad), used while a candidate stands still.
            agent_index: index of the agent in the scenario.
            fallback: see the class attribute.
        """
        xy = np.asarray(xy, dtype=np.float64)
        probs = np.asarray(probs, dtype=np.float64)
        order = np.argsort(-probs, kind="stable")
        xy, probs = xy[order], probs[order]
        prev = np.concatenate([np.broadcast_to(start_xy, (xy.shape[0], 1, 2)), xy[:, :-1]], axis=1)
        delta = xy - prev
        step_m = np.linalg.norm(delta, axis=-1)
        heading = np.arctan2(delta[..., 1], delta[..., 0])
        # A stopped candidate keeps its last heading instead of the arbitrary atan2(0, 0): forward-fill from the
        # last moving step (vectorised: index of the last moving step so far, per row).
        moving = step_m > 1e-3
        heading[:, 0] = np.where(moving[:, 0], heading[:, 0], start_heading)
        moving[:, 0] = True
        last = np.maximum.accumulate(np.where(moving, np.arange(heading.shape[1]), 0), axis=1)
        heading = np.take_along_axis(heading, last, axis=1)
        return cls(
            xy=xy, heading=heading, speed=step_m / DT_S, probs=probs / probs.sum(), agent_index=agent_index,
            fallback=fallback,
        )
