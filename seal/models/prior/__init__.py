"""The trajectory prior pi_gen: multimodal candidate futures for an agent (used by CAT, SEAL and later generators).

Public API:

* `Candidates` — K candidate futures of one agent in the world frame (the contract with the generators).
* `TrajectoryPrior` — ``load`` / ``save`` / ``predict`` / ``encode`` / ``decode`` of a trained prior.
* `constant_velocity_candidates` — the constant-velocity baseline and the prior's fallback.
* `PriorConfig`, `FeatureConfig`, `PriorTrainConfig`, `fit_prior`, `evaluate_prior`, `Encoding`.

Everything that needs torch is imported on first use, so ``from seal.models.prior import Candidates`` stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

from seal.models.prior.baseline import constant_velocity_candidates
from seal.models.prior.candidates import Candidates

_LAZY = {
    "TrajectoryPrior": "seal.models.prior.prior",
    "Encoding": "seal.models.prior.prior",
    "PriorFileError": "seal.models.prior.prior",
    "PriorConfig": "seal.models.prior.network",
    "FeatureConfig": "seal.models.prior.features",
    "PriorTrainConfig": "seal.models.prior.train_config",
    "fit_prior": "seal.models.prior.train",
    "evaluate_prior": "seal.models.prior.evaluate",
}

__all__ = ["Candidates", "constant_velocity_candidates", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'seal.models.prior' has no attribute {name!r}")
