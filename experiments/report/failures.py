"""Where and why egos fail: outcome shares with timeouts and route completion, per-layout and per-source
breakdowns, and the list of failed scenarios per ego and setting with the reason.

Every share here is over the scored episodes of a group (all seeds of a pipeline pooled; ``n`` says how many),
so the four outcome shares of a row add up to 100 %. The layout and source of a scenario come from its dataset
(`seal.core.dataset.scenario_facts`): the layout of generated scenarios (highway, merge, ...) and of imported ones
(the recording's location), the source the recording file of imported scenarios.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.experiments.evaluation.generator_metrics import format_markdown_table

OUTCOMES = ("success", "crash", "out_of_road", "timeout")
FAILURE_KINDS = ("crash", "out_of_road", "timeout")
FAILURES_SHOWN = 10
"""Failed scenarios listed per ego and setting in the failure listing (failures.csv has them all)."""
INLINE_FAILURE_EGOS = 6
"""Egos up to which report.md lists each ego's failures itself; above, report.md has the per-pipeline summary and
the listing goes to failures.md (57 egos x 10 settings would be ~6,000 table lines on the report's page)."""

Facts = Mapping[str, Mapping[str, Mapping[str, str]]]
"""dataset path -> scenario id -> {"layout", "source"}."""


def load_facts(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, dict[str, str]]]:
    """`seal.core.dataset.scenario_facts` of every dataset in ``rows`` (a dataset that no longer opens gets
    none: its scenarios show as layout ``?``)."""
    from seal.core.dataset import scenario_facts
    from seal.core.errors import SealError

    facts: dict[str, dict[str, dict[str, str]]] = {}
    for dataset in sorted({r["dataset"] for r in rows}):
        try:
            facts[dataset] = scenario_facts(dataset)
        except (SealError, OSError, ValueError):
            facts[dataset] = {}
    return facts


def fact(facts: Facts, row: Mapping[str, Any], key: str) -> str:
    return str(facts.get(row["dataset"], {}).get(row["scenario_id"], {}).get(key, "?"))


