"""The interval figure of the report: per setting, each pipeline's success rate with its 95 % interval, drawn by
rliable's `plot_interval_estimates` (one panel per setting, a bar from the interval's low to its high end, a tick at
the point estimate)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.experiments.report.compare import ordered_pipelines

STATISTICS = {"mean": ("mean", "ci_low", "ci_high"), "iqm": ("iqm", "iqm_low", "iqm_high")}


def plot_success_intervals(table: Sequence[Mapping[str, Any]], out: Path, statistic: str = "mean",
                           metric: str = "success") -> Path | None:
    """``ci_<metric>_<statistic>.png`` in ``out`` from `seal.experiments.report.stats.ego_ci_table` rows (rates
    drawn in %); None when the table has no row of ``metric``."""
    rows = [r for r in table if r["metric"] == metric]
    if not rows:
        return None
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    point_key, low_key, high_key = STATISTICS[statistic]
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    # rliable draws the first algorithm at the bottom: reverse so the report's order reads top-down.
    pipelines = ordered_pipelines(r["pipeline"] for r in rows)[::-1]
    cells = {(r["pipeline"], r["setting"]): r for r in rows}
    points, intervals = {}, {}
    for p in pipelines:
        got = [cells.get((p, s)) for s in settings]
        points[p] = np.array([100 * c[point_key] if c else np.nan for c in got])
        intervals[p] = np.array([[100 * c[low_key] if c else np.nan for c in got],
                                 [100 * c[high_key] if c else np.nan for c in got]])
    # One panel per setting: rliable indexes the axes as an array, which needs two panels or more.
    names = settings if len(settings) > 1 else [*settings, ""]
    if len(settings) == 1:
        points = {p: np.append(v, np.nan) for p, v in points.items()}
        intervals = {p: np.hstack([v, [[np.nan], [np.nan]]]) for p, v in intervals.items()}
    fig, axes = plot_utils.plot_interval_estimates(
        points, intervals, metric_names=names, algorithms=pipelines, subfigure_width=2.6,
        row_height=0.45, xlabel=f"ego {metric.replace('_', '-')} rate (%), {statistic} with 95 % interval",
        xlabel_y_coordinate=-0.02 - 0.6 / max(2, len(pipelines)), wspace=0.25)
    for ax in np.ravel(axes):  # one scale in every panel, so the settings compare at a glance
        ax.set_xlim(-2, 102)
        ax.set_xticks([0, 50, 100])
    path = out / f"ci_{metric}_{statistic}.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path
