"""Scenario scoring on logged tracks (no simulator; depends only on the `seal` core and numpy / shapely /
matplotlib).

* `seal.scoring.proximity` — body gaps and collisions of the (ego, adv) pair.
* SafeShift (thesis ch. 3): `seal.scoring.scores.score_scenario` (features in `individual`, `social`, lanes in
  `frenet`, counterfactual tracks in `extrapolation`, motion primitives in `primitives`), dataset scoring and
  storage in `seal.scoring.store` (`score_dataset`, `load_scores`), Normal / Hard splits in `seal.scoring.splits`
  (`make_splits`), figures in `seal.scoring.report` (`write_report`, imports matplotlib), timing in
  `seal.scoring.bench`.
* SEAL criticality (eq. 6.1, 6.2): `seal.scoring.criticality` (`f_coll`, `f_diff`).
* Realism and collision metrics (6.4.3): `seal.scoring.realism` (`realism_wd`, `collision_metrics`).
"""

from seal.scoring.criticality import f_coll, f_diff
from seal.scoring.proximity import PairProximity, any_collision, pair_gaps, pair_proximity, pool_proximity
from seal.scoring.realism import collision_metrics, realism_wd
from seal.scoring.scores import VARIANTS, score_scenario
from seal.scoring.splits import make_splits
from seal.scoring.store import load_scores, score_dataset

__all__ = [
    "VARIANTS",
    "PairProximity",
    "any_collision",
    "collision_metrics",
    "f_coll",
    "f_diff",
    "load_scores",
    "make_splits",
    "pair_gaps",
    "pair_proximity",
    "pool_proximity",
    "realism_wd",
    "score_dataset",
    "score_scenario",
]
