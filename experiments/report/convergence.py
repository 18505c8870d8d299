"""Had the egos finished learning? Read from each run's periodic Normal evaluations (``RUN/eval/evaluations.csv``,
`seal.experiments.report.eval_curves`): the slope of its success rate over the last half of its evaluations
(least squares, in points per 10,000 env steps), per training pipeline (and ego algorithm).

A pipeline whose egos are still improving when training stops is compared at a budget, not at convergence: an
adversarial curriculum takes training time from ordinary driving, so at a short budget it can lose to No-Adv for that
reason alone. The report says so on its first page instead of leaving it to a reader of the curves.

The standard error treats each evaluation's success rate as binomial over its episodes and the evaluations as
independent: an approximation, since every periodic evaluation replays the same scenarios; it keeps one noisy
evaluation of 100 episodes (+/- 4-5 points) from reading as a trend.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from seal.experiments.report.compare import ordered_pipelines
from seal.experiments.report.eval_curves import read_eval_curves
from seal.experiments.report.grouping import label_by_algo

MIN_LATE_EVALS = 3
"""Fewest evaluations in the late half for a slope (fewer: no verdict for that run)."""
RISING_PTS_PER_10K = 1.0
"""Mean late slope (success points per 10k env steps) from which a pipeline counts as still improving (or, negated,
as falling), when it is also more than `N_SE` standard errors from zero."""
N_SE = 2.0
"""Standard errors of the mean slope (from the binomial noise of the evaluations) a verdict needs."""


def late_slope(steps: np.ndarray, success: np.ndarray, episodes: np.ndarray | None = None
               ) -> tuple[float, float] | None:
    """Least-squares slope of ``success`` (rates in [0, 1]) against ``steps`` (env steps) over the last half of the
    evaluations (at least `MIN_LATE_EVALS`), in success points per 10,000 env steps, and its standard error from
    the binomial noise of rates over ``episodes`` episodes each (NaN without ``episodes``); None with too few."""
    steps, success = np.asarray(steps, np.float64), np.asarray(success, np.float64)
    n_eps = np.full(len(steps), np.nan) if episodes is None else np.asarray(episodes, np.float64)
    ok = np.isfinite(steps) & np.isfinite(success)
    steps, success, n_eps = steps[ok], success[ok], n_eps[ok]
    n_late = max(MIN_LATE_EVALS, math.ceil(len(steps) / 2))
    if len(steps) < n_late:
        return None
    x, y, n = steps[-n_late:], success[-n_late:], n_eps[-n_late:]
    dx = x - x.mean()
    if float((dx * dx).sum()) <= 0:
        return None
    weights = dx / (dx * dx).sum()  # slope = sum(weights * y)
    p = float(np.clip(y.mean(), 0.02, 0.98))  # a rate of 0 or 1 is still noisy at another seed
    se = float(np.sqrt((weights**2 * p * (1 - p) / n).sum()))
    scale = 100 * 10_000
    return float((weights * y).sum()) * scale, se * scale


def _verdict(mean: float, se: float) -> str:
    """The verdict of a mean late slope and its standard error (NaN: no episode counts, the size alone decides)."""
    sure = not math.isfinite(se) or abs(mean) > N_SE * se
    if mean >= RISING_PTS_PER_10K and sure:
        return "still improving"
    if mean <= -RISING_PTS_PER_10K and sure:
        return "falling"
    return "no clear trend"


def convergence_rows(runs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per pipeline (``<pipeline> (<algo>)`` when the runs use several algorithms) with periodic
    evaluations: ``runs`` (with a slope), ``late_slope_pts_per_10k`` (mean over them) and its standard error
    ``slope_se`` (binomial noise of the evaluations), ``share_rising``, ``final_success`` (mean of the last
    evaluations), ``last_step`` and ``verdict``: *still improving* / *falling* when the mean slope is at least
    `RISING_PTS_PER_10K` in size and more than `N_SE` standard errors from zero, else *no clear trend*."""
    labels = {str(r["run"]): str(r["pipeline"]) for r in label_by_algo(runs, runs)}
    groups: dict[str, list[tuple[float, float, float, float]]] = {}
    for run, cols in read_eval_curves(runs):
        if "success_rate" not in cols:
            continue
        fit = late_slope(cols["step"], cols["success_rate"], cols.get("episodes"))
        if fit is not None:
            groups.setdefault(labels[str(run["run"])], []).append(
                (*fit, float(cols["success_rate"][-1]), float(cols["step"][-1])))
    rows = []
    for label in ordered_pipelines(groups):
        slopes, ses = [g[0] for g in groups[label]], [g[1] for g in groups[label]]
        mean = float(np.mean(slopes))
        se = float(np.sqrt(np.sum(np.square(ses)))) / len(ses)  # of the mean; NaN without episode counts
        rows.append({"pipeline": label, "runs": len(slopes), "late_slope_pts_per_10k": round(mean, 2),
                     "slope_se": round(se, 2), "share_rising": round(float(np.mean([v > 0 for v in slopes])), 2),
                     "final_success": round(float(np.mean([g[2] for g in groups[label]])), 4),
                     "last_step": int(max(g[3] for g in groups[label])), "verdict": _verdict(mean, se)})
    return rows


def convergence_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The rows as a Markdown table (empty string without rows)."""
    if not rows:
        return ""
    lines = ["| pipeline | runs | late slope (points / 10k steps) +/- SE | seeds rising | final eval success "
             "| verdict |",
             "|---|---:|---:|---:|---:|---|"]
    lines += [f"| {r['pipeline']} | {r['runs']} | {r['late_slope_pts_per_10k']:+.2f} +/- {r['slope_se']:.2f} | "
              f"{100 * r['share_rising']:.0f} % | {100 * r['final_success']:.1f} % | {r['verdict']} |" for r in rows]
    return "\n".join(lines) + "\n"


def convergence_line(rows: Sequence[Mapping[str, Any]]) -> str | None:
    """The first page's line: which pipelines were still improving when training stopped (None without periodic
    evaluations)."""
    if not rows:
        return None
    rising = [r for r in rows if r["verdict"] == "still improving"]
    if not rising:
        return ("- Training: no pipeline's periodic Normal-eval success was still clearly rising when training "
                "stopped (late slope under +1 point per 10k env steps or within 2 standard errors of 0).")
    names = ", ".join(f"{r['pipeline']} ({r['late_slope_pts_per_10k']:+.1f})" for r in rising)
    return (f"- Training: still improving when training stopped (late slope of the periodic Normal-eval success, "
            f"points per 10k env steps): {names}; these rows compare pipelines at this training budget, not at "
            "convergence.")
