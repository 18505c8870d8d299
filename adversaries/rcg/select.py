"""RCG's candidate selection (thesis 7.4, eq. 7.7; constants of 7.5.3 as defaults).

For each prior candidate ``i`` and each of the K past ego roll-outs ``k`` the perturbed scene ``s_i^(k)`` is the
base scenario with the ego's track replaced by roll-out k and the adversary's by candidate i (the other agents keep
their log, as in CAT); the adversary's behaviour in it is embedded (`seal.models.behavior.BehaviorModel`).

* ``d_i = 1/K sum_k KNN_dist(v_i^(k), V_unsafe)``, KNN_dist the mean Euclidean distance to the ``n_knn`` nearest
  unsafe embeddings of the model's cache; ``distance="prototype"`` uses the distance to the unsafe class centroid
  instead (the "Proto" ablation of Table 7.4).
* Collision closeness (CAT's heuristic): the minimum centre distance between candidate i and roll-out k over the
  steps both cover, averaged over k. The ``n_int`` candidates with the smallest closeness are kept; of those the
  one with the smallest ``d_i - prior_weight * log p_i`` is chosen (``p_i`` the candidate's prior probability;
  ``prior_weight = 0`` is the thesis's rule).

Why the plausibility term (README, "Plausibility weight"): unweighted, RCG picks braking candidates the prior
finds unlikely (the everyday "unsafe" class is mostly hard braking), and CAT-RCG's acceleration WD was 0.79 against
CAT's 0.54 (heuristic ego, decisive pool). ``d`` is in embedding units (~0.005 for the chosen candidate on the
decisive pool), hence the small default weight.

Only the kept candidates are embedded (``n_int x K`` scenes): the choice is the same as embedding all of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from seal.adversaries.candidate_path import candidate_track
from seal.adversaries.seal.objective import Ranking, log_prior
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, LENGTH, N_STEPS, VALID, VX, VY, WIDTH, Scenario, X, Y
from seal.models.prior.candidates import Candidates

if TYPE_CHECKING:
    from seal.models.behavior.model import BehaviorModel

N_INT = 6
"""Candidates kept by collision closeness (thesis N_int = 6)."""
N_KNN_CAT = 15
"""Neighbours of KNN_dist for CAT-RCG (thesis: 15, CAT cannot adapt during the roll-out)."""
N_KNN_SEAL = 8
"""Neighbours of KNN_dist for SEAL-RCG (thesis: 8)."""
DEFAULT_PRIOR_WEIGHT = 0.001
"""Weight of ``-log p(candidate)`` added to eq. 7.7's ``d`` (embedding units per nat; 0 = the thesis's rule). Chosen
on the train split among 1e-4 / 3e-4 / 1e-3 / 3e-3 (README, "Plausibility weight")."""


class Distance(StrEnum):
    """Distance of eq. 7.7: mean distance to the nearest unsafe embeddings, or to the unsafe prototype."""

    KNN = "knn"
    PROTOTYPE = "prototype"


DISTANCES = tuple(d.value for d in Distance)


def knn_distance(queries: np.ndarray, cache: np.ndarray, n_knn: int) -> np.ndarray:
    """``[Q]`` mean Euclidean distance of each row of ``queries [Q, D]`` to its ``n_knn`` nearest rows of
    ``cache [N, D]`` (all of them when ``N < n_knn``)."""
    if len(cache) == 0:
        raise ValueError("knn_distance: the unsafe cache is empty")
    # torch, not numpy: its matrix product runs on the threads the entry point set (numpy's BLAS may start its own
    # thread pool, which costs far more than the product on a loaded machine).
    q = torch.as_tensor(np.asarray(queries), dtype=torch.float64)
    c = torch.as_tensor(np.asarray(cache), dtype=torch.float64)
    dist = torch.cdist(q, c)
    k = min(int(n_knn), c.shape[0])
    return torch.topk(dist, k, dim=1, largest=False).values.mean(dim=1).numpy()


def closeness_m(cand_xy: np.ndarray, ego_xy: np.ndarray, ego_valid: np.ndarray) -> np.ndarray:
    """``[C]`` minimum centre distance (m) of candidate ``cand_xy [C, F, 2]`` (row j = step CURRENT_STEP + 1 + j) to
    each past ego roll-out ``ego_xy [K, T, 2]`` (row t = step t, ``ego_valid [K, T]``), averaged over the roll-outs
    that overlap the candidate in time (inf when none does)."""
    n_fut = cand_xy.shape[1]
    steps = CURRENT_STEP + 1 + np.arange(n_fut)
    ok = steps < ego_xy.shape[1]
    rows = steps[ok]
    valid = ego_valid[:, rows]  # [K, F']
    rel = cand_xy[:, None, ok] - ego_xy[None, :, rows]
    gap = np.hypot(rel[..., 0], rel[..., 1])  # [C, K, F']
    per_roll = np.where(valid[None], gap, np.inf).min(axis=-1)  # [C, K]
    usable = np.isfinite(per_roll)
    with np.errstate(invalid="ignore"):
        mean = np.where(usable, per_roll, 0.0).sum(1) / usable.sum(1)
    return np.where(usable.any(1), mean, np.inf)


def ego_tracks(scenario: Scenario, ego_xy: np.ndarray, ego_heading: np.ndarray, ego_valid: np.ndarray
               ) -> np.ndarray:
    """``[K, N_STEPS, 8]`` full ego tracks of the past roll-outs (row t = step t; velocities from finite
    differences of the positions, the box of the logged ego), cut or padded (invalid) to `N_STEPS`."""
    k, t = ego_valid.shape
    out = np.zeros((k, N_STEPS, 8))
    n = min(t, N_STEPS)
    xy = ego_xy[:, :n]
    vel = np.gradient(xy, DT_S, axis=1) if n > 1 else np.zeros_like(xy)
    now = scenario.tracks[scenario.ego_index, CURRENT_STEP]
    out[:, :n, X], out[:, :n, Y], out[:, :n, HEADING] = xy[..., 0], xy[..., 1], ego_heading[:, :n]
    out[:, :n, VX], out[:, :n, VY] = vel[..., 0], vel[..., 1]
    out[:, :n, LENGTH], out[:, :n, WIDTH] = now[LENGTH], now[WIDTH]
    out[:, :n, VALID] = ego_valid[:, :n]
    return out * out[..., VALID:VALID + 1]


def scene_bank(scenario: Scenario, cand_xy: np.ndarray, egos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The perturbed scenes as a bank of tracks and rows: ``bank [A + C + K, N_STEPS, 8]`` (the logged agents, the
    adversary on each candidate ``cand_xy[i]``, the ego on each roll-out ``egos[k]``) and ``scenes [C * K, A]``
    (candidate-major), scene ``(i, k)`` being the logged rows with the adversary's and the ego's replaced."""
    adv = np.stack([candidate_track(scenario, scenario.adv_index, xy) for xy in cand_xy])  # [C, T, 8]
    n, c, k = scenario.n_agents, adv.shape[0], egos.shape[0]
    bank = np.concatenate([scenario.tracks.astype(np.float64), adv, egos])
    scenes = np.tile(np.arange(n), (c * k, 1))
    scenes[:, scenario.adv_index] = n + np.repeat(np.arange(c), k)
    scenes[:, scenario.ego_index] = n + c + np.tile(np.arange(k), c)
    return bank, scenes


