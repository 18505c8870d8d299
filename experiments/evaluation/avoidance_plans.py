"""The ego plans ``seal eval avoidability`` tries on a crash, in two action spaces.

``actions`` (any driver): the heuristic driver plus a piecewise-constant offset on its normalised
``[steering, acceleration]``: full braking / full throttle from each segment on, then random offsets.

``skills`` (what a ReSkill ego can express): the ego's own high-level agent with its skill choices changed. A ReSkill
ego acts only through skills of its benign prior within ``noise_bound`` of the prior's mode (its high-level action
``u`` in ``[-1, 1]^L``), so a crash that the ``actions`` plans avoid may lie outside what this ego can do. The
extreme plans pick, at each skill decision from segment J on, the candidate skill whose first decoded action brakes
(throttles) hardest; the random plans add a piecewise-constant offset to the ego's ``u`` (clipped to the box).
Comparing the two spaces on the same crashes says whether a ReSkill ego's failures are a limit of its skill space
or of what it learned.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from seal.core.scenario import Scenario
from seal.envs.heuristic import HeuristicDriver
from seal.experiments.training.skill_prior import EgoSkills, noise_of
from seal.models.skills.reach import box_candidates

PLAN_SPACES = ("actions", "skills")


@dataclass(frozen=True)
class AvoidabilityConfig:
    """How other ego plans are searched for a crashed episode."""

    n_plans: int = 64
    """Plans tried per crash (in the ``actions`` space besides the heuristic driver; the first 2 x ``segments`` are
    full braking / full throttle from each segment on, the rest random)."""
    segments: int = 6
    """Pieces of the episode horizon over which an offset stays constant."""
    max_accel_offset: float = 2.0
    """Largest acceleration offset of a random ``actions`` plan (normalised action units; the action is clipped to
    [-1, 1], so 2 can override any heuristic acceleration)."""
    max_steer_offset: float = 0.3
    """Largest steering offset of a random ``actions`` plan (normalised action units, x the largest steering
    angle)."""
    steer_share: float = 0.5
    """Share of a random ``actions`` plan's segments that get a steering offset (the others keep the heuristic
    steering)."""
    plan_space: str = "actions"
    """``actions``: plans around the heuristic driver in the env's action space; ``skills``: plans in a ReSkill
    ego's skill space (module docstring)."""
    max_skill_offset: float = 1.0
    """Largest offset per latent dimension of a random ``skills`` plan on the high-level action ``u`` (in its
    [-1, 1] units: 1 moves the ego's choice up to half the box, the extreme plans reach the corners)."""
    skill_candidates: int = 32
    """Random high-level actions (besides the ego's own and the box's corners) among which an extreme ``skills``
    plan picks the hardest braking / throttling skill."""
    seed: int = 0
    """Seed of the random plans (with the scenario index)."""

    def __post_init__(self) -> None:
        if self.n_plans < 0 or self.segments < 1:
            raise ValueError(f"n_plans must be >= 0 and segments >= 1, got {self.n_plans} and {self.segments}")
        if not 0.0 <= self.steer_share <= 1.0:
            raise ValueError(f"steer_share must be in [0, 1], got {self.steer_share}")
        if self.plan_space not in PLAN_SPACES:
            raise ValueError(f"plan_space must be one of {', '.join(PLAN_SPACES)}, got {self.plan_space!r}")
        if self.max_skill_offset < 0 or self.skill_candidates < 0:
            raise ValueError("max_skill_offset and skill_candidates must be >= 0, got "
                             f"{self.max_skill_offset} and {self.skill_candidates}")


