"""`SkillSwitchBehavior`: the SEAL adversary (thesis 6.3.2; ARCHITECTURE.md, methods table): it follows a given
track (the top-ranked candidate) and, from a switch step on - 10 steps (1 s) before the predicted collision / closest
approach by default, see `switch_step_for` - is driven by a `SkillPolicy` that sees its own observation every
step and so reacts to the ego; optionally a second policy (``then``: the SEAL generator's benign skills after
`ADVERSARIAL_STEPS`) takes over from a later step.

Before the switch the adversary is placed on the track (``follow="replay"``, as CAT replays its candidate) or
tracks it with the bicycle model (``follow="track"``); the env builds no observation for it then
(`AdversaryBehavior.observes`). Its observation route is the followed track, so the navigation checkpoints keep
pointing along the chosen candidate after the switch (the thesis derives the adversary's goals from it).
"""

from __future__ import annotations

import sys
from typing import Protocol

import numpy as np

from seal.core.scenario import CURRENT_STEP, VALID, Scenario
from seal.envs.behaviors import AdversaryBehavior, BehaviorOutput, ReplayBehavior, TrackingBehavior
from seal.envs.kinematics import AgentState
from seal.envs.route import Route

SWITCH_OFFSET_STEPS = 10
"""Default steps between the switch to the skill policy and the predicted collision step (1 s)."""
SKILL_NOISE_SCALE = 0.5
"""Default standard deviation of the noise fed to the adversarial skill prior after the switch (1 = sample the
prior; smaller keeps to its likelier skills). 0.5 since session 26 (issue 16): against the 8 No-Adv egos of the
decisive run (4 TD3, 4 ReSkill; Normal eval, 300 scenarios, K = 5) it lowered the realism distance in 8 of 8
(mean WD 0.151 -> 0.127) with close-call rates within 1.5 points; 0.25 and 0 gained little more (0.120-0.124
against two TD3 egos) and raised the collision speed, so 0.5 is kept as the smallest step that does the work."""
ADVERSARIAL_STEPS: int | None = 10
"""Default steps the SEAL adversary's adversarial skills drive after the switch before its benign skills take over
(None: the adversarial prior to the end of the episode, as the thesis does). 10 since session 43 (issue 16): with the
default switch offset the adversarial skill drives from 1 s before the predicted contact to the contact, then the
adversary drives on as the logged traffic does. Against decisive5's TD3 egos (seeds 1-2 of 7 pipelines, 14 egos) on
the held-out pool (300 Normal eval scenarios, K = 5) it lowered the realism distance in 14 of 14 (mean 0.214 ->
0.202) and the acceleration WD in 14 of 14 (0.590 -> 0.554), close calls and adversary collisions within 0.3 points,
collision speed 7.04 -> 7.00 m/s; against 6 ReSkill egos there realism -0.003 (lower for 5), acc WD lower for 6 of 6,
collision speed 4.59 -> 4.55 m/s, and against the heuristic ego 0.207 -> 0.204. 20 (the skill after the contact
adversarial too) was within 0.01 of None on decisive5's pool (6 egos). README, "The attack ends at the contact"."""
FOLLOW_MODES = ("replay", "track")


class StepPolicy(Protocol):
    """What the behaviour needs from a skill policy (`seal.models.skills.policy.SkillPolicy`)."""

    def reset(self, seed: int | None = None) -> None: ...

    def act(self, observation: np.ndarray) -> np.ndarray: ...


def switch_step_for(predicted_step: int | None, offset_steps: int = SWITCH_OFFSET_STEPS) -> int:
    """Scenario step at which to switch to the skill policy: ``offset_steps`` before ``predicted_step`` (a
    scenario step index), not before `CURRENT_STEP`; without a prediction, at `CURRENT_STEP`."""
    if offset_steps < 0:
        raise ValueError(f"offset_steps must be >= 0, got {offset_steps}")
    if predicted_step is None:
        return CURRENT_STEP
    return max(CURRENT_STEP, int(predicted_step) - int(offset_steps))


