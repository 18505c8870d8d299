"""Held-out evaluation of pi_score (item 3 of `seal.experiments.fitting.objective`): MSE per head, the ranking of the
candidates against the simulated ``f_coll + f_diff`` for pi_score and the baselines (logged previous roll-out and
K = 5), each head against its own label, oracle bounds, the label retest and ``rank()`` latency; `evaluate` returns
the metrics that `seal.experiments.fitting.objective_report` writes."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from seal.adversaries.cat.select import cat_select
from seal.core.scenario import CURRENT_STEP
from seal.experiments.fitting.objective_report import K_PREV
from seal.models.objective.labels import LOGGED_ROW, LabelSet
from seal.models.objective.metrics import near_tie_share, ranking_report, spearman
from seal.scoring.criticality import f_coll

LATENCY_CALLS = 200
"""``rank()`` calls timed by `rank_latency_ms`."""


def label_stats(labels: LabelSet) -> dict[str, Any]:
    """How the simulated labels look (share of crashes, of candidates that change the ego's behaviour, of candidate
    pairs whose targets differ by < 0.01)."""
    logged = labels.f_diff[:, LOGGED_ROW]
    return {
        "scenarios": labels.n_scenarios,
        "candidates": labels.n_candidates,
        "pairs": int(labels.f_diff.size),
        "crash_share": round(float(labels.crashed.mean()), 4),
        "scenarios_with_a_crash": round(float(labels.crashed.any(axis=1).mean()), 4),
        "f_coll_mean": round(float(labels.f_coll.mean()), 4),
        "f_coll_var": round(float(labels.f_coll.var()), 5),
        "f_diff_var_all_prev": round(float(labels.f_diff.var()), 5),
        "f_diff_mean_all_prev": round(float(labels.f_diff.mean()), 4),
        "f_diff_mean_logged_prev": round(float(logged.mean()), 4),
        "share_f_diff_gt_0.5_logged_prev": round(float((logged > 0.5).mean()), 4),
        # How much of the per-scenario Spearman rides on differences too small to matter (`near_tie_share`).
        "near_tie_share_logged_prev": round(near_tie_share(labels.f_coll + logged), 4),
    }


def closeness(labels: LabelSet, prev: np.ndarray) -> np.ndarray:
    """``[S, len(prev), N]`` f_coll of each candidate against previous roll-out rows ``prev [S, P]``, as if the
    ego did not react (the no-simulation heuristic)."""
    s = np.arange(labels.n_scenarios)[:, None]
    ego = labels.ego_xy[s, prev][:, :, None]  # [S, P, 1, T, 2]
    valid = labels.ego_valid[s, prev][:, :, None]
    return f_coll(ego, labels.cand_xy[:, None], valid=valid)


def cat_scores(labels: LabelSet, prev: np.ndarray) -> np.ndarray:
    """``[S, N]`` CAT's score of every candidate (`seal.adversaries.cat.select.cat_select`: prior-weighted first
    box hit, summed over roll-outs) against the previous roll-out rows ``prev [S, P]`` of each scenario, with the
    stored vehicle sizes; ``prev`` = the logged row alone gives the labels' own ``cat_score``."""
    out = np.zeros((labels.n_scenarios, labels.n_candidates))
    pad = CURRENT_STEP + 1  # cat_select indexes ego roll-outs by scenario step; the labels start after the present
    for s, rows in enumerate(np.asarray(prev)):
        k = len(rows)
        ego_xy = np.concatenate([np.zeros((k, pad, 2)), labels.ego_xy[s, rows]], axis=1)
        ego_h = np.concatenate([np.zeros((k, pad)), labels.ego_heading[s, rows]], axis=1)
        ego_v = np.concatenate([np.zeros((k, pad), dtype=bool), labels.ego_valid[s, rows]], axis=1)
        (ego_l, ego_w), (adv_l, adv_w) = labels.sizes_m[s].astype(np.float64)
        out[s] = cat_select(labels.cand_xy[s], labels.cand_heading[s], labels.probs[s], adv_size_m=(adv_l, adv_w),
                            ego_xy=ego_xy, ego_heading=ego_h, ego_valid=ego_v, ego_size_m=(ego_l, ego_w)).scores
    return out


def _prev_rows(labels: LabelSet, seed: int) -> np.ndarray:
    """``[S, K_PREV]`` previous roll-outs per scenario: the logged one and K - 1 candidates' episodes."""
    rng = np.random.default_rng(seed)
    m = labels.ego_xy.shape[1]
    k = min(K_PREV, m)
    rows = [np.r_[LOGGED_ROW, 1 + rng.choice(m - 1, k - 1, replace=False)] for _ in range(labels.n_scenarios)]
    return np.asarray(rows, dtype=np.int64)


