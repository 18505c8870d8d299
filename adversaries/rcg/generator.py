"""``cat-rcg`` and ``seal-rcg``: RCG's crash-grounded selection (`seal.adversaries.rcg.select`) in place of the base
generators' scoring (thesis 7.5.3).

* ``cat-rcg``: candidates from the prior, RCG selection with ``n_knn = 15``, the adversary follows the chosen
  candidate open loop (as CAT; ``follow`` as in `seal.adversaries.candidate_generator`).
* ``seal-rcg``: SEAL's generator (`seal.adversaries.seal.generator`) with RCG as its objective (``n_knn = 8``): the
  adversary follows the chosen candidate and hands over to the adversarial skill policy before the predicted
  contact, so it reacts to the ego.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from seal.adversaries.base import Generation, register
from seal.adversaries.candidate_generator import CandidateContext, CandidateGenerator, Follow
from seal.adversaries.candidate_sources import CandidateSource
from seal.adversaries.rcg.select import (
    DEFAULT_PRIOR_WEIGHT,
    N_INT,
    N_KNN_CAT,
    N_KNN_SEAL,
    Distance,
    RCGObjective,
    selection_extra,
)
from seal.adversaries.seal.contact import predict_contact
from seal.adversaries.seal.generator import SEALGenerator, Switch
from seal.adversaries.seal.objective import Ranking
from seal.envs.skill_behavior import ADVERSARIAL_STEPS, SKILL_NOISE_SCALE, SWITCH_OFFSET_STEPS


def _objective(behavior: Any, n_knn: int, n_int: int, distance: str, prior_weight: float, generator: str
               ) -> RCGObjective:
    if behavior is None:
        raise ValueError(f"{generator}: option 'behavior' is required: a behaviour model file (seal fit behavior)")
    if isinstance(behavior, RCGObjective):
        return behavior
    return RCGObjective(behavior, n_knn, n_int, distance, float(prior_weight))


@register("cat-rcg")
class CATRCGGenerator(CandidateGenerator):
    """CAT-RCG (see the module docstring).

    Args:
        candidate_source, prior, candidates: the candidate source, exactly one (as `CandidateGenerator`).
        behavior: a behaviour model file (``seal fit behavior``) or a ready `RCGObjective`.
        n_knn: neighbours of KNN_dist (thesis 15 for CAT).
        n_int: candidates kept by collision closeness (thesis 6).
        distance: ``"knn"`` or ``"prototype"`` (the Table 7.4 ablation).
        prior_weight: weight of the candidates' ``-log`` prior probability added to eq. 7.7's distance (0 = the
            thesis's rule; `seal.adversaries.rcg.select`).
        follow: ``"replay"`` or ``"track"``.
    """

    def __init__(
        self,
        candidate_source: CandidateSource | None = None,
        prior: str | Path | None = None,
        candidates: str | None = None,
        behavior: str | Path | RCGObjective | None = None,
        n_knn: int = N_KNN_CAT,
        n_int: int = N_INT,
        distance: str = Distance.KNN,
        prior_weight: float = DEFAULT_PRIOR_WEIGHT,
        follow: str = Follow.REPLAY,
    ) -> None:
        self.rcg = _objective(behavior, n_knn, n_int, distance, prior_weight, "cat-rcg")
        super().__init__(candidate_source, prior, candidates, follow)

    def _choose(self, context: CandidateContext, rng: np.random.Generator) -> Generation:
        cands = context.cands
        sel = self.rcg.select(context.scenario, cands, context.ego_xy, context.ego_heading, context.ego_valid)
        contact = predict_contact(cands.xy[sel.index], cands.heading[sel.index], context.adv_size_m,
                                  context.ego_xy, context.ego_heading, context.ego_valid, context.ego_size_m)
        return Generation(
            behavior=self.follow_behavior(context.scenario, cands.xy[sel.index]),
            chosen_candidate=sel.index,
            predicted_step=contact.step,
            extra={
                "collision_predicted": contact.collided,
                "prior_prob": float(cands.probs[sel.index]),
                "min_distance_m": contact.min_distance_m,
                "distance": str(self.rcg.distance),
                **selection_extra(sel),
                **context.candidate_extra(),
                "select_time_s": context.since_candidates_s(),
            },
        )


@register("seal-rcg")
class SEALRCGGenerator(SEALGenerator):
    """SEAL-RCG (see the module docstring); options as `SEALGenerator` without ``objective``, plus ``behavior``,
    ``n_knn`` (thesis 8 for SEAL), ``n_int``, ``distance`` and ``prior_weight`` as `CATRCGGenerator`."""

    def __init__(
        self,
        candidate_source: CandidateSource | None = None,
        prior: str | Path | None = None,
        candidates: str | None = None,
        behavior: str | Path | RCGObjective | None = None,
        n_knn: int = N_KNN_SEAL,
        n_int: int = N_INT,
        distance: str = Distance.KNN,
        prior_weight: float = DEFAULT_PRIOR_WEIGHT,
        skills: str | Path | None = None,
        switch: str = Switch.ADVERSARIAL,
        switch_offset_steps: int = SWITCH_OFFSET_STEPS,
        follow: str = Follow.REPLAY,
        noise_scale: float = SKILL_NOISE_SCALE,
        policy: Any = None,
        adversarial_steps: int | None = ADVERSARIAL_STEPS,
        benign_policy: Any = None,
    ) -> None:
        rcg = _objective(behavior, n_knn, n_int, distance, prior_weight, "seal-rcg")
        super().__init__(candidate_source, prior, candidates, objective=rcg, skills=skills, switch=switch,
                         switch_offset_steps=switch_offset_steps, follow=follow, noise_scale=noise_scale,
                         policy=policy, adversarial_steps=adversarial_steps, benign_policy=benign_policy)
        self.rcg = rcg

    def _rank(self, context: CandidateContext) -> Ranking:
        return self.rcg(context.cands, context.adv_size_m, context.ego_xy, context.ego_heading, context.ego_valid,
                        context.ego_size_m, scenario=context.scenario)
