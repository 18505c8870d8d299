"""Figures of a scored dataset (matplotlib, Agg, no display needed): score distributions, feature correlations
and renderings of top-scoring and median scenes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from seal.core.dataset import Dataset
from seal.core.road import RoadDescription
from seal.core.scenario import CURRENT_STEP, VALID, Scenario, X, Y
from seal.scoring.extrapolation import future_extrapolate
from seal.scoring.individual import INDIVIDUAL_FEATURES
from seal.scoring.scores import VARIANTS, road_index
from seal.scoring.social import SOCIAL_FEATURES
from seal.scoring.store import ScoreTable, load_scores
from seal.scoring.tracks import from_tracks

_COLORS = {"gt": "tab:blue", "fe": "tab:orange", "as": "tab:green", "ac": "tab:red"}
_LINE_STYLES = {"continuous": "-", "striped": "--", "none": None}


def write_report(dataset_dir: str | Path, out_dir: str | Path, n_scenes: int = 3) -> list[Path]:
    """Write the figures (PNG) and a small ``score_summary.json`` to ``out_dir``; return the written paths."""
    root, out = Path(dataset_dir), Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    table = load_scores(root)
    paths = [plot_distributions(table, out / "score_distributions.png"),
             plot_correlations(table, out / "feature_correlation.png")]
    ac = table.scene("ac")
    order = np.argsort(-ac, kind="stable")
    top = order[:n_scenes].tolist()
    median_rank = len(order) // 2
    med = order[max(0, median_rank - n_scenes // 2): max(0, median_rank - n_scenes // 2) + n_scenes].tolist()
    ids = table.scenario_ids
    wanted = {ids[k] for k in top + med}
    scenarios = {s.scenario_id: s for s in Dataset.open(root).load(ids=wanted)}
    for tag, ks in (("top", top), ("median", med)):
        for rank, k in enumerate(ks, start=1):
            path = out / f"scene_{tag}{rank}_{ids[k]}.png"
            paths.append(plot_scene(scenarios[ids[k]], {v: float(table.scene(v)[k]) for v in VARIANTS}, path))
    summary = {
        "n_scenarios": len(table),
        "top": [{"id": ids[k], "ac": float(ac[k])} for k in top],
        "median": [{"id": ids[k], "ac": float(ac[k])} for k in med],
        "quantiles": {v: dict(zip(("p50", "p80", "p95", "p99"),
                                  np.quantile(table.scene(v), [0.5, 0.8, 0.95, 0.99]).round(3).tolist(), strict=True))
                      for v in VARIANTS},
    }
    summary_path = out / "score_summary.json"
    summary_path.write_text(json.dumps(summary, indent=2) + "\n")
    return [*paths, summary_path]


def plot_distributions(table: ScoreTable, path: Path) -> Path:
    """Histogram (log counts) and survival function (log) of the scene scores of every variant."""
    fig = Figure(figsize=(11, 4.2))
    ax_h, ax_s = fig.subplots(1, 2)
    hi = max(float(np.max(table.scene(v))) for v in VARIANTS)
    bins = np.linspace(0.0, hi * 1.01 + 1e-9, 60)
    for v in VARIANTS:
        x = np.sort(table.scene(v))
        ax_h.hist(x, bins=bins, histtype="step", lw=1.5, color=_COLORS[v], label=v.upper())
        ax_s.step(x, 1.0 - np.arange(x.size) / x.size, where="post", color=_COLORS[v], label=v.upper())
    thr = float(np.quantile(table.scene("ac"), 0.8))
    for ax in (ax_h, ax_s):
        ax.axvline(thr, color="k", ls=":", lw=1, label="AC 0.8 quantile")
        ax.set_yscale("log")
        ax.set_xlabel("scene score")
        ax.legend(fontsize=8)
    ax_h.set_ylabel("scenes")
    ax_h.set_title("scene score histogram")
    ax_s.set_ylabel("share of scenes with a larger score")
    ax_s.set_title("survival function (long tail)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def _corr(x: np.ndarray) -> np.ndarray:
    x = x - x.mean(0)
    std = x.std(0)
    c = (x.T @ x) / x.shape[0] / np.maximum(np.outer(std, std), 1e-12)
    c[std < 1e-12, :] = np.nan  # a constant feature has no correlation
    c[:, std < 1e-12] = np.nan
    return c


def plot_correlations(table: ScoreTable, path: Path) -> Path:
    """Pearson correlation heat-maps of the individual (agents) and social (active GT pairs) features."""
    a = table.arrays
    ind = a["ind_features_gt"].astype(np.float64)
    soc = a["soc_features_gt"][a["pair_active_gt"]].astype(np.float64)
    # Inverse times and DRAC have a huge range (the score caps them): correlate the capped values.
    soc = np.minimum(soc, np.array([2.0, 2.0, 10.0, 4.0, 4.0, np.inf, np.inf]))
    fig = Figure(figsize=(12, 5.2))
    for ax, x, names, title in zip(
        fig.subplots(1, 2), (ind, soc), (INDIVIDUAL_FEATURES, SOCIAL_FEATURES),
        (f"individual features ({ind.shape[0]} agents)", f"social features ({soc.shape[0]} active pairs)"),
        strict=True,
    ):
        c = _corr(x) if x.shape[0] > 1 else np.full((len(names), len(names)), np.nan)
        im = ax.imshow(c, vmin=-1, vmax=1, cmap="coolwarm")
        ax.set_xticks(range(len(names)), names, rotation=45, ha="right", fontsize=8)
        ax.set_yticks(range(len(names)), names, fontsize=8)
        for (i, j), v in np.ndenumerate(c):
            if np.isfinite(v):
                ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=7)
        ax.set_title(title, fontsize=10)
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return path


def draw_road(ax, road: RoadDescription) -> None:
    """Lane borders (line types as styles) and dotted centre lines."""
    for lane in road.lanes:
        c = lane.centerline
        tang = np.gradient(c, axis=0)
        tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-12)
        normal = np.stack([-tang[:, 1], tang[:, 0]], axis=1)
        for side, kind in zip((1.0, -1.0), lane.line_types, strict=True):
            style = _LINE_STYLES[kind]
            if style is not None:
                b = c + side * 0.5 * lane.width_m * normal
                ax.plot(b[:, 0], b[:, 1], color="0.35", ls=style, lw=0.8 if kind == "striped" else 1.2)
        ax.plot(c[:, 0], c[:, 1], color="0.8", ls=":", lw=0.6)


def plot_scene(scenario: Scenario, scores: dict[str, float], path: Path) -> Path:
    """Road, all tracks (history thick, future thin; ego blue, adversary red) and the scene scores, framed on the
    ego and adversary (25 m around their tracks)."""
    tr = scenario.tracks
    valid = tr[:, :, VALID] > 0.5
    focal_xy = np.concatenate([tr[a][valid[a]][:, [X, Y]] for a in (scenario.ego_index, scenario.adv_index)])
    lo, hi = focal_xy.min(0) - 25.0, focal_xy.max(0) + 25.0
    span = hi - lo
    width_in = 10.0
    fig = Figure(figsize=(width_in, float(np.clip(width_in * span[1] / span[0], 3.0, 9.0)) + 0.8))
    ax = fig.subplots()
    draw_road(ax, scenario.road)
    focal = {scenario.ego_index: ("tab:blue", "ego"), scenario.adv_index: ("tab:red", "adversary")}
    steps = np.arange(tr.shape[1])
    for a in range(scenario.n_agents):
        xy = tr[a][:, [X, Y]]
        color, label = focal.get(a, ("0.45", None))
        lw = 2.0 if label else 1.0
        hist, fut = valid[a] & (steps <= CURRENT_STEP), valid[a] & (steps >= CURRENT_STEP)
        ax.plot(xy[hist, 0], xy[hist, 1], color=color, lw=lw + 1.5, alpha=0.9, zorder=3 if label else 2)
        ax.plot(xy[fut, 0], xy[fut, 1], color=color, lw=lw, alpha=0.9 if label else 0.6, label=label,
                zorder=3 if label else 2)
        if valid[a, CURRENT_STEP]:
            ax.plot(*xy[CURRENT_STEP], "o", color=color, ms=6 if label else 3, zorder=4)
    # The counterfactual (FE) futures of ego and adversary: what AS / AC score them on.
    index = road_index(scenario.road)
    fe = future_extrapolate(from_tracks(scenario.tracks, index), index)
    for a, (color, label) in focal.items():
        if valid[a, CURRENT_STEP]:
            xy = fe.pos[a, CURRENT_STEP:]
            ax.plot(xy[:, 0], xy[:, 1], color=color, ls=":", lw=1.5, zorder=3,
                    label=f"{label} extrapolated (FE)")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    ax.legend(loc="upper right", fontsize=8)
    txt = "  ".join(f"{v.upper()} {scores[v]:.2f}" for v in VARIANTS)
    ax.set_title(f"{scenario.scenario_id} ({scenario.layout}); thick = history, dot = current step\n"
                 f"scene scores: {txt}", fontsize=9)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    return path
