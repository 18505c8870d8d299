"""`MultiAgentSim`: every vehicle of a scenario driven by a policy from its own observation (the SEAL skill
demonstrations: thesis 6.3.3, "all agents in the scenario follow the IDM policy").

`ScenarioEnv` drives one ego and one adversary; here every ``vehicle`` agent is driven, with the same pieces:
the bicycle model (`seal.envs.kinematics`), the observation builder (`seal.envs.observation`, from each agent's own
viewpoint on a route = its logged track) and the simulation core of `ScenarioEnv` (`seal.envs.sim_core`: placement,
the box-overlap test, the road checks). Agents of other types replay
their log.

Step semantics (as in the env): at scenario step ``t`` `observe` gives the observation of every driven agent,
`step` takes their actions ``[steering, acceleration]`` in ``[-1, 1]^2``, moves everybody to ``t + 1`` and then
ends agents for which something happened at ``t + 1``, in this priority:

* ``collision``: its box overlaps another present agent's box (both agents end; a driven agent hit by a replayed
  one ends too);
* ``finished``: it passed the end of its route where its log ends before the scenario does (it left the map), or
  broke a road rule below beyond the end of its route (its route ran out: a heuristic faster than the log). An
  agent whose log runs to the end of the scenario (e.g. one queueing at a junction) drives on past its last
  logged position along the route's straight extension;
* ``out_of_road``: a box corner leaves the drivable area by more than ``offroad_tolerance_m`` where the agent's
  own logged box was on it (so agents that enter or leave the map over a road end, with half the car beyond it,
  are not out of road there), the box crosses a ``continuous`` line its own log does not come within
  ``line_margin_m`` of (the heuristic rounds corners a little differently from the log), or it is more than
  ``max_lateral_m`` from its route.

Ended agents leave the simulation (no wrecks: they would block lanes in ways the heuristic cannot handle).
Agents whose log starts after ``start_step`` enter at their first logged state when that spot is free, and are
driven from then on. At ``end_step`` the remaining agents end with ``horizon``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely

from seal.core.geometry import pairwise_overlaps, track_corners
from seal.core.scenario import N_STEPS, VALID, Scenario
from seal.envs.kinematics import AgentState, bicycle_step
from seal.envs.observation import OBS_DIM, ObservationBuilder
from seal.envs.road_geometry import RoadGeometry, get_road_geometry
from seal.envs.route import Route, RouteProjection
from seal.envs.sim_core import RoadChecks, logged_rows, state_row

END_REASONS = ("horizon", "finished", "collision", "out_of_road")
"""Why an agent's segment ended (the stored code is the index)."""
HORIZON, FINISHED, COLLISION, OUT_OF_ROAD = range(len(END_REASONS))

__all__ = ["COLLISION", "END_REASONS", "FINISHED", "HORIZON", "OUT_OF_ROAD", "AgentEnd", "MultiAgentSim", "SimConfig"]

@dataclass(frozen=True)
class SimConfig:
    """Road checks and time span of a `MultiAgentSim`.

    Attributes:
        start_step: scenario step the simulation starts from (agents at their logged state).
        end_step: last scenario step simulated (the final state; the last actions are taken at ``end_step - 1``).
        max_lateral_m: distance from the own route beyond which an agent is out of road (m).
        offroad_tolerance_m: how far a box corner may leave the drivable area (m).
        check_continuous_lines: crossing a ``continuous`` line (not crossed by the agent's own log) is out of road.
        line_margin_m: ``continuous`` lines within this distance of the agent's logged boxes may be crossed (m).
        finish_margin_m: an agent that leaves the map finishes this far before the end of its route (m).
    """

    start_step: int = 0
    end_step: int = N_STEPS - 1
    max_lateral_m: float = 10.0
    offroad_tolerance_m: float = 0.5
    check_continuous_lines: bool = True
    line_margin_m: float = 0.5
    finish_margin_m: float = 1.0

    def __post_init__(self) -> None:
        if not 0 <= self.start_step < self.end_step <= N_STEPS - 1:
            raise ValueError(
                f"SimConfig: need 0 <= start_step < end_step <= {N_STEPS - 1}, got {self.start_step}, {self.end_step}"
            )


@dataclass
class AgentEnd:
    """One driven agent's simulated span: it acted on steps ``[start_step, end_step)`` and ``end_reason`` (an
    index into `END_REASONS`) happened at ``end_step``."""

    index: int
    agent_id: int
    start_step: int
    end_step: int
    end_reason: int
    """Index into `END_REASONS`."""
    row: np.ndarray | None = None
    """The agent's track row ``[8]`` at ``end_step`` (where it was when it ended; the simulation drops it)."""


