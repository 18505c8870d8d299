"""``cat``: CAT's generator (DESIGN section 7): candidates from a source (the trajectory prior pi_gen), CAT's
selection against the scenario's last K ego roll-outs (`seal.adversaries.cat.select`), and the chosen future replayed
kinematically by the adversary.

``follow="replay"`` (default) places the adversary on the chosen path every step (`ReplayBehavior` of the track
built by `candidate_track`), as CAT does; ``follow="track"`` makes it follow the path with the bicycle model
(`TrackingBehavior`: pure pursuit + speed schedule), for candidates too jerky to replay.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from seal.adversaries.base import AdversaryGenerator, Generation, register
from seal.adversaries.candidate_path import candidate_track
from seal.adversaries.candidate_sources import (
    PRIOR_THREADS,
    CandidateSource,
    adversary_candidates,
    make_candidate_source,
)
from seal.adversaries.cat.select import DECAY, N_KEPT_MODES, STRIDE_STEPS, cat_select
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, VALID, WIDTH, Scenario, X, Y
from seal.envs.behaviors import AdversaryBehavior, ReplayBehavior, TrackingBehavior
from seal.envs.rollout import Rollout

FOLLOW_MODES = ("replay", "track")


def stack_ego_rollouts(history: Sequence[Rollout]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ego ``xy [K, T, 2]``, ``heading [K, T]``, ``valid [K, T]`` of roll-outs of possibly different lengths
    (shorter ones padded as invalid); row ``t`` is scenario step ``t``."""
    n_steps = max(r.tracks.shape[1] for r in history)
    out = np.zeros((len(history), n_steps, 8), dtype=np.float64)
    for i, r in enumerate(history):
        ego = r.ego_track
        out[i, : ego.shape[0]] = ego
    return out[..., [X, Y]], out[..., HEADING], out[..., VALID] > 0.5


@register("cat")
class CATGenerator(AdversaryGenerator):
    """CAT (see the module docstring).

    Args:
        candidate_source: ``scenario -> Candidates`` of the adversary; or give ``prior`` (a trajectory prior
            file) or ``candidates`` (a built-in source name, e.g. ``"lanes"``), exactly one of the three.
        follow: ``"replay"`` or ``"track"``.
        stride: sub-sampling (steps), 5 = 0.5 s.
        decay: uncertainty factor per sample.
        n_kept_modes: modes below this rank share its score in P1.
        prior_threads: torch threads for the prior (process-wide; None leaves torch's setting), see
            `seal.adversaries.candidate_sources.prior_source`.
    """

    def __init__(
        self,
        candidate_source: CandidateSource | None = None,
        prior: str | Path | None = None,
        candidates: str | None = None,
        follow: str = "replay",
        stride: int = STRIDE_STEPS,
        decay: float = DECAY,
        n_kept_modes: int = N_KEPT_MODES,
        prior_threads: int | None = PRIOR_THREADS,
    ) -> None:
        if follow not in FOLLOW_MODES:
            raise ValueError(f"cat: follow must be one of {FOLLOW_MODES}, got {follow!r}")
        self.candidate_source = make_candidate_source(candidate_source, prior, candidates, prior_threads)
        self.follow = follow
        self.stride = int(stride)
        self.decay = float(decay)
        self.n_kept_modes = int(n_kept_modes)

    def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        if not history:
            raise ValueError(f"cat: empty roll-out history for scenario {scenario.scenario_id!r}")
        start = time.perf_counter()
        cands = adversary_candidates(self.candidate_source, scenario, "cat")
        candidate_s = time.perf_counter() - start
        adv = scenario.adv_index
        ego_xy, ego_heading, ego_valid = stack_ego_rollouts(history)
        now = scenario.tracks[:, CURRENT_STEP]
        sel = cat_select(
            cands.xy, cands.heading, cands.probs,
            adv_size_m=(float(now[adv, LENGTH]), float(now[adv, WIDTH])),
            ego_xy=ego_xy, ego_heading=ego_heading, ego_valid=ego_valid,
            ego_size_m=(float(now[scenario.ego_index, LENGTH]), float(now[scenario.ego_index, WIDTH])),
            stride=self.stride, decay=self.decay, n_kept=self.n_kept_modes,
        )
        chosen = cands.xy[sel.index]
        behavior: AdversaryBehavior
        if self.follow == "replay":
            behavior = ReplayBehavior(candidate_track(scenario, adv, chosen))
        else:
            behavior = TrackingBehavior(chosen, start_step=CURRENT_STEP + 1)
        return Generation(
            behavior=behavior,
            chosen_candidate=sel.index,
            predicted_step=sel.predicted_step,
            extra={
                "collision_predicted": sel.collided,
                "score": float(sel.scores[sel.index]),
                "prior_prob": float(cands.probs[sel.index]),
                "min_distance_m": float(sel.min_distance_m[sel.index]),
                "n_candidates": cands.n_candidates,
                "candidate_fallback": getattr(cands, "fallback", None) or "",
                "candidate_time_s": candidate_s,
                "select_time_s": time.perf_counter() - start - candidate_s,
            },
        )