def perturbed_scenes(scenario: Scenario, cand_xy: np.ndarray, egos: np.ndarray) -> np.ndarray:
    """``[C * K, A, N_STEPS, 8]`` the scenes of `scene_bank` written out (for inspection and tests)."""
    bank, scenes = scene_bank(scenario, cand_xy, egos)
    return bank[scenes]


@dataclass(frozen=True)
class RCGSelection:
    """Outcome of `rcg_select`.

    Attributes:
        index: the chosen candidate.
        kept: ``[n_int]`` candidates kept by collision closeness (closest first).
        closeness_m: ``[C]`` collision closeness of every candidate (m).
        distance: ``[n_int]`` eq. 7.7's ``d`` of the kept candidates (embedding units).
        score: ``[n_int]`` what was minimised: ``d - prior_weight * log p`` of the kept candidates.
    """

    index: int
    kept: np.ndarray
    closeness_m: np.ndarray
    distance: np.ndarray
    score: np.ndarray


def rcg_select(
    model: BehaviorModel, scenario: Scenario, cands: Candidates, ego_xy: np.ndarray, ego_heading: np.ndarray,
    ego_valid: np.ndarray, n_knn: int, n_int: int = N_INT, distance: str = Distance.KNN,
    prior_weight: float = DEFAULT_PRIOR_WEIGHT,
) -> RCGSelection:
    """Pick the adversary candidate RCG's way (see the module docstring); ego arrays as from
    `seal.adversaries.candidate_generator.stack_ego_rollouts`."""
    close = closeness_m(cands.xy, ego_xy, ego_valid)
    kept = np.argsort(close, kind="stable")[: max(1, min(int(n_int), cands.n_candidates))]
    egos = ego_tracks(scenario, ego_xy, ego_heading, ego_valid)
    bank, scenes = scene_bank(scenario, cands.xy[kept], egos)
    v = model.embed_scenes(bank, scenes, scenario.adv_index)
    if distance == Distance.PROTOTYPE:
        d = np.linalg.norm(v - model.unsafe_prototype()[None], axis=1)
    else:
        if model.unsafe_cache is None:
            raise ValueError("rcg: the behaviour model has no unsafe cache (fit it with `seal fit behavior`)")
        d = knn_distance(v, model.unsafe_cache, n_knn)
    per_cand = d.reshape(kept.size, egos.shape[0]).mean(axis=1)
    score = per_cand - float(prior_weight) * log_prior(cands.probs)[kept] if prior_weight else per_cand
    return RCGSelection(int(kept[int(np.argmin(score))]), kept, close, per_cand, score)


