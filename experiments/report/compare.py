"""``seal compare``: the thesis-style tables from the results store, as Markdown and CSV.

* Table 6.1 (`ego_table`): per training pipeline and setting, the median and interquartile range (25th-75th
  percentile, linear interpolation) over seeds of the ego's success / crash / out-of-road rate; each seed's
  rate is over the scenarios of that setting. The Replay ego appears as pipeline ``replay``.
* Table 6.2 (`generator_table`): per generator setting (plus ``normal`` as the replayed-log reference and
  ``normal-reactive``, the same with reacting background traffic, where evaluated), the ego
  success / crash rates averaged over the evaluated egos (each ego's rate over scenarios, then the mean), the
  adversary-collision and close-call rates, the realism Wasserstein distances of the pooled episodes' adversary
  against the logged adversaries (yaw rate, acceleration, out-of-road rate, their mean), the mean collision
  speed along the contact normal (m/s, over episodes with an ego-adversary contact), head-on and severe
  head-on rates (of all episodes) and the mean generation time per call.

Plots and videos are in `seal.experiments.report.compare_plots`; `seal.experiments.report.write.write_report`
writes everything into one folder.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.adversaries.base import pipeline_names
from seal.experiments.evaluation.evaluate import REAL_PREFIX, REPLAY_SETTINGS
from seal.experiments.evaluation.generator_metrics import format_markdown_table
from seal.experiments.evaluation.metrics import pooled_realism
from seal.experiments.report.grouping import (
    algo_of,
    base_pipeline,
    ego_groups,
    group_heading,
    groups_in,
    in_group,
    tag_by_group,
)

EGO_METRICS = ("success", "crash", "out_of_road")
PIPELINE_ORDER = ("replay", "heuristic", *pipeline_names())
"""Report order: the built-in egos, then the training pipelines in registry order (`seal.adversaries.base`)."""


def setting_label(setting: str) -> str:
    """Short display name: ``real:/a/b/ngsim`` -> ``real:ngsim``."""
    if setting.startswith(REAL_PREFIX):
        return REAL_PREFIX + Path(setting[len(REAL_PREFIX):]).name
    return setting


def ordered_settings(settings: Iterable[str]) -> list[str]:
    """normal, hard, then generator settings (alphabetical), then real-data settings."""
    from seal.experiments.report.grouping import base_setting

    unique = set(settings)

    def rank(s: str) -> tuple[int, str]:
        if base_setting(s) in REPLAY_SETTINGS:  # normal@pool ranks as normal
            return (REPLAY_SETTINGS.index(base_setting(s)), s)
        return (3 if s.startswith(REAL_PREFIX) else 2, s)

    return sorted(unique, key=rank)


def ordered_pipelines(pipelines: Iterable[str]) -> list[str]:
    """Registry order (`PIPELINE_ORDER`), unknown names after it alphabetically; labels ``<pipeline> (<algo>)``
    (`seal.experiments.report.grouping`) sort by their pipeline, then by algorithm."""

    def rank(label: str) -> tuple[int, str, str]:
        base = base_pipeline(label)
        return (PIPELINE_ORDER.index(base) if base in PIPELINE_ORDER else len(PIPELINE_ORDER), base, algo_of(label))

    return sorted(set(pipelines), key=rank)


def quartiles(values: Sequence[float]) -> tuple[float, float, float]:
    """(25th percentile, median, 75th percentile) with linear interpolation; NaNs if empty."""
    if not values:
        return (math.nan, math.nan, math.nan)
    q25, q50, q75 = np.percentile(np.asarray(values, dtype=np.float64), [25, 50, 75])
    return float(q25), float(q50), float(q75)


def per_run_rates(rows: Sequence[Mapping[str, Any]]) -> dict[tuple[str, str], dict[str, dict[str, float]]]:
    """``{(pipeline, setting): {run: {metric: rate, "scenarios": n}}}`` with each run's rates over scenarios."""
    groups: dict[tuple[str, str], dict[str, list[Mapping[str, Any]]]] = {}
    for r in rows:
        groups.setdefault((r["pipeline"], r["setting"]), {}).setdefault(r["run"], []).append(r)
    out: dict[tuple[str, str], dict[str, dict[str, float]]] = {}
    for key, runs in groups.items():
        out[key] = {
            run: {**{m: float(np.mean([bool(e[m]) for e in eps])) for m in EGO_METRICS}, "scenarios": len(eps)}
            for run, eps in runs.items()
        }
    return out


