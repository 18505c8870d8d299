"""`Rollout`: the executed record of one `ScenarioEnv` episode (what generators keep, K = 5 per scenario)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seal.core.outcome import Outcome
from seal.core.scenario import CURRENT_STEP, HEADING, VALID, X, Y


@dataclass
class Rollout:
    """Executed tracks and events of one episode. Plain data: picklable, numpy + builtins only.

    Attributes:
        scenario_id: the scenario played.
        tracks: ``[A, T, 8]`` float32 in the scenario track layout, ``T = CURRENT_STEP + 1 + horizon_steps``;
            column ``t`` is scenario step ``t``: steps ``0..CURRENT_STEP`` are copied from the log, later
            steps hold the executed states (valid = 0 where an agent was absent or the episode had ended).
        agent_ids: ``[A]`` int64, same order as the scenario.
        ego_id, adv_id: the ego and adversary ids.
        last_step: the last executed scenario step (``CURRENT_STEP + number of env steps``).
        outcome: the reason the episode ended, a `seal.core.outcome.Outcome` (a `str`: ``"success"``, ``"crash"``,
            ``"out_of_road"``, ``"timeout"``; loaded roll-outs hold the plain string); a crash in an episode that
            continued past it is still in `ego_crashes`.
        ego_crashes: ``(step, other_agent_id)`` for every step where the ego overlapped another agent.
        adv_crashes: ``(step, other_agent_id)`` where the adversary overlapped an agent other than the ego.
        out_of_road_step: step where the ego left the road, else None.
        success_step: step where the ego arrived, else None.
        route_completion: ego route completion at the end (share of the logged route, see `ScenarioEnv`).
        episode_return: sum of rewards.
        adversary: name of the adversary behaviour class.
    """

    scenario_id: str
    tracks: np.ndarray
    agent_ids: np.ndarray
    ego_id: int
    adv_id: int
    last_step: int = CURRENT_STEP
    outcome: str = Outcome.TIMEOUT
    ego_crashes: list[tuple[int, int]] = field(default_factory=list)
    adv_crashes: list[tuple[int, int]] = field(default_factory=list)
    out_of_road_step: int | None = None
    success_step: int | None = None
    route_completion: float = 0.0
    episode_return: float = 0.0
    adversary: str = ""

    def index_of(self, agent_id: int) -> int:
        return int(np.flatnonzero(self.agent_ids == agent_id)[0])

    @property
    def ego_track(self) -> np.ndarray:
        """``[T, 8]`` executed ego track."""
        return self.tracks[self.index_of(self.ego_id)]

    @property
    def adv_track(self) -> np.ndarray:
        """``[T, 8]`` executed adversary track."""
        return self.tracks[self.index_of(self.adv_id)]

    @property
    def crashed(self) -> bool:
        return bool(self.ego_crashes)

    @property
    def first_crash_step(self) -> int | None:
        return self.ego_crashes[0][0] if self.ego_crashes else None

    @property
    def n_steps(self) -> int:
        """Number of executed env steps."""
        return self.last_step - CURRENT_STEP

    def valid(self) -> np.ndarray:
        """``[A, T]`` bool validity."""
        return self.tracks[:, :, VALID] > 0.5

    def rear_end_by_background(self, max_heading_deg: float = 45.0) -> bool:
        """Whether the ego's first crash is a hit from behind by background traffic: the agent it touches first
        (not the adversary) has its centre behind the ego's (in the ego's frame) and drives within
        ``max_heading_deg`` of the ego's heading (issue 22: the crashes a replayed background causes)."""
        if not self.ego_crashes:
            return False
        t = self.ego_crashes[0][0]
        others = [i for s, i in self.ego_crashes if s == t and i != self.adv_id]
        if not others or t >= self.tracks.shape[1]:
            return False
        ego = self.tracks[self.index_of(self.ego_id), t].astype(np.float64)
        c, s = np.cos(ego[HEADING]), np.sin(ego[HEADING])
        for agent_id in others:
            other = self.tracks[self.index_of(agent_id), t].astype(np.float64)
            behind = c * (other[X] - ego[X]) + s * (other[Y] - ego[Y]) < 0.0
            dh = abs(float(np.angle(np.exp(1j * (other[HEADING] - ego[HEADING])))))
            if behind and dh < np.radians(max_heading_deg):
                return True
        return False
