"""The report's "where and why" part: outcome shares with timeouts and route completion, per-layout and per-source
breakdowns, the failures per ego and setting with videos of each kind, and the runs' periodic evaluation curves
(`seal.experiments.report.failures`, `failure_videos`, `eval_curves`). Written by
`seal.experiments.report.write.write_report` after the thesis tables."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_bytes
from seal.experiments.report.compare import to_csv
from seal.experiments.report.eval_curves import plot_eval_curves
from seal.experiments.report.failure_videos import render_failure_videos
from seal.experiments.report.failures import (
    INLINE_FAILURE_EGOS,
    fact,
    failure_list,
    failure_summary_markdown,
    failures_markdown,
    load_facts,
    outcome_markdown,
    outcome_table,
)


def multi_source_rows(rows: Sequence[Mapping[str, Any]], facts: Any) -> list[Mapping[str, Any]]:
    """The rows of datasets whose scenarios come from more than one source (imported recordings)."""
    sources: dict[str, set[str]] = {}
    for r in rows:
        sources.setdefault(r["dataset"], set()).add(fact(facts, r, "source"))
    return [r for r in rows if len(sources[r["dataset"]]) > 1]


def write_failure_section(
    rows: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]],
    settings_info: Sequence[Mapping[str, Any]], out: Path, videos_per_kind: int = 0, fmt: str = "mp4",
    plots: bool = True, progress: bool = True,
) -> dict[str, Any]:
    """Write ``outcomes.csv``, ``outcomes_by_layout.csv``, ``outcomes_by_source.csv`` (imported data only),
    ``failures.csv``, ``failures.md`` (the per-ego listing; in report.md too for at most `INLINE_FAILURE_EGOS`
    egos), the failure videos (``videos_per_kind`` per ego, setting and kind, under
    ``failure_videos/``) and ``eval_curves.png`` into ``out``; returns ``{"markdown", "outcomes", "by_layout",
    "by_source", "failures", "videos", "figures"}``."""
    facts = load_facts(rows)
    outcomes, by_layout = outcome_table(rows), outcome_table(rows, facts, "layout")
    source_rows = multi_source_rows(rows, facts)
    by_source = outcome_table(source_rows, facts, "source") if source_rows else []
    failures = failure_list(rows, facts)
    atomic_write_bytes(out / "outcomes.csv", to_csv(outcomes))
    atomic_write_bytes(out / "outcomes_by_layout.csv", to_csv(by_layout))
    if by_source:
        atomic_write_bytes(out / "outcomes_by_source.csv", to_csv(by_source))
    atomic_write_bytes(out / "failures.csv", to_csv([{k: v for k, v in f.items() if k != "setting_name"}
                                                      for f in failures]))
    videos = render_failure_videos(failures, runs, settings_info, out / "failure_videos", videos_per_kind, fmt,
                                   progress) if videos_per_kind > 0 else {}
    figures = []
    if plots:
        curve = plot_eval_curves(runs, out / "eval_curves.png")
        if curve is not None:
            figures.append(curve.name)
    md = [
        "## Outcomes\n",
        "Share of the scored episodes of each outcome (seeds pooled; n episodes; the four add up to 100 %) and the "
        "mean route completion.\n",
        outcome_markdown(outcomes),
        "### Per layout\n",
        outcome_markdown(by_layout, "layout"),
    ]
    if by_source:
        md += ["### Per source (imported recordings)\n", outcome_markdown(by_source, "source")]
    intro = ("Scenarios each ego failed in each setting, with the reason (failures.csv lists them all)"
             + (f"; videos: up to {videos_per_kind} of each kind (crash, out-of-road, timeout) per ego and setting, "
                "played again with the evaluation's seeds" if videos_per_kind > 0 else "") + ".\n")
    listing = failures_markdown(failures, rows, videos=videos)
    atomic_write_bytes(out / "failures.md", ("# Failures per ego and setting\n\n" + intro + "\n" + listing).encode())
    md += ["## Failures\n", "Failed episodes per pipeline and setting (seeds pooled).\n",
           failure_summary_markdown(failures, rows)]
    egos = {str(f["run"]) for f in failures}
    md += ([intro, listing] if len(egos) <= INLINE_FAILURE_EGOS else
           [f"Per ego and setting, with the reason of each failure{' and videos' if videos else ''}: "
            f"[failures.md](failures.md) ({len(egos)} egos).\n"])
    if figures:
        md += ["## Periodic evaluations during training\n",
               "Normal-eval rates of each run's periodic evaluations (eval/evaluations.csv, the eval/* curves of "
               "TensorBoard).\n", *(f"![{f}]({f})\n" for f in figures)]
    return {"markdown": "\n".join(md), "outcomes": outcomes, "by_layout": by_layout, "by_source": by_source,
            "failures": failures, "videos": sorted(videos.values()), "figures": figures}