class PlanEgo:
    """The heuristic driver plus a piecewise-constant offset ``[segments, 2]`` (steering, acceleration) on its
    normalised action, each segment ``segment_steps`` env steps long from the episode's first step."""

    name = "plan"

    def __init__(self, offsets: np.ndarray, segment_steps: int) -> None:
        self.offsets = np.asarray(offsets, dtype=np.float64)
        self.segment_steps = max(1, int(segment_steps))
        self.driver = HeuristicDriver()
        self._first_step: int | None = None

    def reset(self, scenario: Scenario) -> None:
        self._first_step = None

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        if self._first_step is None:
            self._first_step = step
        segment = min((step - self._first_step) // self.segment_steps, len(self.offsets) - 1)
        action = self.driver.act(np.asarray(observation, dtype=np.float64)) + self.offsets[segment]
        return np.clip(action, -1.0, 1.0)


def reskill_skills(ego: Any) -> EgoSkills:
    """The skill model of a ReSkill ego (`seal.experiments.training.egos.ReSkillEgo`); ValueError for any other."""
    skills = getattr(getattr(ego, "policy", None), "skills", None)
    if skills is None:
        raise ValueError(f"plan_space 'skills' needs a ReSkill ego, got {getattr(ego, 'name', ego)!r}")
    return skills


class SkillPlanEgo:
    """A ReSkill ego (`seal.experiments.training.egos.ReSkillEgo`) whose skill choices follow a plan.

    Each segment (``segment_steps`` env steps from the episode's first step) either offsets the ego's high-level
    action ``u`` by ``offsets[segment] [L]`` (clipped to [-1, 1]) or, where ``extreme[segment]`` is -1 / +1, takes
    the skill among ``[u, *candidates]`` whose first decoded action has the lowest / highest acceleration in the
    current state. Skills are still decoded closed loop every step and last the skill horizon, as the ego's own.

    Args:
        ego: the ReSkill ego (its policy is copied; the original is not changed).
        offsets: ``[segments, L]`` offsets on ``u``.
        extreme: ``[segments]`` in {-1, 0, +1}.
        segment_steps: env steps per segment.
        candidates: ``[C, L]`` high-level actions in [-1, 1] the extreme segments choose among (with ``u``).
    """

    name = "skill-plan"

    def __init__(self, ego: Any, offsets: np.ndarray, extreme: np.ndarray, segment_steps: int,
                 candidates: np.ndarray) -> None:
        skills = reskill_skills(ego)
        self.policy = copy.copy(ego.policy)  # its own step counter and current skill; weights shared
        self.policy.skills = skills.clone()
        self._probe = skills.clone()  # scores candidate skills without touching the driven one
        self._high = ego.policy.high_action
        self.policy.high_action = self._choose
        self.deadline_obs = bool(getattr(ego, "deadline_obs", False))
        self.offsets = np.asarray(offsets, dtype=np.float32)
        self.extreme = np.asarray(extreme, dtype=np.int8)
        self.segment_steps = max(1, int(segment_steps))
        self.candidates = np.asarray(candidates, dtype=np.float32)
        self._first_step: int | None = None
        self._segment = 0

    def reset(self, scenario: Scenario) -> None:
        self._first_step = None
        self.policy.reset()

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        if self._first_step is None:
            self._first_step = step
        self._segment = min((step - self._first_step) // self.segment_steps, len(self.offsets) - 1)
        return np.asarray(self.policy.act(observation), dtype=np.float64)

    def _choose(self, full_observation: np.ndarray) -> np.ndarray:
        """The high-level action of the current segment (called by the policy at each skill decision)."""
        u = np.clip(np.asarray(self._high(full_observation), dtype=np.float32).reshape(-1), -1.0, 1.0)
        sign = int(self.extreme[self._segment])
        if sign == 0:
            return np.clip(u + self.offsets[self._segment], -1.0, 1.0)
        obs = np.ascontiguousarray(np.asarray(full_observation, dtype=np.float32).reshape(-1)[: self._probe.obs_dim])
        options = np.vstack([u[None], self.candidates])
        accel = np.empty(len(options))
        for i, option in enumerate(options):
            self._probe.skill(noise_of(option, self.policy.noise_bound), obs)
            accel[i] = float(self._probe.action(obs)[1])
        return options[int(np.argmax(sign * accel))]


def plan_offsets(config: AvoidabilityConfig, rng: np.random.Generator) -> list[np.ndarray]:
    """The ``n_plans`` offset profiles ``[segments, 2]`` of the ``actions`` space (`AvoidabilityConfig.n_plans`)."""
    n = config.segments
    plans: list[np.ndarray] = []
    for first in range(n):
        for accel in (-2.0, 2.0):  # full braking / full throttle from segment `first` on, heuristic steering
            offsets = np.zeros((n, 2))
            offsets[first:, 1] = accel
            plans.append(offsets)
    plans = plans[: config.n_plans]
    while len(plans) < config.n_plans:
        offsets = np.zeros((n, 2))
        offsets[:, 1] = rng.uniform(-config.max_accel_offset, config.max_accel_offset, n)
        steer = rng.random(n) < config.steer_share
        offsets[steer, 0] = rng.uniform(-config.max_steer_offset, config.max_steer_offset, int(steer.sum()))
        plans.append(offsets)
    return plans


def skill_plans(config: AvoidabilityConfig, latent_dim: int, rng: np.random.Generator
                ) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray]:
    """The ``n_plans`` plans ``(offsets [segments, L], extreme [segments])`` of the ``skills`` space (the extreme
    ones first, in `plan_label`'s order) and the candidates ``[C, L]`` of the extreme segments
    (`seal.models.skills.reach.box_candidates` with ``skill_candidates`` uniform draws)."""
    n, dim = config.segments, int(latent_dim)
    plans: list[tuple[np.ndarray, np.ndarray]] = []
    for first in range(n):
        for sign in (-1, 1):
            extreme = np.zeros(n, dtype=np.int8)
            extreme[first:] = sign
            plans.append((np.zeros((n, dim), dtype=np.float32), extreme))
    plans = plans[: config.n_plans]
    while len(plans) < config.n_plans:
        offsets = rng.uniform(-config.max_skill_offset, config.max_skill_offset, (n, dim)).astype(np.float32)
        plans.append((offsets, np.zeros(n, dtype=np.int8)))
    candidates = box_candidates(dim, config.skill_candidates, rng)
    return plans, candidates


def plan_label(i: int, config: AvoidabilityConfig) -> str:
    """What the ``i``-th plan does: ``brake@J`` / ``throttle@J`` (from segment J on) or ``random``."""
    if i < min(2 * config.segments, config.n_plans):
        return f"{'brake' if i % 2 == 0 else 'throttle'}@{i // 2}"
    return "random"


def ego_plans(config: AvoidabilityConfig, ego: Any, index: int, segment_steps: int) -> Iterator[tuple[str, Any]]:
    """``(plan_label, plan ego)`` of the ``index``-th scenario's search, built one at a time (the search stops at the
    first plan reaching the goal). ``ego`` is the reference ego (needed by the ``skills`` space)."""
    rng = np.random.default_rng([config.seed, index])
    if config.plan_space == "skills":
        plans, candidates = skill_plans(config, int(reskill_skills(ego).latent_dim), rng)
        for i, (offsets, extreme) in enumerate(plans):
            yield plan_label(i, config), SkillPlanEgo(ego, offsets, extreme, segment_steps, candidates)
        return
    for i, offsets in enumerate(plan_offsets(config, rng)):
        yield plan_label(i, config), PlanEgo(offsets, segment_steps)
