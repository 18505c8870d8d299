"""Figures and videos of ``seal compare``: bars with IQR per setting, training curves from each run's
``progress.csv``, and videos of each generator against one ego (re-simulated with the evaluation's seeds)."""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.experiments.report.compare import EGO_METRICS, ordered_pipelines

CURVE_X = "time/total_timesteps"
CURVE_COLUMNS = ("rollout/ep_rew_mean", "episode/success_rate", "episode/crash_rate", "episode/out_of_road_rate",
                 "curriculum/p")
"""Columns of `seal train`'s progress.csv plotted against ``time/total_timesteps`` (training-episode rates over
the recent window and the curriculum's perturbation probability p(t)); a column of another name matches when it
ends with the entry's last part (e.g. ``rollout/success_rate``)."""


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")  # files only, no display
    import matplotlib.pyplot as plt

    return plt


def plot_setting_bars(table: Sequence[Mapping[str, Any]], out: Path) -> list[Path]:
    """One PNG per metric (``bars_<metric>.png``): settings on x, a bar per pipeline at the median over seeds
    with an error bar from the 25th to the 75th percentile."""
    plt = _pyplot()
    paths = []
    settings = list(dict.fromkeys(r["setting"] for r in table))
    pipelines = ordered_pipelines(r["pipeline"] for r in table)
    width = 0.8 / max(1, len(pipelines))
    for metric in EGO_METRICS:
        cells = {(r["pipeline"], r["setting"]): r for r in table if r["metric"] == metric}
        fig, ax = plt.subplots(figsize=(max(5.0, 1.2 * len(settings) * max(1, len(pipelines)) * 0.5 + 2), 3.6))
        x = np.arange(len(settings))
        for j, pipeline in enumerate(pipelines):
            rows = [cells.get((pipeline, s)) for s in settings]
            med = np.array([100 * r["median"] if r else np.nan for r in rows])
            lo = np.array([100 * (r["median"] - r["q25"]) if r else 0.0 for r in rows])
            hi = np.array([100 * (r["q75"] - r["median"]) if r else 0.0 for r in rows])
            ax.bar(x + (j - (len(pipelines) - 1) / 2) * width, med, width, yerr=[lo, hi], capsize=3, label=pipeline)
        ax.set_xticks(x, settings)
        ax.set_ylabel(f"{metric.replace('_', '-')} rate (%)")
        ax.set_ylim(0, 105)
        ax.set_title(f"Ego {metric.replace('_', '-')} rate: median and IQR over seeds")
        ax.legend(fontsize=8, ncol=min(len(pipelines), 4))
        path = save_figure(fig, out / f"bars_{metric}.png")
        paths.append(path)
    return paths


def read_progress(path: Path) -> dict[str, np.ndarray]:
    """Numeric columns of an SB3 ``progress.csv`` (empty cells -> NaN)."""
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    cols: dict[str, np.ndarray] = {}
    for key in rows[0] if rows else []:
        values = []
        for r in rows:
            try:
                values.append(float(r[key]) if r[key] not in ("", None) else math.nan)
            except ValueError:
                break
        else:
            cols[key] = np.array(values)
    return cols


def plot_training_curves(runs: Sequence[Mapping[str, Any]], path: Path) -> Path | None:
    """Training curves of every run with a ``progress.csv`` (one line per run, coloured by pipeline; one panel
    per `CURVE_COLUMNS` entry found); None when no run has one."""
    curves = []
    for run in runs:
        if run.get("path") and (Path(run["path"]) / "progress.csv").is_file():
            cols = read_progress(Path(run["path"]) / "progress.csv")
            if CURVE_X in cols:
                curves.append((run, cols))
    if not curves:
        return None
    panels = [c for c in CURVE_COLUMNS if any(_match(cols, c) for _, cols in curves)]
    if not panels:
        return None
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4), squeeze=False)
    colors = {p: f"C{i}" for i, p in enumerate(ordered_pipelines(r["pipeline"] for r, _ in curves))}
    for ax, panel in zip(axes[0], panels, strict=True):
        labelled = set()
        for run, cols in curves:
            key = _match(cols, panel)
            if key is None:
                continue
            ok = np.isfinite(cols[key]) & np.isfinite(cols[CURVE_X])
            label = run["pipeline"] if run["pipeline"] not in labelled else None
            labelled.add(run["pipeline"])
            ax.plot(cols[CURVE_X][ok], cols[key][ok], color=colors[run["pipeline"]], alpha=0.8, label=label)
        ax.set_xlabel("environment steps")
        ax.set_title(panel)
        ax.legend(fontsize=8)
    return save_figure(fig, path)


def _match(cols: Mapping[str, np.ndarray], name: str) -> str | None:
    """``name`` if it has values, else the first column ending with ``/<last part of name>`` that has."""
    tail = "/" + name.rsplit("/", 1)[-1]
    for key in sorted(cols, key=lambda k: k != name):
        if (key == name or key.endswith(tail)) and np.isfinite(cols[key]).any():
            return key
    return None


def render_generator_videos(
    rows: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]], settings_info: Sequence[Mapping[str, Any]],
    out: Path, per_generator: int = 1, fmt: str = "mp4", progress: bool = True,
) -> list[Path]:
    """For every generator setting, ``per_generator`` videos of its scored pass against one ego (the first
    trained run, else the Replay ego, else another built-in ego), preferring scenarios where the ego crashed;
    re-simulated with the same seeds, generator kwargs, K and background as the evaluation
    (`seal.experiments.evaluation.replay_episode.play`;
    `ScenarioEnv` config overrides of the evaluation are not recorded, the default env is used)."""
    from tqdm import tqdm

    from seal.envs.render import render_rollout, write_video
    from seal.experiments.evaluation.replay_episode import EpisodeSpec, EpisodeSpecError, play
    from seal.experiments.training.egos import make_ego

    if fmt not in ("mp4", "gif"):
        raise ValueError(f"--video-format must be mp4 or gif, got {fmt!r}")
    trained = [r for r in runs if r.get("path")]
    builtin = sorted((r for r in runs if not r.get("path")), key=lambda r: r["run"] != "replay")
    if not (trained or builtin):
        return []
    ego_run = trained[0] if trained else builtin[0]
    policy = make_ego(ego_run["path"] or ego_run["run"])
    paths = []
    gen_settings = [s for s in settings_info if s["kind"] == "generator"]
    for s in tqdm(gen_settings, desc="videos", unit="generator", disable=not progress):
        eps = [r for r in rows if r["run"] == ego_run["run"] and r.get("setting_name", r["setting"]) == s["setting"]
               and r["dataset"] == s["dataset"]]
        if not eps:
            continue
        # failures first (crash, then any other), never a success before an off-road episode
        eps.sort(key=lambda r: (not r["crash"], r["outcome"] == "success", not r["adv_collision"], r["scenario_id"]))
        for ep in eps[:per_generator]:
            try:  # the episode as evaluated: same split index, seeds, generator options, K and background
                sc, rollout, _ = play(EpisodeSpec.of_setting(s, ep["scenario_id"], policy))
            except EpisodeSpecError:
                continue
            name = f"{s['setting']}_{Path(ego_run['run']).name}_{sc.scenario_id}.{fmt}"
            frames = render_rollout(rollout, sc.road, sc, adversary_label=f"{s['setting']} (pass {s['k']} of {s['k']})",
                                    ego_label=Path(str(ego_run["run"])).name)
            paths.append(write_video(frames, out / name))
    return paths


def save_figure(fig: Any, path: Path) -> Path:
    """Lay out ``fig``, write it to ``path`` (110 dpi, parent folders created) and close it; returns ``path``."""
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path
