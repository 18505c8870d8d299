"""``steered``: CAT's selection over candidates decoded from the adversary's steered latent.

The trajectory prior's target latent is moved along vectors fitted by ``seal fit probes`` (`seal.models.steering`,
papers 000 / 002) before decoding: one vector and one strength, or a grid of them (default: the lane-change and
acceleration control vectors at the output latent, each at -1, 0, +1 class gaps: 9 decodes, 288 candidates, the
unsteered 32 among them). CAT's selection (`seal.adversaries.cat.select`) then ranks the candidates against the
scenario's last K ego roll-outs and the adversary follows the chosen one. ``steer_random_seed`` replaces every
vector by a random direction of the same norm (the baseline). CAT and SEAL take the same steering as their
``steer`` option; this generator is CAT with steering required.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from seal.adversaries.base import register
from seal.adversaries.candidate_generator import Follow
from seal.adversaries.candidate_sources import (
    DEFAULT_STEER_ALPHA,
    DEFAULT_STEER_VECTOR,
    CandidateSource,
    steered_prior_source,
)
from seal.adversaries.cat.generator import CATGenerator
from seal.adversaries.cat.select import DECAY, N_KEPT_MODES, STRIDE_STEPS


@register("steered")
class SteeredGenerator(CATGenerator):
    """CAT over steered candidates (see the module docstring).

    Args:
        prior: the trajectory prior file (or give ``candidate_source``, already steered).
        steer: the steering file or folder of ``seal fit probes`` (required with ``prior``).
        steer_vector: vector name(s), comma-separated for a grid: ``FEATURE@SITE`` or a bare feature at its best
            probe site.
        steer_alpha: steering strength(s) (a list for a grid): tau / 100 for control vectors, standard deviations
            of the latents for risk vectors.
        steer_random_seed: random directions of the same norms instead of the fitted vectors (the baseline).
        project_road: project the decoded candidates on the road (`seal.models.prior.road_projection`): on by
            default, the decoder's candidates leave the road in curves whether steered or not.
        candidate_source, candidates, follow, stride, decay, n_kept_modes: as `CATGenerator`.
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
        steer_random_seed: int | None = None,
        project_road: bool = True,
    ) -> None:
        if candidate_source is None and steer is None:
            raise ValueError("steered: option 'steer' is required: the folder written by `seal fit probes` "
                             "(--gen-opt steered.steer=DIR, 'steer:' in configs)")
        if steer_random_seed is not None and candidate_source is None:
            if prior is None:
                raise ValueError("steered: option 'steer_random_seed' steers the prior's latents: give a prior file")
            candidate_source = steered_prior_source(prior, steer or "", steer_vector, steer_alpha,
                                                    int(steer_random_seed), bool(project_road))
            super().__init__(candidate_source, None, candidates, follow, stride, decay, n_kept_modes)
            self.prior_file = Path(prior)  # the process still runs prior inference (entry points set threads)
        else:
            super().__init__(candidate_source, prior, candidates, follow, stride, decay, n_kept_modes, steer,
                             steer_vector, steer_alpha, bool(project_road) if prior is not None else None)
        self.steer_vector, self.steer_alpha, self.steer_random_seed = steer_vector, steer_alpha, steer_random_seed
        self.project_road = bool(project_road)
