"""Scenario scoring on logged tracks (no simulator; depends only on the `seal` core and numpy / shapely /
matplotlib).

* `scoring.proximity` — body gaps and collisions of the (ego, adv) pair.
* SafeShift (thesis ch. 3): `scoring.scores.score_scenario` (features in `individual`, `social`, lanes in
  `frenet`, counterfactual tracks in `extrapolation`, motion primitives in `primitives`), dataset scoring and
  storage in `scoring.store` (`score_dataset`, `load_scores`), Normal / Hard splits in `scoring.splits`
  (`make_splits`), figures in `scoring.report` (`write_report`, imports matplotlib), timing in `scoring.bench`.
* SEAL criticality (eq. 6.1, 6.2): `scoring.criticality` (`f_coll`, `f_diff`).
* Realism and collision metrics (6.4.3): `scoring.realism` (`realism_wd`, `collision_metrics`).
"""

from scoring.criticality import f_coll, f_diff
from scoring.proximity import PairProximity, any_collision, pair_gaps, pair_proximity, pool_proximity
from scoring.realism import collision_metrics, realism_wd
from scoring.scores import VARIANTS, score_scenario
from scoring.splits import make_splits
from scoring.store import load_scores, score_dataset

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
