"""How SEAL ranks its candidates (thesis 6.3.1; Fig. 6.5 "Learned Obj" vs "Heuristic Obj").

* A learned objective file (`seal.models.objective.ObjectiveModel`, imported lazily): every candidate is scored with the
  mean over the K past ego roll-outs of the predicted ``f_coll + f_diff``, plus ``prior_weight`` times the log of the
  candidate's prior probability; the highest score wins. ``prior_weight = 0`` is the thesis's rule (6.3.1).

  Why the plausibility term (README, "Plausibility weight"): the learned score alone picks the prior's
  unlikeliest modes (median prior probability 0.001 against CAT's 0.010), which are its stopping modes, and the
  adversary then brakes in front of the ego far more often than logged drivers do, making SEAL less realistic than
  CAT. A small weight keeps the choice among plausible futures while the learned score still decides between them.
* ``"cat"``: CAT's heuristic selection (`seal.adversaries.cat.select.cat_select`: prior-weighted earliest box
  intersection, closest candidate when none collides), the ablation.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from seal.adversaries.cat.select import DECAY, N_KEPT_MODES, STRIDE_STEPS, cat_select
from seal.models.prior.candidates import Candidates

HEURISTIC = "cat"
DEFAULT_PRIOR_WEIGHT = 0.02
"""Weight of ``log p(candidate)`` in SEAL's learned ranking (score units per nat; 0 = the thesis's score alone). Chosen
on the train split among 0.02 / 0.05 / 0.1 / 0.2 (README, "Plausibility weight")."""
DEFAULT_HEADS = "coll+diff"
"""The learned ranking's predicted terms: the thesis's ``f_coll + f_diff`` (`seal.models.objective.model.
DEFAULT_RANK_HEADS`, named here too because that package is imported only when a learned objective is used)."""
PROB_FLOOR = 1e-12
"""Probabilities are floored here before the log, so a candidate of probability 0 is penalised, not infinitely."""


def log_prior(probs: np.ndarray) -> np.ndarray:
    """``log p`` of candidate probabilities ``[C]`` (floored at `PROB_FLOOR`): the plausibility term SEAL's and
    RCG's rankings weigh with their ``prior_weight``."""
    return np.log(np.maximum(np.asarray(probs, dtype=np.float64), PROB_FLOOR))


@dataclass(frozen=True)
class Ranking:
    """Which candidate an objective picked.

    Attributes:
        index: the chosen candidate.
        scores: ``[N]`` the objective's score of every candidate (higher = better for the adversary).
        extra: objective-specific JSON-serialisable details.
    """

    index: int
    scores: np.ndarray
    extra: dict[str, Any]


