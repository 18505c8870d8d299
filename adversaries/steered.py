"""``steered``: CAT's selection over candidates decoded from the adversary's latent steered toward risk.

The trajectory prior's target latent is moved by ``steer_alpha`` along a vector fitted by ``seal fit probes``
(`seal.models.steering`, papers 000 / 002; default: the proximity-risk vector at its best probe site, alpha 1.5)
before decoding; CAT's selection (`seal.adversaries.cat.select`) then ranks the steered candidates against the
scenario's last K ego roll-outs, and the adversary follows the chosen one. The same steering is available to CAT
and SEAL as their ``steer`` option; this generator is CAT with steering required.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from seal.adversaries.base import register
from seal.adversaries.candidate_generator import Follow
from seal.adversaries.candidate_sources import DEFAULT_STEER_ALPHA, DEFAULT_STEER_VECTOR, CandidateSource
from seal.adversaries.cat.generator import CATGenerator
from seal.adversaries.cat.select import DECAY, N_KEPT_MODES, STRIDE_STEPS


@register("steered")
class SteeredGenerator(CATGenerator):
    """CAT over steered candidates (see the module docstring).

    Args:
        prior: the trajectory prior file (or give ``candidate_source``, already steered).
        steer: the steering file or folder of ``seal fit probes`` (required with ``prior``).
        steer_vector: vector name: ``FEATURE@SITE`` or a bare feature at its best probe site.
        steer_alpha: steering strength (standard deviations of the latents for risk vectors).
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
    ) -> None:
        if candidate_source is None and steer is None:
            raise ValueError("steered: option 'steer' is required: the folder written by `seal fit probes` "
                             "(--gen-opt steered.steer=DIR, 'steer:' in configs)")
        super().__init__(candidate_source, prior, candidates, follow, stride, decay, n_kept_modes, steer,
                         steer_vector, steer_alpha)
        self.steer_vector, self.steer_alpha = steer_vector, steer_alpha