def per_head_ranking(pred: np.ndarray, close: np.ndarray, labels: LabelSet) -> dict[str, dict[str, float]]:
    """Mean Spearman (over scenarios, previous roll-out = the logged episode) of each head alone against its own
    label, next to closeness against the same label: where the learned objective ranks candidates differently
    from closeness and where it only shifts the level of a scenario (which no ranking sees).

    Args:
        pred: ``[S, N, 2]`` predicted f_coll, f_diff.
        close: ``[S, N]`` closeness to the logged-adversary roll-out.
        labels: the labels (f_coll ``[S, N]``, f_diff of the logged row ``[S, N]``).
    """
    out = {}
    for h, (name, target) in enumerate((("f_coll", labels.f_coll), ("f_diff", labels.f_diff[:, LOGGED_ROW]))):
        out[name] = {"pi_score_head": round(float(spearman(pred[..., h], target).mean()), 4),
                     "closeness": round(float(spearman(close, target).mean()), 4)}
    return out


def oracle_bounds(close: np.ndarray, labels: LabelSet) -> dict[str, float]:
    """Mean Spearman (over scenarios, previous roll-out = the logged episode) against the simulated f_coll + f_diff
    of closeness with one part of that target known exactly: the crash flags (crashing candidates first, closeness
    within each group: the most any crash predictor can add to closeness) and f_diff (closeness + the true f_diff:
    what predicting the ego's change of path would give). How far above closeness a learned score can get, and where.

    Args:
        close: ``[S, N]`` closeness to the logged-adversary roll-out.
        labels: the labels (crash flags, f_coll and f_diff of the logged row).
    """
    logged = labels.f_diff[:, LOGGED_ROW]
    target = labels.f_coll + logged
    return {"closeness_plus_true_crash": round(float(spearman(close + labels.crashed, target).mean()), 4),
            "closeness_plus_true_f_diff": round(float(spearman(close + logged, target).mean()), 4)}


def label_retest(labels: LabelSet, second: LabelSet, scores: dict[str, np.ndarray]) -> dict[str, Any]:
    """How reproducible the held-out labels are: ``second`` is another draw of the same labels (same scenarios,
    candidates and ego; another skill-noise seed of the ``seal`` label behaviour). With the logged-adversary episode
    as the previous roll-out, the mean Spearman of the second draw's ``f_coll + f_diff`` against the first draw's says
    how much of the label is noise: one draw already ranks the other this well, and a score that predicted the
    expected label exactly would reach about the square root of it (for correlations, corr(E[y], y) = sqrt(corr(y1,
    y2))). A score far below it is short of what the labels allow, not held back by their noise. ``scores`` (``[S,
    N]`` each, e.g. pi_score and closeness) are ranked against the second draw too.

    Raises ValueError when the two label sets are not of the same scenarios and candidates."""
    same = (list(labels.scenario_ids) == list(second.scenario_ids) and labels.cand_xy.shape == second.cand_xy.shape
            and np.allclose(labels.cand_xy, second.cand_xy, atol=1e-4)
            and np.allclose(labels.ego_xy[:, LOGGED_ROW], second.ego_xy[:, LOGGED_ROW], atol=1e-4))
    if not same:
        raise ValueError("label retest: the second draw is not of the same scenarios, candidates and logged "
                         "episodes as the labels (other split, limit, prior or ego); delete its folder and re-run")
    first_sum = labels.f_coll + labels.f_diff[:, LOGGED_ROW]
    second_sum = second.f_coll + second.f_diff[:, LOGGED_ROW]

    def mean_rho(a: np.ndarray, b: np.ndarray) -> float:
        return round(float(spearman(a, b).mean()), 4)

    return {
        "label_spearman": mean_rho(second_sum, first_sum),
        "label_spearman_per_head": {"f_coll": mean_rho(second.f_coll, labels.f_coll),
                                    "f_diff": mean_rho(second.f_diff[:, LOGGED_ROW], labels.f_diff[:, LOGGED_ROW])},
        "f_diff_above_half_agreement": round(float(np.mean((labels.f_diff[:, LOGGED_ROW] > 0.5)
                                                           == (second.f_diff[:, LOGGED_ROW] > 0.5))), 4),
        "scores_on_second_draw": {name: mean_rho(v, second_sum) for name, v in scores.items()},
        "scenarios": int(labels.n_scenarios),
    }


