"""`SteeredPrior`: a trajectory prior whose target latent is steered along one fitted vector before decoding (the
candidate source of the ``steered`` generator and of CAT / SEAL's ``steer`` option)."""

from __future__ import annotations

import itertools
import os
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import torch

from seal.core.scenario import Scenario
from seal.models.prior.baseline import constant_velocity_candidates
from seal.models.prior.candidates import Candidates
from seal.models.prior.prior import TrajectoryPrior
from seal.models.steering.bundle import SteeringBundle, SteeringFileError, SteeringVector
from seal.models.steering.latents import SceneBatch, decode_tokens, finish, prepare, site_names, tokens_at
from seal.models.steering.linear import random_direction


def resolve_vector(bundle: SteeringBundle, name: str) -> SteeringVector:
    """``FEATURE@SITE``, or a bare ``FEATURE`` (e.g. ``risk_proximity``) at the bundle's best probe site for it
    (``output`` when the bundle names none)."""
    if "@" in name:
        return bundle.get(name)
    best = bundle.info.get("best_site", {})
    feature = name.removeprefix("risk_")
    site = best.get(feature, "output") if isinstance(best, dict) else "output"
    return bundle.get(f"{name}@{site}")


SteerAlpha = float | Sequence[float] | str
"""One steering strength, or several (a sequence or comma-separated text) for a grid of steered decodes."""


def parse_alphas(alpha: SteerAlpha) -> tuple[float, ...]:
    """``alpha`` as a tuple of floats (``"-1,0,1"`` and ``[-1, 0, 1]`` give ``(-1.0, 0.0, 1.0)``)."""
    values: list[object]
    if isinstance(alpha, str):
        values = [a for a in alpha.replace(" ", "").split(",") if a]
    elif isinstance(alpha, Sequence):
        values = list(alpha)
    else:
        values = [alpha]
    try:
        out = tuple(float(str(a)) for a in values)
    except (TypeError, ValueError):
        raise ValueError(f"steer_alpha must be a number or a list of numbers, got {alpha!r}") from None
    if not out:
        raise ValueError("steer_alpha: no value given")
    return out


class SteeredPrior:
    """Candidates of ``prior`` with each target's latent moved along fitted vectors of ``steer``.

    One vector and one alpha: the target's latent moves by ``alpha * unit * direction`` and the 32 candidates of
    that decode are returned. Several vectors (comma-separated names, all at one site) and / or several alphas: a
    grid, one decode per combination (each vector scaled by each alpha, combinations summed; with 0 among the
    alphas the unsteered decode is one of them), every decode's candidates kept with its probabilities divided by
    the number of decodes.

    Args:
        prior: the trajectory prior.
        steer: a steering file or folder (``seal fit probes``), or a loaded `SteeringBundle`.
        vector: vector name(s) (`resolve_vector`), comma-separated for a grid.
        alpha: steering strength(s) in the vectors' unit (alpha for risk vectors, tau / 100 for control vectors).
        random_seed: the baseline: each vector's direction replaced by a random unit direction (seeded), its unit
            kept, so every offset has the norm of the structured one.
        project_road: project the decoded candidates on the road (`TrajectoryPrior.project`, with the prior's
            `road_projection` or its default): on by default, because the decoder's candidates leave the road in
            curves (roundabouts) whether steered or not, and steering moves more of them there (issue 20 note).
    """

    def __init__(self, prior: TrajectoryPrior, steer: str | os.PathLike[str] | SteeringBundle, vector: str,
                 alpha: SteerAlpha, random_seed: int | None = None, project_road: bool = True) -> None:
        bundle = steer if isinstance(steer, SteeringBundle) else SteeringBundle.load(steer)
        self.prior = prior
        self.project_road = bool(project_road)
        self.vectors = [resolve_vector(bundle, name.strip()) for name in str(vector).split(",") if name.strip()]
        if not self.vectors:
            raise ValueError(f"steer_vector: no vector name in {vector!r}")
        if random_seed is not None:
            rng = np.random.default_rng(random_seed)
            self.vectors = [replace(v, name=f"random({v.name})", direction=random_direction(v.direction.size, rng))
                            for v in self.vectors]
        for v in self.vectors:
            self._check(v)
        self.site = self.vectors[0].site
        if any(v.site != self.site for v in self.vectors):
            raise SteeringFileError(f"steer_vector {vector!r}: a grid needs vectors at one site, got "
                                    f"{', '.join(v.name for v in self.vectors)}")
        self.alphas = parse_alphas(alpha)
        combos = itertools.product(self.alphas, repeat=len(self.vectors))
        self.offsets = np.stack([sum((v.offset(a) for v, a in zip(self.vectors, combo, strict=True)),
                                     np.zeros(prior.config.d_model)) for combo in combos])
        """``[n_decodes, d_model]`` the offsets of the grid (one row for one vector and one alpha)."""

    def _check(self, v: SteeringVector) -> None:
        if v.site not in site_names(self.prior):
            raise SteeringFileError(f"steering vector {v.name!r} is at site {v.site!r}, which this prior does not "
                                    f"have ({', '.join(site_names(self.prior))})")
        if v.direction.shape != (self.prior.config.d_model,):
            raise SteeringFileError(f"steering vector {v.name!r} has {v.direction.size} dimensions; the prior's "
                                    f"latents have {self.prior.config.d_model} (fitted for another prior?)")

    def predict(self, scenario: Scenario, agent: int) -> Candidates:
        """Steered candidates of ``agent`` (constant-velocity fallback for a too-short history, as the prior)."""
        self.prior._check_present(scenario, agent)
        try:
            batch = prepare(self.prior, [scenario], [agent])
        except ValueError as exc:
            return constant_velocity_candidates(scenario, agent, self.prior.n_candidates, fallback=str(exc))
        n = len(self.offsets)
        tokens, mask = tokens_at(self.prior, batch, self.site)
        tokens, mask = tokens.repeat(n, 1, 1), mask.repeat(n, 1)
        tokens[:, 0] = tokens[:, 0] + torch.as_tensor(self.offsets, dtype=tokens.dtype)
        grid = SceneBatch({"start": batch.feats["start"].repeat(n, 1)}, np.repeat(batch.pose, n, axis=0))
        xy, probs = decode_tokens(self.prior, grid, finish(self.prior, self.site, tokens, mask), mask)
        xy = xy.reshape(-1, *xy.shape[2:])
        if self.project_road:  # every decode of the grid is the same agent: one call for all its candidates
            xy = self.prior.project_agent(xy, batch.pose[0], batch.feats["start"][0].numpy(), scenario.road)
        return Candidates.from_positions(xy, probs.reshape(-1) / n, batch.pose[0, :2],
                                         float(batch.pose[0, 2]), agent)
