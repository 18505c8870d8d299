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
from seal.experiments.report.grouping import algo_of

STATISTICS = {"mean": ("mean", "ci_low", "ci_high"), "iqm": ("iqm", "iqm_low", "iqm_high")}


def _interval_figure(cells: Mapping[tuple[str, str], tuple[float, float, float]], settings: Sequence[str],
                     xlabel: str, xlim: tuple[float, float], path: Path, zero_line: bool = False,
                     xticks: Sequence[float] | None = None) -> Path:
    """One panel per setting, one row per pipeline (report order, top-down) of ``cells[(pipeline, setting)] =
    (point, low, high)``; missing cells left empty; every panel on the scale ``xlim``; saved to ``path``."""
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt
    from rliable import plot_utils

    # rliable draws the first algorithm at the bottom: reverse so the report's order reads top-down.
    pipelines = ordered_pipelines({p for p, _ in cells})[::-1]
    # One panel per setting: rliable indexes the axes as an array, which needs two panels or more.
    names = list(settings) if len(settings) > 1 else [*settings, ""]
    empty = (np.nan, np.nan, np.nan)
    got = {p: np.array([cells.get((p, s), empty) for s in names], dtype=np.float64) for p in pipelines}
    points = {p: v[:, 0] for p, v in got.items()}
    intervals = {p: v[:, 1:].T for p, v in got.items()}
    fig, axes = plot_utils.plot_interval_estimates(
        points, intervals, metric_names=names, algorithms=pipelines, subfigure_width=2.6, row_height=0.45,
        xlabel=xlabel, xlabel_y_coordinate=-0.02 - 0.6 / max(2, len(pipelines)), wspace=0.25)
    for ax in np.ravel(axes):  # one scale in every panel, so the settings compare at a glance
        ax.set_xlim(*xlim)
        if xticks is not None:
            ax.set_xticks(list(xticks))
        if zero_line:
            ax.axvline(0.0, color="black", linewidth=0.8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_success_intervals(table: Sequence[Mapping[str, Any]], out: Path, statistic: str = "mean",
                           metric: str = "success") -> Path | None:
    """``ci_<metric>_<statistic>.png`` in ``out`` from `seal.experiments.report.stats.ego_ci_table` rows (rates
    drawn in %); None when the table has no row of ``metric``."""
    rows = [r for r in table if r["metric"] == metric]
    if not rows:
        return None
    keys = STATISTICS[statistic]
    cells = {(r["pipeline"], r["setting"]): tuple(100 * r[k] for k in keys) for r in rows}
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    return _interval_figure(cells, settings, f"ego {metric.replace('_', '-')} rate (%), {statistic} with 95 % interval",
                            (-2, 102), out / f"ci_{metric}_{statistic}.png", xticks=(0, 50, 100))


def plot_success_differences(table: Sequence[Mapping[str, Any]], out: Path) -> list[Path]:
    """``success_differences[_<algo>].png`` in ``out``, one per reference pipeline of
    `seal.experiments.report.differences.difference_table` rows: per setting (and over all settings) each pipeline's
    success minus the reference's in points with its 95 % interval, a line at 0; [] without rows."""
    references = list(dict.fromkeys(r["reference"] for r in table))
    paths = []
    for ref in references:
        rows = [r for r in table if r["reference"] == ref]
        # no spread among the seeds: no interval, drawn as the point alone
        cells = {(r["pipeline"], r["setting"]): (100 * r["difference"],
                                                 100 * (r["low"] if np.isfinite(r["low"]) else r["difference"]),
                                                 100 * (r["high"] if np.isfinite(r["high"]) else r["difference"]))
                 for r in rows}
        bound = max(1.0, max(abs(v) for c in cells.values() for v in c))  # one symmetric scale, 0 marked
        algo = algo_of(ref)
        name = f"success_differences_{algo}.png" if algo and len(references) > 1 else "success_differences.png"
        settings = list(dict.fromkeys(r["setting"] for r in rows))
        paths.append(_interval_figure(cells, settings, f"success minus {ref} (points), 95 % interval",
                                      (-1.05 * bound, 1.05 * bound), out / name, zero_line=True))
    return paths