def evaluate(model: Any, labels: LabelSet, seed: int = 0, retest: LabelSet | None = None) -> dict[str, Any]:
    """Held-out metrics of the module docstring for ``model`` (an `ObjectiveModel`) on ``labels``; with ``retest``
    (a second draw of the same labels) also `label_retest`."""
    from seal.models.objective.train import PairTensors, predict_pairs

    tensors = PairTensors(labels)
    all_pairs = tensors.pairs(np.arange(labels.n_scenarios), "all")
    pred = predict_pairs(model, tensors, all_pairs)
    s, i, j = all_pairs.T
    target = np.stack([labels.f_coll[s, j], labels.f_diff[s, i, j]], axis=-1)
    logged = i == LOGGED_ROW

    def mse(rows: np.ndarray) -> dict[str, float]:
        err = (pred[rows] - target[rows]) ** 2
        return {"f_coll": round(float(err[:, 0].mean()), 5), "f_diff": round(float(err[:, 1].mean()), 5),
                "pairs": int(rows.sum())}

    n_s, m, n = labels.n_scenarios, labels.ego_xy.shape[1], labels.n_candidates
    pred_grid = pred.reshape(n_s, m, n, 2)

    # The logged-adversary episode as the previous roll-out.
    sim_logged = labels.f_coll + labels.f_diff[:, LOGGED_ROW]
    close_logged = closeness(labels, np.full((n_s, 1), LOGGED_ROW))[:, 0]
    scores_logged = {
        "pi_score": pred_grid[:, LOGGED_ROW].sum(axis=-1),
        "closeness": close_logged,
        "cat": labels.cat_score + 1e-6 * close_logged,
        "prior_probability": labels.probs.astype(np.float64),
    }
    # K = 5 previous roll-outs: SEAL's selection score against f_coll + mean_i f_diff_i.
    prev = _prev_rows(labels, seed)
    rows = np.arange(n_s)[:, None]
    sim_k = labels.f_coll + labels.f_diff[rows, prev].mean(axis=1)
    close_k = closeness(labels, prev).mean(axis=1)
    scores_k = {
        "pi_score": pred_grid[rows, prev].sum(axis=-1).mean(axis=1),
        "closeness": close_k,
        # CAT's ties among candidates that hit no roll-out are broken by closeness, as for the logged previous one.
        "cat": cat_scores(labels, prev) + 1e-6 * close_k,
        "prior_probability": labels.probs.astype(np.float64),
    }
    report = {
        "mse": {"all_prev": mse(np.ones(len(all_pairs), dtype=bool)), "logged_prev": mse(logged)},
        "ranking_logged_prev": {k: ranking_report(v, sim_logged, crashed=labels.crashed)
                                for k, v in scores_logged.items()},
        "ranking_per_head": per_head_ranking(pred_grid[:, LOGGED_ROW], close_logged, labels),
        "oracle_bounds_logged_prev": oracle_bounds(close_logged, labels),
        "ranking_k5_prev": {k: ranking_report(v, sim_k, crashed=labels.crashed) for k, v in scores_k.items()},
        "labels": label_stats(labels),
    }
    if retest is not None:
        report["label_retest"] = label_retest(labels, retest, {k: v for k, v in scores_logged.items()
                                                               if k != "prior_probability"})
    return report


def rank_latency_ms(model: Any, n_calls: int = LATENCY_CALLS, seed: int = 0) -> dict[str, float]:
    """Median / p95 wall time (ms) of ``model.rank`` for 32 candidates x K = 5 roll-outs on one torch thread."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        rng = np.random.default_rng(seed)
        t = model.config.n_steps
        cand_xy = np.cumsum(np.broadcast_to(rng.normal(size=(32, 1, 2)), (32, t, 2)), axis=1)
        cand_h = np.arctan2(cand_xy[..., 1], cand_xy[..., 0])
        ego_xy = np.cumsum(np.ones((K_PREV, t, 2)), axis=1)
        ego_h, ego_v = np.zeros((K_PREV, t)), np.ones((K_PREV, t), dtype=bool)
        adv = {"adv_xy": ego_xy + np.array([10.0, 0.0]), "adv_valid": ego_v,  # the previous adversary 10 m ahead
               "cand_probs": rng.dirichlet(np.ones(32))}
        for _ in range(10):
            model.rank(cand_xy, cand_h, ego_xy, ego_h, ego_v, **adv)
        times = []
        for _ in range(n_calls):
            start = time.perf_counter()
            model.rank(cand_xy, cand_h, ego_xy, ego_h, ego_v, **adv)
            times.append(time.perf_counter() - start)
    finally:
        torch.set_num_threads(threads)
    ms = np.asarray(times) * 1e3
    return {"median_ms": round(float(np.median(ms)), 2), "p95_ms": round(float(np.percentile(ms, 95)), 2),
            "calls": n_calls, "candidates": 32, "rollouts": K_PREV}
