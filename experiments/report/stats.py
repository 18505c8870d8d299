"""Uncertainty of the ego comparison: bootstrap confidence intervals and the probability of improvement.

* `ego_ci_table`: per (pipeline, setting, metric) the mean over seeds of each seed's rate, with a 95 % percentile
  bootstrap interval from a two-level resampling (seeds with replacement, then each drawn seed's scenarios with
  replacement), so both the seed-to-seed and the scenario-to-scenario variation enter.
* `improvement_table`: the probability of improvement of a pipeline X over a reference Y (Agarwal et al. 2021,
  rliable): per setting ``P(X > Y) = mean over seed pairs (m, n) of 1[x_m > y_n] + 0.5 * 1[x_m = y_n]`` of the
  seeds' success rates, averaged over the settings both were evaluated on; its 95 % interval from a stratified
  bootstrap (each pipeline's seeds resampled per setting). References: each pipeline's base in the registry
  (`seal.adversaries.base.GeneratorSpec.base`, e.g. ``cat`` for ``cat-rcg``) and ``noadv``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from seal.adversaries.base import NO_ADVERSARY, generator_spec
from seal.experiments.report.compare import EGO_METRICS, ordered_pipelines, ordered_settings, setting_label

N_BOOT = 2000
ALPHA = 0.05


def _outcomes(rows: Sequence[Mapping[str, Any]], metric: str) -> dict[tuple[str, str], dict[str, np.ndarray]]:
    """``{(pipeline, setting): {run: [episodes] 0/1 outcomes of metric}}``."""
    out: dict[tuple[str, str], dict[str, list[float]]] = {}
    for r in rows:
        out.setdefault((r["pipeline"], r["setting"]), {}).setdefault(r["run"], []).append(float(bool(r[metric])))
    return {k: {run: np.asarray(v) for run, v in runs.items()} for k, runs in out.items()}


def bootstrap_mean_ci(runs: Sequence[np.ndarray], n_boot: int = N_BOOT, seed: int = 0, alpha: float = ALPHA
                      ) -> tuple[float, float, float]:
    """``(mean over runs of the run means, low, high)``: two-level percentile bootstrap (runs, then episodes)."""
    if not runs:
        return math.nan, math.nan, math.nan
    rng = np.random.default_rng(seed)
    point = float(np.mean([r.mean() for r in runs]))
    stats = np.empty(n_boot)
    for b in range(n_boot):
        picked = rng.integers(len(runs), size=len(runs))
        stats[b] = np.mean([runs[i][rng.integers(runs[i].size, size=runs[i].size)].mean() for i in picked])
    lo, hi = np.quantile(stats, [alpha / 2, 1 - alpha / 2])
    return point, float(lo), float(hi)


def ego_ci_table(rows: Sequence[Mapping[str, Any]], n_boot: int = N_BOOT, seed: int = 0) -> list[dict[str, Any]]:
    """One row per (pipeline, setting, metric): ``mean``, ``ci_low``, ``ci_high`` (rates in [0, 1]), ``seeds``."""
    table = []
    for metric in EGO_METRICS:
        outcomes = _outcomes(rows, metric)
        for pipeline in ordered_pipelines(p for p, _ in outcomes):
            for setting in ordered_settings(s for p, s in outcomes if p == pipeline):
                runs = list(outcomes[(pipeline, setting)].values())
                mean, lo, hi = bootstrap_mean_ci(runs, n_boot, seed)
                table.append({"pipeline": pipeline, "setting": setting_label(setting), "metric": metric,
                              "seeds": len(runs), "mean": mean, "ci_low": lo, "ci_high": hi})
    return table


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """``P(X > Y)`` over all pairs of the samples ``x [m]``, ``y [n]`` (ties count one half)."""
    x, y = np.asarray(x, dtype=np.float64)[:, None], np.asarray(y, dtype=np.float64)[None]
    return float(((x > y) + 0.5 * (x == y)).mean())


def average_poi(x_tasks: Sequence[np.ndarray], y_tasks: Sequence[np.ndarray], n_boot: int = N_BOOT, seed: int = 0,
                alpha: float = ALPHA) -> tuple[float, float, float]:
    """Mean over tasks of `probability_of_improvement` and its stratified-bootstrap interval."""
    point = float(np.mean([probability_of_improvement(x, y) for x, y in zip(x_tasks, y_tasks, strict=True)]))
    rng = np.random.default_rng(seed)
    stats = np.empty(n_boot)
    for b in range(n_boot):
        stats[b] = np.mean([probability_of_improvement(x[rng.integers(x.size, size=x.size)],
                                                       y[rng.integers(y.size, size=y.size)])
                            for x, y in zip(x_tasks, y_tasks, strict=True)])
    lo, hi = np.quantile(stats, [alpha / 2, 1 - alpha / 2])
    return point, float(lo), float(hi)


def references(pipeline: str) -> list[str]:
    """What ``pipeline`` is compared with: its registry base (if any), then ``noadv``."""
    spec = generator_spec(pipeline)
    refs = [spec.base] if spec is not None and spec.base else []
    return [r for r in refs if r != pipeline] + ([NO_ADVERSARY] if pipeline != NO_ADVERSARY else [])


def improvement_table(rows: Sequence[Mapping[str, Any]], n_boot: int = N_BOOT, seed: int = 0
                      ) -> list[dict[str, Any]]:
    """One row per (pipeline, reference) evaluated on common settings: average probability of improvement in
    success rate over those settings, its interval, the settings and the seeds on each side."""
    success = _outcomes(rows, "success")
    rates = {k: np.array([v.mean() for v in runs.values()]) for k, runs in success.items()}
    pipelines = ordered_pipelines(p for p, _ in rates)
    table = []
    for pipeline in pipelines:
        for ref in references(pipeline):
            settings = [s for s in ordered_settings(s for p, s in rates if p == pipeline) if (ref, s) in rates]
            if not settings:
                continue
            x = [rates[(pipeline, s)] for s in settings]
            y = [rates[(ref, s)] for s in settings]
            poi, lo, hi = average_poi(x, y, n_boot, seed)
            table.append({"pipeline": pipeline, "reference": ref, "settings": len(settings),
                          "seeds": int(x[0].size), "reference_seeds": int(y[0].size),
                          "p_improvement": poi, "ci_low": lo, "ci_high": hi})
    return table


def ci_markdown(table: Sequence[Mapping[str, Any]], metric: str = "success") -> str:
    """Pipelines x settings, cells ``mean % [low-high]`` of ``metric``."""
    rows = [r for r in table if r["metric"] == metric]
    settings = list(dict.fromkeys(r["setting"] for r in rows))
    out = ["| pipeline | " + " | ".join(settings) + " |", "|---|" + "---:|" * len(settings)]
    for pipeline in dict.fromkeys(r["pipeline"] for r in rows):
        cells = {r["setting"]: r for r in rows if r["pipeline"] == pipeline}
        out.append(f"| {pipeline} | " + " | ".join(
            f"{100 * c['mean']:.1f} [{100 * c['ci_low']:.1f}-{100 * c['ci_high']:.1f}]" if (c := cells.get(s))
            else "-" for s in settings) + " |")
    return "\n".join(out) + "\n"


def improvement_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    out = ["| pipeline | over | settings | seeds | P(improvement) [95 % CI] |", "|---|---|---:|---:|---:|"]
    for r in table:
        out.append(f"| {r['pipeline']} | {r['reference']} | {r['settings']} | {r['seeds']} vs "
                   f"{r['reference_seeds']} | {r['p_improvement']:.2f} [{r['ci_low']:.2f}-{r['ci_high']:.2f}] |")
    return "\n".join(out) + "\n"
