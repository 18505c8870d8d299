"""How large a success difference the data allow: each training pipeline against the reference pipeline (No-Adv,
trained without an adversary), per setting and over all settings, in points with a 95 % interval.

A verdict of "not shown" (`seal.experiments.report.stats.poi_verdict`) says that no difference was found, not how
small the difference is. These intervals say that: a pipeline whose interval against No-Adv is [-2.1, +1.3] points
in a setting makes its egos neither more than 1.3 points better nor more than 2.1 worse there, as far as this run
can tell.

The interval is Welch's t interval (`scipy.stats.ttest_ind(equal_var=False).confidence_interval`) of the difference
of the two pipelines' mean per-seed success rates, each seed's rate taken over the scenarios both pipelines played
(so what is common to them, a scenario every ego fails, is the same on both sides); over all settings each seed's
rate is its mean over the settings (one ego plays them all). Why not a bootstrap of the seeds: with 4 seeds a side
it covers too little. Splitting each of the fifth decisive run's TD3 pipelines' 8 seeds 4 against 4 (35 splits x 7
pipelines, no true difference), a percentile bootstrap of the seeds put 0 outside its 95 % interval in 13.5 % of the
per-setting and 15.1 % of the all-settings differences, Welch's interval in 5.0 % and 5.3 %.
New scenarios of the same kind: the two pipelines play the same scenarios, so the scenario-to-scenario variation
mostly cancels in their difference, and what is left is already in each seed's rate. A paired crossed bootstrap
(scenarios drawn once for both pipelines and all their seeds, each pipeline's seeds drawn apart) gave median
half-widths of 2.8 / 4.8 points (ReSkill / TD3, every pipeline minus No-Adv in every setting of that run), Welch's
2.8 / 4.6; the scenario part alone 1.6 / 2.2. A single pipeline's rate is another matter
(`seal.experiments.report.stats`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats

from seal.experiments.report.agreement import ALL_SETTINGS
from seal.experiments.report.compare import ordered_pipelines, ordered_settings, setting_label
from seal.experiments.report.grouping import algo_of, base_pipeline, comparable
from seal.experiments.report.stats import CONFIDENCE, paired_outcomes, score_matrices

REFERENCE_PIPELINE = "noadv"
"""The pipeline every other is differenced against (trained on the logged scenarios alone)."""


def difference_interval(pairs: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float, float]:
    """``(difference, low, high)`` of the mean per-seed success rate X - R over the settings of ``pairs`` (per setting
    the outcomes ``x [scenarios, seeds_x]`` and ``r [scenarios, seeds_r]`` on the same scenarios; a seed column is
    the same ego in every setting), rates in [0, 1], with Welch's 95 % interval (module docstring) clipped to
    [-1, 1]; the interval is NaN with fewer than 2 seeds a side or no spread among the seeds."""
    x = np.mean([px.mean(axis=0) for px, _ in pairs], axis=0)  # each seed's rate, averaged over the settings
    r = np.mean([pr.mean(axis=0) for _, pr in pairs], axis=0)
    difference = float(x.mean() - r.mean())
    if min(len(x), len(r)) < 2 or (np.ptp(x) == 0 and np.ptp(r) == 0):
        return difference, math.nan, math.nan
    with warnings.catch_warnings():  # scipy warns of "catastrophic cancellation" when the two sides are equal
        warnings.simplefilter("ignore", RuntimeWarning)
        ci = stats.ttest_ind(x, r, equal_var=False).confidence_interval(CONFIDENCE)
    # a difference of two rates lies in [-1, 1]; with 2 seeds a side the t interval can reach far past it
    return difference, max(-1.0, float(ci.low)), min(1.0, float(ci.high))


def difference_table(rows: Sequence[Mapping[str, Any]], reference: str = REFERENCE_PIPELINE) -> list[dict[str, Any]]:
    """One row per trained pipeline X of an algorithm that has ``reference`` and per setting both played with
    their seeds, then one over those settings (``setting`` = `ALL_SETTINGS`, when X kept its seeds in all):
    ``pipeline``, ``reference`` (labels), ``setting``, ``seeds``, ``reference_seeds``, ``scenarios`` (summed over
    the settings), ``difference`` (X - reference, mean success rate) with ``low`` / ``high``."""
    matrices = score_matrices(rows)
    pipelines = ordered_pipelines({p for p, _ in matrices})
    out = []
    for ref in (p for p in pipelines if base_pipeline(p) == reference):
        for x in (p for p in pipelines if p != ref and comparable(p, ref)):
            settings = [s for s in ordered_settings(s for p, s in matrices if p == x) if (ref, s) in matrices]
            pairs = {s: paired_outcomes(matrices[(x, s)], matrices[(ref, s)]) for s in settings}
            pairs = {s: p for s, p in pairs.items() if p[0].shape[0]}
            for s, pair in pairs.items():
                out.append(_row(x, ref, setting_label(s), [pair]))
            same_egos = len({(matrices[(x, s)].runs, matrices[(ref, s)].runs) for s in pairs}) == 1
            if len(pairs) > 1 and same_egos:
                out.append(_row(x, ref, ALL_SETTINGS, list(pairs.values())))
    return out


def _row(x: str, ref: str, setting: str, pairs: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, Any]:
    d, low, high = difference_interval(pairs)
    return {"pipeline": x, "reference": ref, "setting": setting, "seeds": pairs[0][0].shape[1],
            "reference_seeds": pairs[0][1].shape[1], "scenarios": sum(p[0].shape[0] for p in pairs),
            "difference": d, "low": low, "high": high}


def _cell(r: Mapping[str, Any]) -> str:
    if not math.isfinite(r["low"]):
        return f"{100 * r['difference']:+.1f} [no spread]"
    return f"{100 * r['difference']:+.1f} [{100 * r['low']:+.1f}, {100 * r['high']:+.1f}]"


def difference_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """Per ego algorithm a matrix pipeline x setting of ``difference [low, high]`` in points."""
    out = []
    for ref in dict.fromkeys(r["reference"] for r in table):
        rows = [r for r in table if r["reference"] == ref]
        settings = list(dict.fromkeys(r["setting"] for r in rows))
        cells = {(r["pipeline"], r["setting"]): r for r in rows}
        out += [f"| minus {ref} | " + " | ".join(settings) + " |", "|---|" + "---:|" * len(settings)]
        for p in dict.fromkeys(r["pipeline"] for r in rows):
            out.append(f"| {p} | " + " | ".join(_cell(c) if (c := cells.get((p, s))) else "-" for s in settings)
                       + " |")
        out.append("")
    return "\n".join(out)


def bound_line(table: Sequence[Mapping[str, Any]], algo: str) -> str | None:
    """The first page's sentence for one ego algorithm: over all settings each pipeline's difference from the
    reference with its interval, and the range the per-setting intervals span; None without rows."""
    rows = [r for r in table if algo_of(r["pipeline"]) == algo]
    pooled = [r for r in rows if r["setting"] == ALL_SETTINGS]
    per_setting = [r for r in rows if r["setting"] != ALL_SETTINGS and math.isfinite(r["low"])]
    if not rows or not per_setting:
        return None
    ref = rows[0]["reference"]
    seeds = min(min(r["seeds"], r["reference_seeds"]) for r in rows)
    lows, highs = min(r["low"] for r in per_setting), max(r["high"] for r in per_setting)
    overall = ("; over all settings " + ", ".join(f"{base_pipeline(r['pipeline'])} {_cell(r)}" for r in pooled)
               if pooled else "")
    return (f"- How large a difference the data allow (success minus {ref}, points, Welch's 95 % intervals over the "
            f"seeds, here as few as {seeds} a pipeline): every pipeline's interval lies within {100 * lows:+.1f} to "
            f"{100 * highs:+.1f} in every setting{overall}.")