def _shares(eps: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    return {
        "n": len(eps), **{o: float(np.mean([e["outcome"] == o for e in eps])) for o in OUTCOMES},
        "route_completion": float(np.mean([e["route_completion"] for e in eps])),
    }


def outcome_table(rows: Sequence[Mapping[str, Any]], facts: Facts | None = None, by: str | None = None
                  ) -> list[dict[str, Any]]:
    """One row per (pipeline, setting[, ``by``]) with ``n`` episodes, the share of each outcome and the mean
    route completion; ``by``: ``layout`` or ``source`` (needs ``facts``)."""
    from seal.experiments.report.compare import ordered_pipelines, ordered_settings, setting_label

    groups: dict[tuple[str, str, str], list[Mapping[str, Any]]] = {}
    for r in rows:
        extra = fact(facts or {}, r, by) if by else ""
        groups.setdefault((r["pipeline"], r["setting"], extra), []).append(r)
    table = []
    for pipeline in ordered_pipelines(p for p, _, _ in groups):
        for setting in ordered_settings(s for p, s, _ in groups if p == pipeline):
            for extra in sorted(x for p, s, x in groups if p == pipeline and s == setting):
                head = {"pipeline": pipeline, "setting": setting_label(setting)}
                if by:
                    head[by] = extra
                table.append({**head, **_shares(groups[(pipeline, setting, extra)])})
    return table


def outcome_markdown(table: Sequence[Mapping[str, Any]], by: str | None = None) -> str:
    columns = [("pipeline", "pipeline", "{}"), ("setting", "setting", "{}")]
    if by:
        columns.append((by, by, "{}"))
    columns += [("n", "n", "{}"), ("success", "success", "{:.1%}"), ("crash", "crash", "{:.1%}"),
                ("out_of_road", "out of road", "{:.1%}"), ("timeout", "timeout", "{:.1%}"),
                ("route_completion", "route completion", "{:.1%}")]
    return format_markdown_table(table, tuple(columns))


def reason(row: Mapping[str, Any]) -> str:
    """Why an episode failed, in words: the outcome, whom the ego hit, how far along the route it got."""
    completion = f"{100 * float(row['route_completion']):.0f} % of the route"
    if row["outcome"] == "crash":
        whom = "the adversary" if row.get("adv_collision") else "other traffic"
        return f"crashed into {whom} at {completion}"
    if row["outcome"] == "out_of_road":
        return f"left the road at {completion}"
    gap = row.get("min_gap_m")
    near = f"; closest gap to the adversary {gap:.1f} m" if isinstance(gap, float) and math.isfinite(gap) else ""
    return f"timed out at {completion}{near}"


def failure_list(rows: Sequence[Mapping[str, Any]], facts: Facts | None = None) -> list[dict[str, Any]]:
    """Every failed episode (outcome not success), ordered by ego, setting, kind and scenario, with its layout,
    source and `reason`."""
    from seal.experiments.report.compare import setting_label

    failed = [r for r in rows if r["outcome"] != "success"]
    failed.sort(key=lambda r: (r["pipeline"], str(r["run"]), r["setting"], FAILURE_KINDS.index(r["outcome"])
                               if r["outcome"] in FAILURE_KINDS else 9, r["scenario_id"]))
    return [{
        "pipeline": r["pipeline"], "ego": _ego_label(r), "run": r["run"], "setting": setting_label(r["setting"]),
        "scenario_id": r["scenario_id"], "layout": fact(facts or {}, r, "layout"),
        "source": fact(facts or {}, r, "source"), "outcome": r["outcome"], "dataset": r["dataset"],
        "setting_name": r.get("setting_name", r["setting"]),
        "route_completion": float(r["route_completion"]), "reason": reason(r),
        "crashed_into": ("adversary" if r.get("adv_collision") else "other") if r["outcome"] == "crash" else "",
    } for r in failed]


def _ego_label(row: Mapping[str, Any]) -> str:
    run = str(row["run"])
    return run if "/" not in run else f"{row['pipeline']} ({Path(run).name})"


def failures_markdown(failures: Sequence[Mapping[str, Any]], rows: Sequence[Mapping[str, Any]],
                      shown: int = FAILURES_SHOWN, videos: Mapping[tuple[str, str, str], str] | None = None) -> str:
    """Per ego and setting: how many of its scenarios failed of each kind, then the first ``shown`` failures
    with layout and reason (a link where a video of it exists: ``videos[(run, setting, scenario_id)]``)."""
    from seal.experiments.report.compare import setting_label

    totals: dict[tuple[str, str], int] = {}
    for r in rows:
        key = (str(r["run"]), setting_label(r["setting"]))
        totals[key] = totals.get(key, 0) + 1
    groups: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for f in failures:
        groups.setdefault((str(f["run"]), f["setting"]), []).append(f)
    out = []
    for (run, setting), items in groups.items():
        kinds = ", ".join(f"{sum(i['outcome'] == k for i in items)} {k.replace('_', '-')}" for k in FAILURE_KINDS)
        out.append(f"**{items[0]['ego']}**, `{setting}`: {len(items)} of {totals.get((run, setting), 0)} "
                   f"scenarios failed ({kinds})\n")
        out.append("| scenario | layout | outcome | reason | video |")
        out.append("|---|---|---|---|---|")
        for i in items[:shown]:
            video = (videos or {}).get((run, setting, i["scenario_id"]))
            link = f"[video]({video})" if video else ""
            out.append(f"| {i['scenario_id']} | {i['layout']} | {i['outcome'].replace('_', '-')} | {i['reason']} "
                       f"| {link} |")
        if len(items) > shown:
            out.append(f"\n... and {len(items) - shown} more (failures.csv)")
        out.append("")
    return "\n".join(out) if out else "(no failures)\n"


def failure_summary_markdown(failures: Sequence[Mapping[str, Any]], rows: Sequence[Mapping[str, Any]]) -> str:
    """Per pipeline and setting (seeds pooled): failed episodes of all scored ones, split into crashes into the
    adversary, crashes into other traffic, out-of-road and timeouts (counts)."""
    from seal.experiments.report.compare import ordered_pipelines, setting_label

    totals: dict[tuple[str, str], int] = {}
    for r in rows:
        key = (r["pipeline"], setting_label(r["setting"]))
        totals[key] = totals.get(key, 0) + 1
    counts: dict[tuple[str, str], dict[str, int]] = {}
    for f in failures:
        kind = f"crash-{f['crashed_into']}" if f["outcome"] == "crash" else f["outcome"].replace("_", "-")
        cell = counts.setdefault((f["pipeline"], f["setting"]), {})
        cell[kind] = cell.get(kind, 0) + 1
    kinds = ("crash-adversary", "crash-other", "out-of-road", "timeout")
    out = ["| pipeline | setting | failed / episodes | " + " | ".join(kinds) + " |", "|---|---|---:|" + "---:|" * 4]
    rank = {p: i for i, p in enumerate(ordered_pipelines({p for p, _ in totals}))}
    for (p, setting), n in sorted(totals.items(), key=lambda item: rank[item[0][0]]):  # stable: settings as read
        c = counts.get((p, setting), {})
        out.append(f"| {p} | {setting} | {sum(c.values())} / {n} | " + " | ".join(str(c.get(k, 0)) for k in kinds)
                   + " |")
    return "\n".join(out) + "\n"
