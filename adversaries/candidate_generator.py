"""`CandidateGenerator`: what every candidate-based generator (CAT, SEAL, later ones) shares.

A candidate-based generator takes the adversary's candidate futures from a source
(`seal.adversaries.candidate_sources`), stacks the scenario's past ego roll-outs into arrays, ranks the candidates
against them and lets the adversary follow the chosen one. The shared part lives here:

* the candidate source (a callable, a trajectory prior file or a built-in name, exactly one);
* timing: ``candidate_time_s`` (getting the candidates) and ``select_time_s`` (everything after) in
  `seal.adversaries.base.Generation.extra`;
* ego roll-out stacking (`stack_ego_rollouts`) and the agents' box sizes (`CandidateContext`);
* the follow behaviour: ``follow="replay"`` places the adversary on the chosen path every step (`ReplayBehavior`
  of the track built by `seal.adversaries.candidate_path.candidate_track`), ``follow="track"`` makes it follow the
  path with the bicycle model (`TrackingBehavior`: pure pursuit + speed schedule), for candidates too jerky to
  replay.

Subclasses only rank and choose: they implement `CandidateGenerator._choose`.
"""

from __future__ import annotations

import time
from abc import abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

import numpy as np

from seal.adversaries.base import AdversaryGenerator, Generation
from seal.adversaries.candidate_path import candidate_track
from seal.adversaries.candidate_sources import (
    DEFAULT_STEER_ALPHA,
    DEFAULT_STEER_VECTOR,
    CandidateSource,
    adversary_candidates,
    make_candidate_source,
)
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, VALID, WIDTH, Scenario, X, Y
from seal.envs.behaviors import AdversaryBehavior, ReplayBehavior, TrackingBehavior
from seal.envs.rollout import Rollout
from seal.models.prior.candidates import Candidates


class Follow(StrEnum):
    """How the adversary follows the chosen candidate (see the module docstring)."""

    REPLAY = "replay"
    TRACK = "track"


FOLLOW_MODES = tuple(m.value for m in Follow)


def check_follow(generator: str, follow: str) -> Follow:
    """``follow`` as a `Follow`; a clear error (naming ``generator``) for anything else."""
    if follow not in FOLLOW_MODES:
        raise ValueError(f"{generator}: follow must be one of {', '.join(FOLLOW_MODES)}, got {follow!r}")
    return Follow(follow)


