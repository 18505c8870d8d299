"""``cat``: CAT's generator (`ARCHITECTURE.md`, generators): candidates from a source (the trajectory prior
pi_gen), CAT's selection against the scenario's last K ego roll-outs (`seal.adversaries.cat.select`), and the chosen
future followed by the adversary (``follow``, see `seal.adversaries.candidate_generator`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from seal.adversaries.base import Generation, register
from seal.adversaries.candidate_generator import CandidateContext, CandidateGenerator, Follow
from seal.adversaries.candidate_sources import DEFAULT_STEER_ALPHA, DEFAULT_STEER_VECTOR, CandidateSource
from seal.adversaries.cat.select import DECAY, N_KEPT_MODES, STRIDE_STEPS, cat_select


@register("cat")
class CATGenerator(CandidateGenerator):
    """CAT (see the module docstring).

    Args:
        candidate_source: ``scenario -> Candidates`` of the adversary; or give ``prior`` (a trajectory prior
            file) or ``candidates`` (a built-in source name, e.g. ``"lanes"``), exactly one of the three.
        follow: ``"replay"`` or ``"track"``.
        stride: sub-sampling (steps), 5 = 0.5 s.
        decay: uncertainty factor per sample.
        n_kept_modes: modes below this rank share its score in P1.
        steer, steer_vector, steer_alpha, project_road: latent steering of the prior's candidates and their
            projection on the road (`CandidateGenerator`).
    """

    def __init__(
        self,
        candidate_source: CandidateSource | None = None,
        prior: str | Path | None = None,
        candidates: str | None = None,
        follow: str = Follow.REPLAY,
        stride: int = STRIDE_STEPS,
        decay: float = DECAY,
        n_kept_modes: int = N_KEPT_MODES,
        steer: str | Path | None = None,
        steer_vector: str = DEFAULT_STEER_VECTOR,
        steer_alpha: float | Sequence[float] | str = DEFAULT_STEER_ALPHA,
        project_road: bool | None = None,
    ) -> None:
        super().__init__(candidate_source, prior, candidates, follow, steer, steer_vector, steer_alpha,
                         project_road)
        self.stride = int(stride)
        self.decay = float(decay)
        self.n_kept_modes = int(n_kept_modes)

    def _choose(self, context: CandidateContext, rng: np.random.Generator) -> Generation:
        cands = context.cands
        sel = cat_select(
            cands.xy, cands.heading, cands.probs, adv_size_m=context.adv_size_m,
            ego_xy=context.ego_xy, ego_heading=context.ego_heading, ego_valid=context.ego_valid,
            ego_size_m=context.ego_size_m, stride=self.stride, decay=self.decay, n_kept=self.n_kept_modes,
        )
        return Generation(
            behavior=self.follow_behavior(context.scenario, cands.xy[sel.index]),
            chosen_candidate=sel.index,
            predicted_step=sel.predicted_step,
            extra={
                "collision_predicted": sel.collided,
                "score": float(sel.scores[sel.index]),
                "prior_prob": float(cands.probs[sel.index]),
                "min_distance_m": float(sel.min_distance_m[sel.index]),
                **context.candidate_extra(),
                "select_time_s": context.since_candidates_s(),
            },
        )