def ego_table(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Table 6.1 in long form: one row per (pipeline, setting, metric) with ``seeds`` (runs), ``scenarios``
    (episodes in all), ``median``, ``q25``, ``q75``, ``iqr`` (rates in [0, 1])."""
    rates = per_run_rates(rows)
    table = []
    for pipeline in ordered_pipelines(p for p, _ in rates):
        for setting in ordered_settings(s for p, s in rates if p == pipeline):
            runs = rates[(pipeline, setting)]
            for metric in EGO_METRICS:
                q25, med, q75 = quartiles([r[metric] for r in runs.values()])
                table.append({
                    "pipeline": pipeline, "setting": setting_label(setting), "metric": metric,
                    "seeds": len(runs), "scenarios": int(sum(r["scenarios"] for r in runs.values())),
                    "median": med, "q25": q25, "q75": q75, "iqr": q75 - q25,
                })
    return table


def ego_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """Table 6.1 as Markdown: a block per metric, pipelines as rows, settings as columns, cells
    ``median % [q25-q75] (n)``, n the scored episodes of the cell (all seeds)."""
    out = []
    settings = list(dict.fromkeys(r["setting"] for r in table))
    settings = [setting_label(s) for s in ordered_settings(settings)] if settings else []
    for metric in EGO_METRICS:
        out.append(f"### {metric.replace('_', '-')} rate (median [IQR] over seeds)\n")
        out.append("| pipeline | seeds | " + " | ".join(settings) + " |")
        out.append("|---|---:|" + "---:|" * len(settings))
        for pipeline in dict.fromkeys(r["pipeline"] for r in table):
            cells = {r["setting"]: r for r in table if r["pipeline"] == pipeline and r["metric"] == metric}
            seeds = max((r["seeds"] for r in cells.values()), default=0)
            line = [_pct_cell(cells.get(s)) for s in settings]
            out.append(f"| {pipeline} | {seeds} | " + " | ".join(line) + " |")
        out.append("")
    return "\n".join(out)


def _pct_cell(row: Mapping[str, Any] | None) -> str:
    if row is None or not math.isfinite(row["median"]):
        return "-"
    return f"{100 * row['median']:.1f} [{100 * row['q25']:.1f}-{100 * row['q75']:.1f}] ({row['scenarios']})"


def generator_table(rows: Sequence[Mapping[str, Any]], settings_info: Sequence[Mapping[str, Any]] = ()
                    ) -> list[dict[str, Any]]:
    """Table 6.2: one row per generator setting (and ``normal`` as reference) over all egos in ``rows``
    (histogram columns decoded). ``settings_info`` (the store's settings rows) marks generator settings; without
    it, any setting not normal / hard / real:... counts as a generator."""
    from seal.experiments.report.grouping import base_setting

    generators = {s["setting"] for s in settings_info if s.get("kind") == "generator"}
    by_setting: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        by_setting.setdefault(r["setting"], []).append(r)
    table = []
    for setting in ordered_settings(by_setting):
        base = base_setting(setting)  # the stored name of a setting relabelled `setting@dataset`
        is_generator = base in generators or (
            not settings_info and base not in REPLAY_SETTINGS and not setting.startswith(REAL_PREFIX)
        )
        if not (is_generator or base in ("normal", "normal-reactive")):
            continue
        eps = by_setting[setting]
        per_run: dict[str, list[Mapping[str, Any]]] = {}
        for e in eps:
            per_run.setdefault(e["run"], []).append(e)
        speeds = [e["collision_speed_mps"] for e in eps if e["collision_speed_mps"] is not None]
        gen_ms = [e["generation_ms_mean"] for e in eps if e["generation_ms_mean"] is not None]
        n = len(eps)
        table.append({
            "setting": setting_label(setting),
            "egos": len(per_run),
            "episodes": n,
            "ego_success": float(np.mean([np.mean([bool(e["success"]) for e in v]) for v in per_run.values()])),
            "ego_crash": float(np.mean([np.mean([bool(e["crash"]) for e in v]) for v in per_run.values()])),
            "adv_collision_rate": sum(bool(e["adv_collision"]) for e in eps) / n,
            "close_call_rate": sum(bool(e["close_call"]) for e in eps) / n,
            **(realism := pooled_realism([dict(e) for e in eps])),
            # Thesis Table 7.6: yaw and acceleration only (out-of-road adversaries are common in real crashes).
            "realism_yaw_acc": float(np.nanmean([realism["yaw_wd"], realism["acc_wd"]])),
            # The other reading of "profiles derived from the original X_adv in s" (thesis 6.4.3): each episode's
            # own WDs to its scenario's logged adversary, averaged over episodes (short tracks: larger values).
            "realism_yaw_acc_per_scenario": _per_episode_yaw_acc(eps),
            "collision_speed_mps": float(np.mean(speeds)) if speeds else math.nan,
            "head_on_rate": sum(bool(e["head_on"]) for e in eps) / n,
            "severe_head_on_rate": sum(bool(e["severe_head_on"]) for e in eps) / n,
            "generation_ms_mean": float(np.mean(gen_ms)) if gen_ms else math.nan,
        })
    return table


def generator_table_by_group(ego_rows: Sequence[Mapping[str, Any]], settings_info: Sequence[Mapping[str, Any]] = ()
                             ) -> list[dict[str, Any]]:
    """`generator_table` over all egos and, when the rows are labelled with several ego algorithms, against each
    algorithm's egos apart (`seal.experiments.report.grouping.ego_groups`); each row says which in ``ego_group``."""
    return tag_by_group(ego_groups(ego_rows), lambda rows: generator_table(rows, settings_info))


def _per_episode_yaw_acc(eps: Sequence[Mapping[str, Any]]) -> float:
    """Mean over ``eps`` of each episode's mean of its yaw and acceleration WDs (NaN without any)."""
    values = [(float(e["yaw_wd"]) + float(e["acc_wd"])) / 2 for e in eps
              if e.get("yaw_wd") is not None and e.get("acc_wd") is not None]
    values = [v for v in values if math.isfinite(v)]
    return float(np.mean(values)) if values else math.nan


GENERATOR_COLUMNS = (
    ("setting", "generator", "{}"),
    ("egos", "egos", "{}"),
    ("episodes", "episodes", "{}"),
    ("ego_success", "ego success", "{:.1%}"),
    ("ego_crash", "ego crash", "{:.1%}"),
    ("adv_collision_rate", "adv. collision", "{:.1%}"),
    ("close_call_rate", "close call", "{:.1%}"),
    ("yaw_wd", "yaw WD", "{:.3f}"),
    ("acc_wd", "acc WD", "{:.3f}"),
    ("road_wd", "road WD", "{:.3f}"),
    ("realism", "realism (mean WD)", "{:.3f}"),
    ("realism_yaw_acc", "yaw+acc WD", "{:.3f}"),
    ("realism_yaw_acc_per_scenario", "yaw+acc WD per scenario", "{:.3f}"),
    ("hard_brake_share", "hard brake (< -3 m/s^2)", "{:.1%}"),
    ("logged_hard_brake_share", "logged hard brake", "{:.1%}"),
    ("collision_speed_mps", "coll. speed (m/s)", "{:.2f}"),
    ("head_on_rate", "head-on", "{:.1%}"),
    ("severe_head_on_rate", "severe head-on", "{:.1%}"),
    ("generation_ms_mean", "gen. ms", "{:.1f}"),
)


def generator_markdown(table: Sequence[Mapping[str, Any]]) -> str:
    """Table 6.2 as Markdown; a table built per ego group (`seal.experiments.report.grouping.ego_groups`, key
    ``ego_group``) as one table per group under its heading."""
    groups = groups_in(table)
    if len(groups) < 2:
        return format_markdown_table(table, GENERATOR_COLUMNS)
    return "\n".join(group_heading(g, len(groups)) + "\n" + format_markdown_table(in_group(table, g), GENERATOR_COLUMNS)
                     for g in groups)


def to_csv(rows: Sequence[Mapping[str, Any]]) -> bytes:
    buf = io.StringIO()
    fields = list(dict.fromkeys(k for r in rows for k in r))
    writer = csv.DictWriter(buf, fieldnames=fields, restval="", lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()})
    return buf.getvalue().encode()