class Objective(Protocol):
    """Ranks the candidates against past ego roll-outs (arrays as from
    `seal.adversaries.candidate_generator.stack_ego_rollouts`); ``prev_adv``: ``(xy [K, T, 2], valid [K, T])`` of
    what the adversary drove in each of those roll-outs (`stack_adv_rollouts`), for objectives that use it."""

    name: str

    def __call__(
        self, cands: Candidates, adv_size_m: tuple[float, float], ego_xy: np.ndarray, ego_heading: np.ndarray,
        ego_valid: np.ndarray, ego_size_m: tuple[float, float],
        prev_adv: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> Ranking: ...


class HeuristicObjective:
    """CAT's selection as SEAL's objective (see the module docstring); options as in `cat_select`."""

    name = HEURISTIC

    def __init__(self, stride: int = STRIDE_STEPS, decay: float = DECAY, n_kept: int = N_KEPT_MODES) -> None:
        self.stride, self.decay, self.n_kept = int(stride), float(decay), int(n_kept)

    def __call__(
        self, cands: Candidates, adv_size_m: tuple[float, float], ego_xy: np.ndarray, ego_heading: np.ndarray,
        ego_valid: np.ndarray, ego_size_m: tuple[float, float],
        prev_adv: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> Ranking:
        sel = cat_select(
            cands.xy, cands.heading, cands.probs, adv_size_m=adv_size_m, ego_xy=ego_xy, ego_heading=ego_heading,
            ego_valid=ego_valid, ego_size_m=ego_size_m, stride=self.stride, decay=self.decay, n_kept=self.n_kept,
        )
        return Ranking(sel.index, sel.scores, {"collision_predicted_cat": sel.collided,
                                               "cat_predicted_step": sel.predicted_step})


class LearnedObjective:
    """pi_score from a model file (`seal.models.objective.ObjectiveModel`): argmax of `ObjectiveModel.rank` plus
    ``prior_weight * log p`` (see the module docstring).

    Args:
        path: a model file written by ``seal fit objective``.
        prior_weight: weight of the candidates' log prior probability (>= 0; 0 = the learned score alone).
        heads: the predicted terms summed (`seal.models.objective.model.RANK_HEADS`): ``"coll+diff"`` (the
            thesis), ``"coll"`` or ``"diff"`` alone (ablations of the ranking rule).
    """

    def __init__(self, path: str | Path, prior_weight: float = DEFAULT_PRIOR_WEIGHT, heads: str = DEFAULT_HEADS
                 ) -> None:
        if not np.isfinite(prior_weight) or prior_weight < 0:
            raise ValueError(f"seal: prior_weight must be a finite number >= 0, got {prior_weight}")
        self.prior_weight = float(prior_weight)
        path = Path(path)
        try:
            from seal.models.objective import ObjectiveModel
            from seal.models.objective.model import RANK_HEADS
        except ImportError as exc:
            raise ValueError(f"seal: objective={str(path)!r} needs the learned objective package "
                f"seal.models.objective, "
                             f"which is not available ({exc}); use objective=cat for CAT's heuristic") from exc
        if heads not in RANK_HEADS:
            raise ValueError(f"seal: objective_heads must be one of {', '.join(RANK_HEADS)}, got {heads!r}")
        self.heads = heads
        self.model = ObjectiveModel.load(path)
        self.name = path.name
        self.n_steps = int(self.model.config.n_steps)

    def __call__(
        self, cands: Candidates, adv_size_m: tuple[float, float], ego_xy: np.ndarray, ego_heading: np.ndarray,
        ego_valid: np.ndarray, ego_size_m: tuple[float, float],
        prev_adv: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> Ranking:
        from seal.models.objective import align_ego_rollouts

        n = self.n_steps
        if cands.xy.shape[1] < n:
            raise ValueError(f"seal: the objective model scores {n}-step futures, the candidates have "
                             f"{cands.xy.shape[1]} steps (use a candidate source with {n} future steps)")
        xy, heading, valid = align_ego_rollouts(ego_xy, ego_heading, ego_valid, n_steps=n)
        adv: dict[str, np.ndarray] = {}
        if self.model.config.prev_adversary:
            if prev_adv is None:
                raise ValueError(f"seal: objective {self.name} ranks with the previous roll-outs' adversary; call it "
                                 "with prev_adv=(xy, valid) (seal.adversaries.candidate_generator.stack_adv_rollouts)")
            adv_xy, _, adv_valid = align_ego_rollouts(prev_adv[0], np.zeros(prev_adv[1].shape), prev_adv[1], n_steps=n)
            adv = {"adv_xy": adv_xy, "adv_valid": adv_valid}
        learned = np.asarray(self.model.rank(cands.xy[:, :n], cands.heading[:, :n], xy, heading, valid,
                                             heads=self.heads, cand_probs=cands.probs, **adv), dtype=np.float64)
        if self.prior_weight == 0.0:
            return Ranking(int(np.argmax(learned)), learned, {})
        scores = learned + self.prior_weight * log_prior(cands.probs)
        best = int(np.argmax(scores))
        return Ranking(best, scores, {"prior_weight": self.prior_weight, "learned_score": float(learned[best]),
                                      "learned_argmax": int(np.argmax(learned))})


def make_objective(spec: str | Path | Objective | None, prior_weight: float = DEFAULT_PRIOR_WEIGHT,
                   heads: str = DEFAULT_HEADS, **heuristic_options: Any) -> Objective:
    """``"cat"`` -> `HeuristicObjective` (with ``heuristic_options``); a file path -> `LearnedObjective` (with
    ``prior_weight`` and ``heads``); an `Objective` object is returned as is. ``prior_weight`` and ``heads`` apply to
    a learned objective only (CAT's heuristic weighs its candidates by the prior itself and has no heads)."""
    if spec is None:
        raise ValueError("seal: option 'objective' is required: a learned objective file (seal fit objective) or "
                         "'cat' for CAT's heuristic selection")
    if not isinstance(spec, str | Path):
        return spec
    if str(spec) == HEURISTIC:
        if heads != DEFAULT_HEADS:
            raise ValueError(f"seal: objective_heads={heads!r} needs a learned objective file, not objective=cat")
        return HeuristicObjective(**heuristic_options)
    if not Path(spec).is_file():
        raise ValueError(f"seal: objective {str(spec)!r} is neither 'cat' nor an existing objective model file "
                         "(train one with `seal fit objective`)")
    return LearnedObjective(spec, prior_weight, heads)
