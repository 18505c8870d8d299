"""How far a skill space reaches: the hardest braking and the strongest throttle among the skills a prior offers in a
state, at a noise bound.

A ReSkill ego picks its skill as ``z = f_s^{-1}(b u)`` with its high-level action ``u`` in ``[-1, 1]^L`` and the
noise bound ``b`` (`seal.experiments.training.skill_prior.noise_of`), so what it can do in a state is bounded by
the skills that box maps to. For each state this module decodes the first action of the skills of `box_candidates`
(the box's corners, its centre and uniform draws) and keeps the lowest and highest acceleration. A space whose
median hardest braking is a fraction of what logged drivers do in their 5 % tail cannot express an emergency stop,
and an ego choosing among its skills cannot learn one, whatever it is trained against.

The first action is what a skill does before the state changes. For a decoder that also reads the previous action
(SEAL's smooth skills) it stays near that action, so the reach understates what such a skill does over its horizon;
the ReSkill ego's decoder does not read it (``experiments/configs/skills_ego.yaml``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from seal.models.skills.realnvp import ConditionalRealNVP
from seal.models.skills.vae import SkillVAE

REACH_NOISE_BOUNDS = (1.0, 2.0, 3.0)
"""Noise bounds the skills report measures the reach at (the ReSkill ego's ``noise_bound`` default is 1)."""

ACCEL = 1
"""Index of the acceleration in a normalised ``[steering, acceleration]`` action."""


def box_candidates(dim: int, n_random: int, rng: np.random.Generator) -> np.ndarray:
    """High-level actions ``[C, dim]`` float32 in ``[-1, 1]``: the box's corners (all of them up to dim 5, else 32
    drawn), its centre, then ``n_random`` uniform draws."""
    if dim <= 5:
        corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * dim, indexing="ij")).reshape(dim, -1).T
    else:
        corners = rng.choice([-1.0, 1.0], size=(32, dim))
    return np.vstack([corners, np.zeros((1, dim)), rng.uniform(-1.0, 1.0, (n_random, dim))]).astype(np.float32)


@torch.no_grad()
def first_accelerations(vae: SkillVAE, prior: ConditionalRealNVP, states: np.ndarray, candidates: np.ndarray,
                        noise_bound: float) -> np.ndarray:
    """First decoded acceleration ``[S, C]`` (normalised) of the skill ``f_s^{-1}(noise_bound * u)`` for each state
    ``states [S, D]`` and high-level action ``candidates [C, L]``."""
    vae.eval()
    prior.eval()
    s, c = len(states), len(candidates)
    cond = torch.as_tensor(states, dtype=torch.float32)
    embedded = prior.embed_state(cond).repeat_interleave(c, dim=0)
    noise = torch.as_tensor(noise_bound * candidates, dtype=torch.float32).repeat(s, 1)
    z = prior.sample(noise, embedded=embedded)
    actions = vae.decode(cond.repeat_interleave(c, dim=0), z)
    return actions[:, ACCEL].reshape(s, c).numpy()


def skill_reach(vae: SkillVAE, prior: ConditionalRealNVP, states: np.ndarray, logged_accel: np.ndarray,
                noise_bounds: Sequence[float] = REACH_NOISE_BOUNDS, n_random: int = 64, seed: int = 0
                ) -> dict[str, Any]:
    """Per noise bound, the hardest braking (lowest first acceleration) and strongest throttle of the skills in
    each state ``states [S, D]``: their 10 %, 50 % and 90 % quantiles over the states (normalised acceleration),
    and the logged drivers' acceleration quantiles in the same states (``logged_accel [S]``) for reference."""
    candidates = box_candidates(prior.config.latent_dim, n_random, np.random.default_rng(seed))
    quantiles = (10, 50, 90)

    def q(values: np.ndarray) -> dict[str, float]:
        return {f"p{p}": round(float(v), 4) for p, v in zip(quantiles, np.percentile(values, quantiles), strict=True)}

    out: dict[str, Any] = {"states": int(len(states)), "candidates": int(len(candidates))}
    for bound in noise_bounds:
        accel = first_accelerations(vae, prior, states, candidates, float(bound))
        out[f"noise_bound_{bound:g}"] = {"hardest_braking": q(accel.min(1)), "strongest_throttle": q(accel.max(1))}
    logged = np.percentile(np.asarray(logged_accel, dtype=np.float64), (5, 50, 95))
    out["logged_accel"] = {"p5": round(float(logged[0]), 4), "p50": round(float(logged[1]), 4),
                           "p95": round(float(logged[2]), 4)}
    return out


def format_reach(name: str, reach: dict[str, Any]) -> str:
    """One line: the median hardest braking and strongest throttle per noise bound, and the logged tails."""
    cells = [f"noise bound {key.removeprefix('noise_bound_')}: [{v['hardest_braking']['p50']:+.2f}, "
             f"{v['strongest_throttle']['p50']:+.2f}]" for key, v in reach.items() if key.startswith("noise_bound_")]
    logged = reach["logged_accel"]
    return (f"{name} skill reach (first decoded acceleration, median over {reach['states']} held-out states, "
            f"hardest braking / strongest throttle): {'; '.join(cells)}; logged drivers p5 / p95 "
            f"[{logged['p5']:+.2f}, {logged['p95']:+.2f}]")