def stack_ego_rollouts(history: Sequence[Rollout]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ego ``xy [K, T, 2]``, ``heading [K, T]``, ``valid [K, T]`` of roll-outs of possibly different lengths
    (shorter ones padded as invalid); row ``t`` is scenario step ``t``."""
    return _stack([r.ego_track for r in history])


def stack_adv_rollouts(history: Sequence[Rollout]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same as `stack_ego_rollouts` of each roll-out's adversary (what it drove in that episode)."""
    return _stack([r.adv_track for r in history])


def _stack(tracks: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n_steps = max(t.shape[0] for t in tracks)
    out = np.zeros((len(tracks), n_steps, 8), dtype=np.float64)
    for i, track in enumerate(tracks):
        out[i, : track.shape[0]] = track
    return out[..., [X, Y]], out[..., HEADING], out[..., VALID] > 0.5


@dataclass(frozen=True)
class CandidateContext:
    """What a candidate-based generator ranks with, for one generation.

    Attributes:
        scenario: the base scenario.
        cands: the adversary's candidates (``xy [C, F, 2]``, ...).
        adv_size_m: adversary (length, width) in metres at `CURRENT_STEP`.
        ego_size_m: ego (length, width) in metres at `CURRENT_STEP`.
        ego_xy: ``[K, T, 2]`` past ego roll-outs (`stack_ego_rollouts`).
        ego_heading: ``[K, T]`` (rad).
        ego_valid: ``[K, T]`` bool.
        adv_xy: ``[K, T, 2]`` the adversary of each past roll-out (`stack_adv_rollouts`).
        adv_valid: ``[K, T]`` bool.
        start: `time.perf_counter` when the generation began (s).
        candidate_time_s: seconds spent getting the candidates.
    """

    scenario: Scenario
    cands: Candidates
    adv_size_m: tuple[float, float]
    ego_size_m: tuple[float, float]
    ego_xy: np.ndarray
    ego_heading: np.ndarray
    ego_valid: np.ndarray
    adv_xy: np.ndarray
    adv_valid: np.ndarray
    start: float
    candidate_time_s: float

    def since_candidates_s(self) -> float:
        """Seconds since the candidates were ready (the ranking / selection time so far)."""
        return time.perf_counter() - self.start - self.candidate_time_s

    def candidate_extra(self) -> dict[str, Any]:
        """The candidate-source entries of `Generation.extra`: count, fallback and ``candidate_time_s``."""
        return {
            "n_candidates": self.cands.n_candidates,
            "candidate_fallback": getattr(self.cands, "fallback", None) or "",
            "candidate_time_s": self.candidate_time_s,
        }


def uses_prior_file(generators: Iterable[AdversaryGenerator]) -> bool:
    """Whether any of ``generators`` reads its candidates from a trajectory prior file: entry points then set torch
    to `seal.adversaries.candidate_sources.PRIOR_THREADS` threads (what loading a prior used to do)."""
    return any(isinstance(g, CandidateGenerator) and g.prior_file is not None for g in generators)


def _size_m(scenario: Scenario, agent: int) -> tuple[float, float]:
    now = scenario.tracks[agent, CURRENT_STEP]
    return float(now[LENGTH]), float(now[WIDTH])


class CandidateGenerator(AdversaryGenerator):
    """Base of candidate-based generators (see the module docstring).

    Args:
        candidate_source: ``scenario -> Candidates`` of the adversary; or give ``prior`` (a trajectory prior
            file) or ``candidates`` (a built-in source name, e.g. ``"lanes"``), exactly one of the three.
        prior: a trajectory prior file (`seal.adversaries.candidate_sources.prior_source`).
        candidates: a built-in candidate source name.
        follow: ``"replay"`` or ``"track"``.
        steer: a steering file / folder (``seal fit probes``): the prior's candidates are decoded with the
            adversary's latent moved by ``steer_alpha`` along ``steer_vector`` (needs ``prior``).
        steer_vector: vector name (``FEATURE@SITE``, or a bare feature at its best probe site).
        steer_alpha: steering strength.
        project_road: project the prior's candidates on the road (`seal.models.prior.road_projection`); None: off
            for the plain prior, on for a steered one (`seal.adversaries.candidate_sources.make_candidate_source`).
    """

    def __init__(
        self,
        candidate_source: CandidateSource | None = None,
        prior: str | Path | None = None,
        candidates: str | None = None,
        follow: str = Follow.REPLAY,
        steer: str | Path | None = None,
        steer_vector: str = DEFAULT_STEER_VECTOR,
        steer_alpha: float | Sequence[float] | str = DEFAULT_STEER_ALPHA,
        project_road: bool | None = None,
    ) -> None:
        self.follow = check_follow(self.name, follow)
        self.candidate_source = make_candidate_source(candidate_source, prior, candidates, steer, steer_vector,
                                                      steer_alpha, project_road)
        self.prior_file = None if prior is None else Path(prior)
        """The trajectory prior file the candidates come from, if any (its process runs torch with
        `seal.adversaries.candidate_sources.PRIOR_THREADS`, set by the entry point)."""

    def _generate(self, scenario: Scenario, history: Sequence[Rollout], rng: np.random.Generator) -> Generation:
        if not history:
            raise ValueError(f"{self.name}: empty roll-out history for scenario {scenario.scenario_id!r}")
        start = time.perf_counter()
        cands = adversary_candidates(self.candidate_source, scenario, self.name)
        candidate_s = time.perf_counter() - start
        ego_xy, ego_heading, ego_valid = stack_ego_rollouts(history)
        adv_xy, _, adv_valid = stack_adv_rollouts(history)
        context = CandidateContext(
            scenario=scenario, cands=cands, adv_size_m=_size_m(scenario, scenario.adv_index),
            ego_size_m=_size_m(scenario, scenario.ego_index), ego_xy=ego_xy, ego_heading=ego_heading,
            ego_valid=ego_valid, adv_xy=adv_xy, adv_valid=adv_valid, start=start, candidate_time_s=candidate_s,
        )
        return self._choose(context, rng)

    @abstractmethod
    def _choose(self, context: CandidateContext, rng: np.random.Generator) -> Generation:
        """Rank ``context.cands`` against the past ego roll-outs and return the generation of the chosen one
        (its ``extra`` ends with ``select_time_s = context.since_candidates_s()``)."""

    def follow_behavior(self, scenario: Scenario, chosen_xy: np.ndarray) -> AdversaryBehavior:
        """The adversary following the chosen candidate ``xy [F, 2]`` as ``self.follow`` says."""
        if self.follow == Follow.REPLAY:
            return ReplayBehavior(candidate_track(scenario, scenario.adv_index, chosen_xy))
        return TrackingBehavior(chosen_xy, start_step=CURRENT_STEP + 1)
