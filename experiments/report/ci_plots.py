"""The interval figures of the report: per setting, each pipeline's success rate with its 95 % interval, and its
success difference from No-Adv with its interval (`plot_success_differences`), drawn by
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


def plot_success_differences(table: Sequence[Mapping[str, Any]], out: Path) -> list[Path]:
    """``success_differences[_<algo>].png`` in ``out``, one per reference pipeline of
    `seal.experiments.report.differences.difference_table` rows: per setting (and over all settings) each pipeline's
    success minus the reference's in points with its 95 % interval, a line at 0; [] without rows."""
    if not table:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    paths = []
    references = list(dict.fromkeys(r["reference"] for r in table))
    for ref in references:
        rows = [r for r in table if r["reference"] == ref]
        settings = list(dict.fromkeys(r["setting"] for r in rows))
        names = settings if len(settings) > 1 else [*settings, ""]
        pipelines = ordered_pipelines(r["pipeline"] for r in rows)[::-1]
        cells = {(r["pipeline"], r["setting"]): r for r in rows}
        points, intervals = {}, {}
        for p in pipelines:
            got = [cells.get((p, s)) for s in names]
            d = np.array([100 * c["difference"] if c else np.nan for c in got])
            # no spread among the seeds: no interval, drawn as the point alone
            low = np.array([100 * c["low"] if c and np.isfinite(c["low"]) else v for c, v in zip(got, d, strict=True)])
            high = np.array([100 * c["high"] if c and np.isfinite(c["high"]) else v
                             for c, v in zip(got, d, strict=True)])
            points[p], intervals[p] = d, np.stack([low, high])
        bound = max(1.0, float(np.nanmax(np.abs(np.concatenate([v.ravel() for v in intervals.values()])))))
        fig, axes = plot_utils.plot_interval_estimates(
            points, intervals, metric_names=names, algorithms=pipelines, subfigure_width=2.6, row_height=0.45,
            xlabel=f"success minus {ref} (points), 95 % interval", wspace=0.25,
            xlabel_y_coordinate=-0.02 - 0.6 / max(2, len(pipelines)))
        for ax in np.ravel(axes):  # one symmetric scale, 0 marked: which side of no difference, at a glance
            ax.set_xlim(-1.05 * bound, 1.05 * bound)
            ax.axvline(0.0, color="black", linewidth=0.8)
        algo = ref[ref.index("(") + 1:-1] if ref.endswith(")") else ""
        path = out / (f"success_differences_{algo}.png" if algo and len(references) > 1 else "success_differences.png")
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=100, bbox_inches="tight")
        plt.close(fig)
        paths.append(path)
    return paths
