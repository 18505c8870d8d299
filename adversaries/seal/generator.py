"""``seal``: SEAL's generator (thesis 6.3; `ARCHITECTURE.md`, generators).

1. Candidates from a source (the trajectory prior pi_gen, as CAT; `seal.adversaries.candidate_generator`).
2. Ranking against the scenario's last K ego roll-outs by the objective (`seal.adversaries.seal.objective`): the learned
   pi_score (a model file) plus ``prior_weight`` x the candidate's log prior probability (a plausibility term,
   ``prior_weight=0`` is the thesis's score alone), or CAT's heuristic (``objective="cat"``, the ablation).
3. The adversary follows the top candidate (placed on it, ``follow="replay"``, or tracking it with the bicycle
   model, ``follow="track"``) and, ``switch_offset_steps`` (10 = 1 s) before the candidate's predicted collision /
   closest-approach step (`seal.adversaries.seal.contact.predict_contact`), hands over to the skill policy
   (`seal.envs.skill_behavior.SkillSwitchBehavior`): every 10 steps noise through the adversarial prior given its own
   observation, actions decoded closed-loop each step, so it reacts to the ego; ``adversarial_steps`` after the
   switch (10: at the predicted contact) the benign prior's skills take over (None: adversarial to the end, the
   thesis; README "The attack ends at the contact").

Ablations (thesis Fig. 6.5): ``switch="benign"`` samples skills from the benign prior, ``switch="none"`` follows
the candidate to the end (trajectory only, no skills); ``objective="cat"`` replaces the learned objective.

The skill policy's noise seed is drawn from the generator's rng, so a generation fixes its roll-out (for a
deterministic ego) whatever the env's seed.
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from seal.adversaries.base import Generation, register
from seal.adversaries.candidate_generator import CandidateContext, CandidateGenerator, Follow, check_follow
from seal.adversaries.candidate_path import candidate_track
from seal.adversaries.candidate_sources import DEFAULT_STEER_ALPHA, DEFAULT_STEER_VECTOR, CandidateSource
from seal.adversaries.cat.select import DECAY, N_KEPT_MODES, STRIDE_STEPS
from seal.adversaries.seal.contact import predict_contact
from seal.adversaries.seal.objective import (
    DEFAULT_HEADS,
    DEFAULT_PRIOR_WEIGHT,
    Objective,
    Ranking,
    make_objective,
)
from seal.envs.behaviors import AdversaryBehavior
from seal.envs.skill_behavior import (
    ADVERSARIAL_STEPS,
    SKILL_NOISE_SCALE,
    SWITCH_OFFSET_STEPS,
    SkillSwitchBehavior,
    switch_step_for,
)


class Switch(StrEnum):
    """Skill prior after the switch; ``none``: no switch, the adversary follows the chosen candidate to the end."""

    ADVERSARIAL = "adversarial"
    BENIGN = "benign"
    NONE = "none"


SWITCH_MODES = tuple(m.value for m in Switch)


def load_skill_policy(skills: str | Path | None, switch: str, noise_scale: float = 1.0,
                      horizon: int | None = None) -> Any:
    """The `seal.models.skills.policy.SkillPolicy` of folder ``skills`` with prior ``switch`` (a new skill every
    ``horizon`` steps, default the VAE's window; noise std ``noise_scale``); None for ``switch="none"``."""
    if switch not in SWITCH_MODES:
        raise ValueError(f"seal: switch must be one of {', '.join(SWITCH_MODES)}, got {switch!r}")
    if switch == Switch.NONE:
        return None
    if skills is None:
        raise ValueError(f"seal: switch={switch!r} needs option 'skills': a folder written by `seal fit skills` "
                         "(or switch=none for trajectory following only)")
    if not Path(skills).is_dir():
        raise ValueError(f"seal: skills folder {skills} does not exist (train one with `seal fit skills`)")
    from seal.models.skills.policy import SkillPolicy

    return SkillPolicy.load(skills, prior=switch, noise_scale=noise_scale, horizon=horizon)


def _own_copy(policy: Any) -> Any:
    """A behaviour's own copy of a ready skill policy (`SkillPolicy.clone`: its episode state, shared weights)."""
    return policy.clone() if hasattr(policy, "clone") else policy


@register("seal")
class SEALGenerator(CandidateGenerator):
    """SEAL (see the module docstring).

    Args:
        candidate_source: ``scenario -> Candidates``; or give ``prior`` (a trajectory prior file) or ``candidates``
            (a built-in source name, e.g. ``"lanes"``), exactly one of the three.
        objective: a learned objective model file, ``"cat"`` (CAT's heuristic selection), or an
            `seal.adversaries.seal.objective.Objective`.
        prior_weight: weight of the candidates' log prior probability added to the learned score (>= 0; 0 = the
            thesis's score alone); not used by ``objective="cat"``, which weighs its candidates by the prior itself.
        objective_heads: the learned objective's predicted terms summed for the ranking: ``"coll+diff"`` (the
            thesis), ``"coll"`` or ``"diff"`` alone (ablations; `seal.adversaries.seal.objective.LearnedObjective`).
        skills: skill model folder (``seal fit skills``); not needed with ``switch="none"``.
        switch: ``"adversarial"`` (SEAL), ``"benign"`` or ``"none"`` (trajectory only).
        switch_offset_steps: steps between the switch and the predicted collision / closest approach (10 = 1 s).
        follow: ``"replay"`` or ``"track"``: how the candidate is followed before the switch.
        noise_scale: standard deviation of the skill noise (1 = sample the prior; < 1 keeps to its likelier skills;
            default `seal.envs.skill_behavior.SKILL_NOISE_SCALE`).
        skill_horizon: steps per skill (a new skill is drawn every ``skill_horizon`` steps; None: the VAE's window,
            10 = 1 s).
        adversarial_steps: steps the adversarial prior's skills drive after the switch, then the benign prior's (the
            attack is the interaction; after it the adversary drives on as traffic does); None: the adversarial prior
            to the end (the thesis). ``switch="adversarial"`` only; default
            `seal.envs.skill_behavior.ADVERSARIAL_STEPS`.
        policy: a ready skill policy (``reset(seed)`` / ``act(obs)``) instead of loading ``skills``.
        benign_policy: with ``policy``, the ready policy that drives after ``adversarial_steps`` (without it a ready
            ``policy`` drives to the end).
        stride, decay, n_kept_modes: CAT's selection options (``objective="cat"`` only).
        steer, steer_vector, steer_alpha, project_road: latent steering of the prior's candidates and their
            projection on the road (`CandidateGenerator`).
    """

    def __init__(
        self,
        candidate_source: CandidateSource | None = None,
        prior: str | Path | None = None,
        candidates: str | None = None,
        objective: str | Path | Objective | None = None,
        prior_weight: float = DEFAULT_PRIOR_WEIGHT,
        skills: str | Path | None = None,
        switch: str = Switch.ADVERSARIAL,
        switch_offset_steps: int = SWITCH_OFFSET_STEPS,
        follow: str = Follow.REPLAY,
        noise_scale: float = SKILL_NOISE_SCALE,
        skill_horizon: int | None = None,
        policy: Any = None,
        stride: int = STRIDE_STEPS,
        decay: float = DECAY,
        n_kept_modes: int = N_KEPT_MODES,
        steer: str | Path | None = None,
        steer_vector: str = DEFAULT_STEER_VECTOR,
        steer_alpha: float | Sequence[float] | str = DEFAULT_STEER_ALPHA,
        project_road: bool | None = None,
        objective_heads: str = DEFAULT_HEADS,
        adversarial_steps: int | None = ADVERSARIAL_STEPS,
        benign_policy: Any = None,
    ) -> None:
        check_follow(self.name, follow)
        if switch not in SWITCH_MODES:
            raise ValueError(f"seal: switch must be one of {', '.join(SWITCH_MODES)}, got {switch!r}")
        if int(switch_offset_steps) < 0:
            raise ValueError(f"seal: switch_offset_steps must be >= 0, got {switch_offset_steps}")
        if float(noise_scale) < 0:
            raise ValueError(f"seal: noise_scale must be >= 0, got {noise_scale}")
        if skill_horizon is not None and int(skill_horizon) < 1:
            raise ValueError(f"seal: skill_horizon must be >= 1, got {skill_horizon}")
        self.objective = make_objective(objective, prior_weight=float(prior_weight), heads=objective_heads,
                                        stride=stride, decay=decay, n_kept=n_kept_modes)
        self.switch = Switch(switch)
        self.switch_offset_steps = int(switch_offset_steps)
        horizon = None if skill_horizon is None else int(skill_horizon)
        self.policy = policy if policy is not None or switch == Switch.NONE else load_skill_policy(
            skills, switch, noise_scale, horizon)
        if adversarial_steps is not None and int(adversarial_steps) < 0:
            raise ValueError(f"seal: adversarial_steps must be >= 0 (or null: to the end), got {adversarial_steps}")
        # The hand-over to the benign prior: with switch=adversarial only; a ready `policy` needs its `benign_policy`.
        hand_over = adversarial_steps is not None and self.switch == Switch.ADVERSARIAL and (
            policy is None or benign_policy is not None)
        self.adversarial_steps = int(adversarial_steps) if hand_over and adversarial_steps is not None else None
        self.benign_policy = None if not hand_over else benign_policy if benign_policy is not None else (
            load_skill_policy(skills, Switch.BENIGN, noise_scale, horizon))
        super().__init__(candidate_source, prior, candidates, follow, steer, steer_vector, steer_alpha,
                         project_road)

    def _rank(self, context: CandidateContext) -> Ranking:
        """The objective's ranking of the candidates against the past ego roll-outs (a subclass whose objective
        also needs the scenario, e.g. ``seal-rcg``, overrides this)."""
        return self.objective(context.cands, context.adv_size_m, context.ego_xy, context.ego_heading,
                              context.ego_valid, context.ego_size_m, prev_adv=(context.adv_xy, context.adv_valid))

    def _choose(self, context: CandidateContext, rng: np.random.Generator) -> Generation:
        cands, scenario = context.cands, context.scenario
        ego_rollouts = (context.ego_xy, context.ego_heading, context.ego_valid)
        ranking = self._rank(context)
        rank_s = context.since_candidates_s()
        chosen = ranking.index
        contact = predict_contact(cands.xy[chosen], cands.heading[chosen], context.adv_size_m, *ego_rollouts,
                                  context.ego_size_m)
        switch_step = switch_step_for(contact.step, self.switch_offset_steps)
        behavior: AdversaryBehavior
        skill_seed = then_step = None
        if self.switch == Switch.NONE:
            behavior = self.follow_behavior(scenario, cands.xy[chosen])
        else:
            skill_seed = int(rng.integers(2**63))
            track = candidate_track(scenario, scenario.adv_index, cands.xy[chosen])
            then = None if self.benign_policy is None else _own_copy(self.benign_policy)
            then_step = None if then is None else switch_step + int(self.adversarial_steps or 0)
            behavior = SkillSwitchBehavior(_own_copy(self.policy), track=track, switch_step=switch_step,
                                           follow=self.follow, seed=skill_seed, then=then, then_step=then_step)
        return Generation(
            behavior=behavior,
            chosen_candidate=chosen,
            predicted_step=contact.step,
            extra={
                "objective": self.objective.name,
                "switch": str(self.switch),
                "switch_step": None if self.switch == Switch.NONE else switch_step,
                "benign_step": then_step,
                "skill_seed": skill_seed,
                "collision_predicted": contact.collided,
                "score": float(ranking.scores[chosen]),
                "scores": [round(float(s), 6) for s in ranking.scores],
                "prior_prob": float(cands.probs[chosen]),
                "min_distance_m": contact.min_distance_m,
                **context.candidate_extra(),
                "rank_time_s": rank_s,
                "select_time_s": context.since_candidates_s(),
                **ranking.extra,
            },
        )