class MultiAgentSim:
    """Every vehicle of ``scenario`` driven by actions given per step (see the module docstring).

    Args:
        scenario: the scenario.
        config: time span and road checks.

    Attributes:
        t: current scenario step.
        ends: `AgentEnd` of every driven agent that has ended so far (all of them once `done`).
    """

    def __init__(self, scenario: Scenario, config: SimConfig | None = None) -> None:
        self.scenario = scenario
        self.config = cfg = config or SimConfig()
        self.geometry: RoadGeometry = get_road_geometry(scenario.road)
        self.road = RoadChecks(self.geometry, cfg.max_lateral_m, cfg.offroad_tolerance_m, cfg.check_continuous_lines)
        self._builder = ObservationBuilder(self.geometry)
        self._log = scenario.tracks.astype(np.float64)
        n = scenario.n_agents
        valid = self._log[:, :, VALID] > 0.5
        self._first = np.argmax(valid, axis=1)
        self._last = valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1)
        driven = np.array([t == "vehicle" for t in scenario.agent_types], dtype=bool)
        # A driven agent needs a future in the log after it enters (else it has no route to follow).
        self._driven = driven & (self._last > np.maximum(self._first, cfg.start_step)) & (
            self._first <= cfg.end_step - 1
        )
        self.t = cfg.start_step
        self._states: list[AgentState | None] = [None] * n
        self._routes: list[Route | None] = [None] * n
        self._proj: list[RouteProjection | None] = [None] * n
        self._exempt: list[np.ndarray | None] = [None] * n
        self._log_s: dict[int, np.ndarray] = {}
        """Per driven agent that entered: arc length of its valid logged steps along its route (m)."""
        self._log_on_road: dict[int, np.ndarray] = {}
        """Per driven agent that entered: its logged box is on the drivable area at those steps."""
        self._start: dict[int, int] = {}
        self._cur = np.zeros((n, 8), dtype=np.float64)
        self.ends: list[AgentEnd] = []
        self._pending = {int(i) for i in np.flatnonzero(self._driven)}
        self._place_replayed(self.t)
        self._enter(self.t)

    # ------------------------------------------------------------------------------------------------ queries
    @property
    def active(self) -> np.ndarray:
        """Indices (scenario rows) of the driven agents present at `t`, ascending."""
        return np.array(sorted(self._start), dtype=np.int64)

    @property
    def done(self) -> bool:
        return self.t >= self.config.end_step or (not self._start and not self._pending)

    def state(self, index: int) -> AgentState | None:
        """Current state of driven agent ``index`` (None when it is not active)."""
        return self._states[index] if index in self._start else None

    def boxes(self) -> np.ndarray:
        """``[A, 8]`` current rows of all agents (track layout; valid = 0 where absent)."""
        return self._cur.copy()

    def observe(self) -> tuple[np.ndarray, np.ndarray]:
        """Active driven agents (indices ``[n]``) and their own observations ``[n, OBS_DIM]`` float32 at `t`."""
        idx = self.active
        obs = np.empty((idx.size, OBS_DIM), dtype=np.float32)
        cur = self._cur
        present = cur[:, VALID] > 0.5
        for k, i in enumerate(idx.tolist()):
            mask = present.copy()
            mask[i] = False
            obs[k] = self._builder.build(self._states[i], self._routes[i], cur[mask, :7], self._proj[i])
        return idx, obs

    # ------------------------------------------------------------------------------------------------ dynamics
    def step(self, indices: np.ndarray, actions: np.ndarray) -> list[AgentEnd]:
        """Apply ``actions [n, 2]`` (``[steering, acceleration]``) to the agents ``indices`` (all active agents,
        as returned by `observe`), advance to ``t + 1``; returns the agents that ended at ``t + 1``."""
        if self.done:
            raise RuntimeError("MultiAgentSim.step() after the simulation ended")
        idx = np.asarray(indices, dtype=np.int64)
        if idx.tolist() != self.active.tolist():
            raise ValueError("MultiAgentSim.step: actions must be given for exactly the active agents, in order")
        act = np.asarray(actions, dtype=np.float64).reshape(idx.size, 2)
        for k, i in enumerate(idx.tolist()):
            self._states[i] = bicycle_step(self._states[i], act[k, 0], act[k, 1])
        self.t += 1
        t = self.t
        self._place_replayed(t)
        for i in idx.tolist():
            self._cur[i] = state_row(self._states[i])
        ended = self._check(idx)
        self._enter(t)
        if t >= self.config.end_step:
            for i in self.active.tolist():
                ended.append(self._end(i, HORIZON))
            self._pending.clear()
        return ended

    def _check(self, idx: np.ndarray) -> list[AgentEnd]:
        cfg, road = self.config, self.road
        cur = self._cur
        present = np.flatnonzero(cur[:, VALID] > 0.5)
        reason: dict[int, int] = {}
        if present.size > 1:
            hit = pairwise_overlaps(cur[present])
            for k in np.flatnonzero(hit.any(axis=1)).tolist():
                i = int(present[k])
                if i in self._start:
                    reason[i] = COLLISION
        for i in idx.tolist():
            state, route = self._states[i], self._routes[i]
            proj = route.project(state.x, state.y, self._proj[i].segment)
            self._proj[i] = proj
            if i in reason:
                continue
            off_road = (
                self._off_road(i, state, proj.s)
                or road.too_far(proj.lateral)
                or road.crosses_solid(state, self._exempt[i])
            )
            if proj.s >= route.length - cfg.finish_margin_m and (self._last[i] < N_STEPS - 1 or off_road):
                reason[i] = FINISHED
            elif off_road:
                reason[i] = OUT_OF_ROAD
        return [self._end(i, r) for i, r in sorted(reason.items())]

    def _off_road(self, i: int, state: AgentState, s: float) -> bool:
        """A box corner is off the drivable area at a place where the agent's logged box was on it."""
        if self.road.corners_on_road(state):
            return False
        log_s, log_on = self._log_s[i], self._log_on_road[i]
        k = int(np.searchsorted(log_s, s))
        return bool(log_on[max(0, k - 1) : k + 1].all())

    def _end(self, i: int, reason: int) -> AgentEnd:
        end = AgentEnd(i, int(self.scenario.agent_ids[i]), self._start.pop(i), self.t, reason, self._cur[i].copy())
        self.ends.append(end)
        self._cur[i] = 0.0
        self._states[i] = None
        return end

    def _place_replayed(self, t: int) -> None:
        """Log rows at step ``t`` for the agents that are not driven (and empty rows for pending ones)."""
        rows = logged_rows(self._log, t)
        for i in range(self.scenario.n_agents):
            if not self._driven[i]:
                self._cur[i] = rows[i]
            elif i not in self._start:
                self._cur[i] = 0.0

    def _log_road_profile(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Arc length ``[V]`` of each valid logged step of agent ``i`` along its route (m) and whether the logged
        box there lies on the drivable area (within the tolerance)."""
        track = self._log[i][self._log[i][:, VALID] > 0.5]
        step = np.hypot(np.diff(track[:, 0]), np.diff(track[:, 1]))
        log_s = np.concatenate([[0.0], np.cumsum(step)])
        corners = track_corners(track)  # [V, 4, 2]
        xs, ys = corners[..., 0], corners[..., 1]
        tol = self.config.offroad_tolerance_m
        # The grown area is cached per road by `RoadGeometry` (the same one `on_road` tests against).
        area = self.geometry._grown(tol) if tol > 0 else self.geometry.drivable
        on = shapely.contains_xy(area, xs.ravel(), ys.ravel()).reshape(-1, 4).all(axis=1)
        return log_s, on

    def _enter(self, t: int) -> None:
        """Start driving the pending agents whose log is valid at ``t`` and whose spot is free."""
        for i in sorted(self._pending):
            if self._first[i] > t:
                continue
            self._pending.discard(i)
            if self._last[i] <= t:
                continue  # its log ended before it could enter
            row = self._log[i, t]
            present = np.flatnonzero(self._cur[:, VALID] > 0.5)
            if present.size and pairwise_overlaps(np.vstack([row[None], self._cur[present]]))[0].any():
                continue  # the spot is taken (someone drove into it): this agent never enters
            self._states[i] = state = AgentState.from_track_row(row)
            route = Route.from_track(self._log[i], start_step=t)
            self._routes[i] = route
            self._proj[i] = route.project(state.x, state.y, route.start_segment)
            self._log_s[i], self._log_on_road[i] = self._log_road_profile(i)
            if self.config.check_continuous_lines:
                boxes = self._log[i][self._log[i][:, VALID] > 0.5][:, [0, 1, 2, 5, 6]]
                boxes[:, 3:] += 2.0 * self.config.line_margin_m
                hits = self.geometry.continuous_hits_along(boxes)
                self._exempt[i] = hits if hits.any() else None
            self._start[i] = t
            self._cur[i] = row

