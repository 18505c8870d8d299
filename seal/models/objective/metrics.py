"""Ranking metrics of a candidate score against simulated outcomes, per scenario (numpy only).

* Spearman correlation between a score and the simulated ``f_coll + f_diff`` over the candidates of a scenario
  (average ranks for ties; a constant score or target has no correlation and counts as 0).
* Top-1-in-top-k: the score's best candidate is among the k best simulated candidates (ties at the k-th place
  count as in).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def average_ranks(x: np.ndarray) -> np.ndarray:
    """Ranks ``0..n-1`` along the last axis; tied values share their mean rank."""
    x = np.asarray(x, dtype=np.float64)
    order = np.argsort(x, axis=-1, kind="stable")
    sorted_x = np.take_along_axis(x, order, axis=-1)
    n = x.shape[-1]
    ranks = np.empty_like(x)
    flat_sorted = sorted_x.reshape(-1, n)
    flat_order = order.reshape(-1, n)
    flat_ranks = ranks.reshape(-1, n)
    for r in range(flat_sorted.shape[0]):
        # Tie groups: starts where the sorted value changes.
        starts = np.flatnonzero(np.r_[True, np.diff(flat_sorted[r]) != 0])
        ends = np.r_[starts[1:], n]
        mean_rank = (starts + ends - 1) / 2.0
        flat_ranks[r, flat_order[r]] = np.repeat(mean_rank, ends - starts)
    return ranks


def spearman(score: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Spearman correlation along the last axis (``[..., N]`` -> ``[...]``); 0 where either side is constant."""
    a = average_ranks(score)
    b = average_ranks(target)
    a = a - a.mean(axis=-1, keepdims=True)
    b = b - b.mean(axis=-1, keepdims=True)
    den = np.sqrt((a * a).sum(axis=-1) * (b * b).sum(axis=-1))
    num = (a * b).sum(axis=-1)
    return np.where(den > 1e-12, num / np.where(den > 1e-12, den, 1.0), 0.0)


def top1_in_topk(score: np.ndarray, target: np.ndarray, k: int = 3) -> np.ndarray:
    """``[...]`` bool: the argmax of ``score`` has a target at least the k-th largest target."""
    score, target = np.asarray(score, np.float64), np.asarray(target, np.float64)
    best = np.argmax(score, axis=-1)
    kth = -np.sort(-target, axis=-1)[..., min(k, target.shape[-1]) - 1]
    return np.take_along_axis(target, best[..., None], axis=-1)[..., 0] >= kth - 1e-12


def crash_chosen_when_any(score: np.ndarray, crashed: np.ndarray) -> float:
    """Among the scenarios (rows of ``[S, N]``) where some candidate made the ego hit the adversary (``crashed``),
    the share where the score's top candidate is one of them (NaN when no scenario has a crash): how often a
    selector that plays its best candidate finds a crash that exists."""
    crashed = np.asarray(crashed, dtype=bool)
    has = crashed.any(axis=-1)
    if not has.any():
        return float("nan")
    best = np.argmax(np.asarray(score, np.float64), axis=-1)
    return float(np.take_along_axis(crashed, best[..., None], axis=-1)[..., 0][has].mean())


def ranking_report(score: np.ndarray, target: np.ndarray, k: int = 3, crashed: np.ndarray | None = None
                   ) -> dict[str, Any]:
    """Mean / median Spearman, share of scenarios with Spearman >= 0.6, top-1-in-top-k rate and the mean simulated
    target of the chosen candidate against the best possible (regret), over scenarios (rows of ``[S, N]``); with
    ``crashed [S, N]`` also `crash_chosen_when_any`."""
    rho = spearman(score, target)
    best = np.argmax(score, axis=-1)
    chosen = np.take_along_axis(np.asarray(target, np.float64), best[:, None], axis=-1)[:, 0]
    report: dict[str, Any] = {
        "spearman_mean": round(float(rho.mean()), 4),
        "spearman_median": round(float(np.median(rho)), 4),
        "share_spearman_ge_0.6": round(float((rho >= 0.6).mean()), 4),
        f"top1_in_top{k}": round(float(top1_in_topk(score, target, k).mean()), 4),
        "chosen_target_mean": round(float(chosen.mean()), 4),
        "best_target_mean": round(float(np.max(target, axis=-1).mean()), 4),
        "scenarios": int(rho.size),
    }
    if crashed is not None:
        report["crash_chosen_when_any"] = round(crash_chosen_when_any(score, crashed), 4)
    return report


def near_tie_share(target: np.ndarray, tolerance: float = 0.01) -> float:
    """Share of the candidate pairs of a scenario (rows of ``[S, N]``, every unordered pair) whose targets differ by
    less than ``tolerance``, averaged over scenarios: how much of a per-scenario Spearman is decided by differences
    that small."""
    t = np.asarray(target, np.float64)
    n = t.shape[-1]
    iu = np.triu_indices(n, 1)
    close = np.abs(t[..., :, None] - t[..., None, :])[..., iu[0], iu[1]] < tolerance
    return float(close.mean()) if close.size else float("nan")
