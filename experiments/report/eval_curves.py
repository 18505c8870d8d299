"""The runs' periodic evaluations as curves: ``seal train`` evaluates the ego every ``eval_every`` env steps on the
Normal eval split (one deterministic episode per scenario, logged adversary) and appends a row to
``RUN/eval/evaluations.csv`` (the same numbers as the ``eval/*`` keys in TensorBoard). One panel per metric, one
line per run, coloured by pipeline."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.experiments.report.compare import ordered_pipelines
from seal.experiments.report.compare_plots import _pyplot, read_progress, save_figure

EVAL_FILE = Path("eval") / "evaluations.csv"
EVAL_METRICS = ("success_rate", "crash_rate", "out_of_road_rate", "route_completion")


def read_eval_curves(runs: Sequence[Mapping[str, Any]]) -> list[tuple[Mapping[str, Any], dict[str, np.ndarray]]]:
    """(run, columns of its ``eval/evaluations.csv``) for every run folder that has one with a ``step`` column."""
    curves = []
    for run in runs:
        path = Path(str(run.get("path") or "")) / EVAL_FILE
        if run.get("path") and path.is_file():
            cols = read_progress(path)
            if "step" in cols and len(cols["step"]):
                curves.append((run, cols))
    return curves


def plot_eval_curves(runs: Sequence[Mapping[str, Any]], path: Path) -> Path | None:
    """``eval_curves.png``: the periodic Normal-eval rates of every run against env steps; None without any."""
    curves = read_eval_curves(runs)
    panels = [m for m in EVAL_METRICS if any(m in cols for _, cols in curves)]
    if not panels:
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4), squeeze=False)
    colors = {p: f"C{i}" for i, p in enumerate(ordered_pipelines(str(r["pipeline"]) for r, _ in curves))}
    for ax, metric in zip(axes[0], panels, strict=True):
        labelled: set[str] = set()
        for run, cols in curves:
            if metric not in cols:
                continue
            pipeline = str(run["pipeline"])
            ax.plot(cols["step"], 100 * cols[metric], marker="o", ms=3, color=colors[pipeline], alpha=0.8,
                    label=pipeline if pipeline not in labelled else None)
            labelled.add(pipeline)
        ax.set_xlabel("environment steps")
        ax.set_ylabel("%")
        ax.set_ylim(-2, 102)
        ax.set_title(f"eval {metric.replace('_', ' ')}")
        ax.legend(fontsize=8)
    return save_figure(fig, path)
