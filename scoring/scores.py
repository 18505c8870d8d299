"""SafeShift trajectory and scene scores of one scenario, for the variants GT, FE, AS and AC (thesis 3.3).

* GT: individual score of the logged track + social scores of logged pairs.
* FE: the same on the future-extrapolated tracks of all agents (`seal.scoring.extrapolation`).
* AS (asymmetric): agent i's individual score on its FE track + social scores of (i FE, j logged) for every j.
* AC (asymmetric combined) = max(GT, AS) per trajectory (thesis: "the maximum value of these two scores"; the
  SafeShift code takes the max per score component instead, which is never smaller).

Trajectory score = individual score + sum of the social scores of the pairs the agent is in (eq. 3.3). Scene
score = sum over agents of weight x trajectory score / (N_focal + sqrt(N_others)), weight 1 for the focal agents
(ego and adversary) and 1 / (1 + d) for the others, d (m) the smallest centre distance to a focal agent at a step
where both are valid: on GT tracks for GT, FE tracks for FE, the smaller of the two for AS and AC (as in the
SafeShift code).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from seal.core.road import RoadDescription
from seal.core.scenario import Scenario
from seal.scoring.extrapolation import future_extrapolate
from seal.scoring.frenet import RoadIndex
from seal.scoring.individual import INDIVIDUAL_FEATURES, individual_features, individual_score
from seal.scoring.primitives import Primitives, single_anomaly
from seal.scoring.social import SOCIAL_FEATURES, TrackContext, social_features, social_score
from seal.scoring.tracks import AgentTracks, from_tracks

VARIANTS = ("gt", "fe", "as", "ac")

_ROAD_CACHE: dict[int, tuple[RoadDescription, RoadIndex]] = {}
_ROAD_CACHE_SIZE = 64


def road_index(road: RoadDescription) -> RoadIndex:
    """`RoadIndex` of ``road``, cached per road object (shards share road objects between their scenarios)."""
    hit = _ROAD_CACHE.get(id(road))
    if hit is not None and hit[0] is road:
        return hit[1]
    if len(_ROAD_CACHE) >= _ROAD_CACHE_SIZE:
        _ROAD_CACHE.pop(next(iter(_ROAD_CACHE)))
    index = RoadIndex(road)
    _ROAD_CACHE[id(road)] = (road, index)
    return index


@dataclass
class ScenarioScores:
    """Scores of one scenario with ``A`` agents and ``P`` unordered pairs ``(pair_i < pair_j)`` active in at least
    one variant (all other pairs score 0).

    Attributes:
        ind_features: ``{"gt"|"fe": [A, len(INDIVIDUAL_FEATURES)]}``.
        ind_score: ``{"gt"|"fe": [A]}``.
        soc_features: ``{"gt"|"fe"|"as_ij"|"as_ji": [P, len(SOCIAL_FEATURES)]}`` (zeros for inactive pairs).
        pair_score: ``{"gt", "fe", "as_ij" (i FE, j GT), "as_ji" (j FE, i GT)}: [P]``.
        pair_active: ``{same keys}: [P]`` bool.
        traj: ``{variant: [A]}`` trajectory scores; weights: ``{variant: [A]}``; scene: ``{variant: float}``.
    """

    scenario_id: str
    agent_ids: np.ndarray
    focal: np.ndarray
    pair_i: np.ndarray
    pair_j: np.ndarray
    ind_features: dict[str, np.ndarray] = field(default_factory=dict)
    ind_score: dict[str, np.ndarray] = field(default_factory=dict)
    soc_features: dict[str, np.ndarray] = field(default_factory=dict)
    pair_score: dict[str, np.ndarray] = field(default_factory=dict)
    pair_active: dict[str, np.ndarray] = field(default_factory=dict)
    traj: dict[str, np.ndarray] = field(default_factory=dict)
    weights: dict[str, np.ndarray] = field(default_factory=dict)
    scene: dict[str, float] = field(default_factory=dict)


def focal_distance(tracks: AgentTracks, focal: np.ndarray) -> np.ndarray:
    """``[A]`` smallest centre distance (m) of each agent to any focal agent over steps where both are valid."""
    f = np.flatnonzero(focal)
    d = np.linalg.norm(tracks.pos[:, None] - tracks.pos[None, f], axis=-1)  # [A, F, T]
    both = tracks.valid[:, None] & tracks.valid[None, f]
    return np.where(both, d, np.inf).min(axis=(1, 2))


def scene_score(traj: np.ndarray, focal: np.ndarray, dist: np.ndarray) -> tuple[float, np.ndarray]:
    """Scene score and weights ``[A]`` from trajectory scores ``[A]``, focal mask ``[A]`` and distances ``[A]``."""
    weights = np.where(focal, 1.0, 1.0 / (1.0 + dist))
    n_focal = int(focal.sum())
    denom = n_focal + np.sqrt(max(traj.size - n_focal, 0))
    return float((weights * traj).sum() / denom), weights


def score_scenario(scenario: Scenario, prim: Primitives | None = None) -> ScenarioScores:
    """All variants' scores of one scenario (see the module docstring); ``prim`` None = no anomaly features."""
    index = road_index(scenario.road)
    gt = from_tracks(scenario.tracks, index)
    fe = future_extrapolate(gt, index)
    n = gt.n_agents
    focal = np.zeros(n, dtype=bool)
    focal[[scenario.ego_index, scenario.adv_index]] = True
    res = ScenarioScores(scenario.scenario_id, scenario.agent_ids.copy(), focal, *np.triu_indices(n, k=1))
    I, J = res.pair_i, res.pair_j

    ctx = {}
    for name, tr in (("gt", gt), ("fe", fe)):
        ctx[name] = TrackContext(tr, index)
        feats = individual_features(tr, single_anomaly(prim, ctx[name].windows))
        res.ind_features[name] = np.stack([feats[k] for k in INDIVIDUAL_FEATURES], axis=1)
        res.ind_score[name] = individual_score(feats)

    for name in ("gt", "fe"):
        feats, active = social_features(ctx[name], ctx[name], I, J, index, prim)
        res.soc_features[name] = np.stack([feats[k] for k in SOCIAL_FEATURES], axis=1)
        res.pair_score[name] = social_score(feats)
        res.pair_active[name] = active
    # Asymmetric: ordered pairs (i FE, j GT) for both orders in one call.
    feats, active = social_features(ctx["fe"], ctx["gt"], np.concatenate([I, J]), np.concatenate([J, I]), index, prim)
    both = social_score(feats)
    stacked = np.stack([feats[k] for k in SOCIAL_FEATURES], axis=1)
    res.soc_features["as_ij"], res.soc_features["as_ji"] = stacked[: I.size], stacked[I.size :]
    res.pair_score["as_ij"], res.pair_score["as_ji"] = both[: I.size], both[I.size :]
    res.pair_active["as_ij"], res.pair_active["as_ji"] = active[: I.size], active[I.size :]

    def pair_sum(score_i: np.ndarray, score_j: np.ndarray) -> np.ndarray:
        return np.bincount(I, score_i, minlength=n) + np.bincount(J, score_j, minlength=n)

    res.traj["gt"] = res.ind_score["gt"] + pair_sum(res.pair_score["gt"], res.pair_score["gt"])
    res.traj["fe"] = res.ind_score["fe"] + pair_sum(res.pair_score["fe"], res.pair_score["fe"])
    res.traj["as"] = res.ind_score["fe"] + pair_sum(res.pair_score["as_ij"], res.pair_score["as_ji"])
    res.traj["ac"] = np.maximum(res.traj["gt"], res.traj["as"])

    # Keep only pairs active in some variant: the rest score 0 everywhere (and would dominate memory).
    keep = np.logical_or.reduce([res.pair_active[k] for k in res.pair_active])
    res.pair_i, res.pair_j = I[keep], J[keep]
    for store in (res.soc_features, res.pair_score, res.pair_active):
        for k in store:
            store[k] = store[k][keep]

    d_gt, d_fe = focal_distance(gt, focal), focal_distance(fe, focal)
    dists = {"gt": d_gt, "fe": d_fe, "as": np.minimum(d_gt, d_fe), "ac": np.minimum(d_gt, d_fe)}
    for v in VARIANTS:
        res.scene[v], res.weights[v] = scene_score(res.traj[v], focal, dists[v])
    return res