class SkillSwitchBehavior(AdversaryBehavior):
    """Follow ``track`` before ``switch_step``, then act with ``policy`` (see the module docstring).

    Args:
        policy: the skill policy (reset at every episode).
        track: ``[T, 8]`` track in the scenario layout indexed by scenario step (e.g.
            `seal.adversaries.candidate_path.candidate_track` of the chosen candidate); None for the logged adversary.
        switch_step: first scenario step whose move the policy decides (``CURRENT_STEP``: from the start).
        follow: ``"replay"`` (placement on the track) or ``"track"`` (bicycle-model tracking) before the switch.
        seed: seed of the policy's noise each episode; None draws it from the env's rng at reset (so
            ``env.reset(seed=...)`` fixes the roll-out).
        then, then_step: a second skill policy that acts from scenario step ``then_step`` on (e.g. the benign prior's
            once the interaction is past); None: ``policy`` to the end.
    """

    needs_observation = True

    def __init__(
        self, policy: StepPolicy, track: np.ndarray | None = None, switch_step: int = CURRENT_STEP,
        follow: str = "replay", seed: int | None = None, then: StepPolicy | None = None,
        then_step: int | None = None,
    ) -> None:
        if follow not in FOLLOW_MODES:
            raise ValueError(f"SkillSwitchBehavior: follow must be one of {FOLLOW_MODES}, got {follow!r}")
        if int(switch_step) < CURRENT_STEP:
            raise ValueError(f"SkillSwitchBehavior: switch_step must be >= {CURRENT_STEP}, got {switch_step}")
        given = None if track is None else np.asarray(track, dtype=np.float64)
        if given is not None and (given.ndim != 2 or given.shape[1] != 8 or given.shape[0] <= CURRENT_STEP + 1):
            raise ValueError(f"SkillSwitchBehavior: track must be [T > {CURRENT_STEP + 1}, 8], got {given.shape}")
        if (then is None) != (then_step is None) or (then_step is not None and int(then_step) < int(switch_step)):
            raise ValueError("SkillSwitchBehavior: give both then and then_step (>= switch_step), or neither")
        self.policy = policy
        self.then = then
        self.then_step = None if then_step is None else int(then_step)
        # What `step` reads: the policy of the steps from `_then_from` on (``policy`` itself without a second one).
        self._then: StepPolicy = then if then is not None else policy
        self._then_from = self.then_step if self.then_step is not None else sys.maxsize
        self.switch_step = int(switch_step)
        self.follow = follow
        self.seed = seed
        self._given = given
        self._follower: AdversaryBehavior | None = None
        """Drives the adversary before the switch (a `ReplayBehavior` or `TrackingBehavior` of the track)."""
        self._routes: dict[int, tuple[Scenario | None, Route]] = {}
        self.episode_seed: int | None = None
        """Seed the policy got at the last reset."""

    def reset(self, scenario: Scenario, rng: np.random.Generator) -> None:
        if self.follow == "track":
            track = self._given if self._given is not None else scenario.track(scenario.adv_id).astype(np.float64)
            valid = np.flatnonzero(track[:, VALID] > 0.5)
            self._follower = TrackingBehavior(track[: valid[-1] + 1], start_step=0)
        else:
            self._follower = ReplayBehavior(self._given)
        self._follower.reset(scenario, rng)
        self.episode_seed = int(rng.integers(2**63)) if self.seed is None else int(self.seed)
        self.policy.reset(self.episode_seed)
        if self.then is not None:
            self.then.reset((self.episode_seed + 1) % 2**63)

    def make_route(self, scenario: Scenario) -> Route:
        # Cached (a route is immutable): building one walks the track in Python, every episode otherwise. Keyed
        # by the scenario object, whose logged adversary track it is (a given track serves every scenario); the
        # entry keeps the object, so its id is not reused while cached.
        owner = None if self._given is not None else scenario
        hit = self._routes.get(id(owner))
        if hit is None or hit[0] is not owner:
            track = self._given if self._given is not None else scenario.track(scenario.adv_id)
            if len(self._routes) > 1024:
                self._routes.clear()
            hit = (owner, Route.from_track(track))
            self._routes[id(owner)] = hit
        return hit[1]

    def observes(self, t: int) -> bool:
        return t >= self.switch_step

    def step(self, t: int, state: AgentState | None, observation: np.ndarray | None) -> BehaviorOutput:
        if state is None:
            return BehaviorOutput.absent()
        if t >= self.switch_step:
            if observation is None:
                raise RuntimeError("SkillSwitchBehavior: the env passed no observation after the switch")
            policy = self._then if t >= self._then_from else self.policy
            steering, acceleration = policy.act(observation).tolist()
            return BehaviorOutput.act(steering, acceleration)
        assert self._follower is not None, "reset() first"
        return self._follower.step(t, state, observation)