class RCGObjective:
    """RCG as a SEAL objective (`seal.adversaries.seal.objective.Objective`, plus the scenario it needs).

    Args:
        model: a behaviour model file (``seal fit behavior``) or a loaded `BehaviorModel`.
        n_knn: neighbours of KNN_dist.
        n_int: candidates kept by collision closeness.
        distance: ``"knn"`` or ``"prototype"``.
        prior_weight: weight of the kept candidates' ``-log`` prior probability added to ``d`` (>= 0; 0 = the
            thesis's rule).
    """

    name = "rcg"

    def __init__(self, model: str | Path | BehaviorModel, n_knn: int, n_int: int = N_INT,
                 distance: str = Distance.KNN, prior_weight: float = DEFAULT_PRIOR_WEIGHT) -> None:
        if not np.isfinite(prior_weight) or prior_weight < 0:
            raise ValueError(f"rcg: prior_weight must be a finite number >= 0, got {prior_weight}")
        if distance not in DISTANCES:
            raise ValueError(f"rcg: distance must be one of {', '.join(DISTANCES)}, got {distance!r}")
        if int(n_knn) < 1 or int(n_int) < 1:
            raise ValueError(f"rcg: n_knn and n_int must be >= 1, got {n_knn} and {n_int}")
        if isinstance(model, str | Path):
            from seal.models.behavior.model import BehaviorModel

            if not Path(model).is_file():
                raise ValueError(f"rcg: behaviour model {str(model)!r} does not exist (train one with "
                                 "`seal fit behavior`)")
            model = BehaviorModel.load(model)
        self.model = model
        self.n_knn, self.n_int, self.distance = int(n_knn), int(n_int), Distance(distance)
        self.prior_weight = float(prior_weight)

    def select(self, scenario: Scenario, cands: Candidates, ego_xy: np.ndarray, ego_heading: np.ndarray,
               ego_valid: np.ndarray) -> RCGSelection:
        return rcg_select(self.model, scenario, cands, ego_xy, ego_heading, ego_valid, self.n_knn, self.n_int,
                          self.distance, self.prior_weight)

    def __call__(
        self, cands: Candidates, adv_size_m: tuple[float, float], ego_xy: np.ndarray, ego_heading: np.ndarray,
        ego_valid: np.ndarray, ego_size_m: tuple[float, float],
        prev_adv: tuple[np.ndarray, np.ndarray] | None = None, scenario: Scenario | None = None,
    ) -> Ranking:
        """`Ranking` of the candidates: the kept ones scored ``-d`` (higher = chosen), the others below them
        (``prev_adv`` is not used)."""
        if scenario is None:
            raise ValueError("rcg: ranking needs the base scenario (the perturbed scenes are built from it)")
        sel = self.select(scenario, cands, ego_xy, ego_heading, ego_valid)
        return Ranking(sel.index, ranking_scores(sel), selection_extra(sel))


def ranking_scores(sel: RCGSelection) -> np.ndarray:
    """``[C]`` scores, higher = preferred: ``-score`` for the kept candidates; every other candidate one unit below
    the lowest kept score, ordered by closeness (so ``argmax`` is the choice and the order is RCG's)."""
    n = sel.closeness_m.size
    scores = np.empty(n)
    kept_scores = -sel.score
    scores[sel.kept] = kept_scores
    rest = np.setdiff1d(np.arange(n), sel.kept)
    if rest.size:
        order = np.argsort(np.argsort(sel.closeness_m[rest], kind="stable"), kind="stable")
        scores[rest] = kept_scores.min() - 1.0 - order / max(rest.size, 1)
    return scores


def selection_extra(sel: RCGSelection) -> dict[str, Any]:
    """JSON-safe details of a selection for `seal.adversaries.base.Generation.extra`."""
    close = sel.closeness_m[sel.index]
    return {
        "rcg_distance": round(float(sel.distance[list(sel.kept).index(sel.index)]), 6),
        "rcg_kept": [int(i) for i in sel.kept],
        "rcg_closeness_m": round(float(close), 4) if np.isfinite(close) else None,
    }
