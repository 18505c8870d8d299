"""The report folder of `seal compare --out` and `seal run`: tables (`seal.experiments.report.compare`), figures
and videos (`seal.experiments.report.compare_plots`) and ``report.md`` tying them together."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_bytes
from seal.experiments.evaluation.evaluate import REAL_PREFIX
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.report.compare import (
    ego_markdown,
    ego_table,
    generator_markdown,
    generator_table_by_group,
    ordered_pipelines,
    per_run_rates,
    setting_label,
    to_csv,
)
from seal.experiments.report.compare_plots import plot_setting_bars, plot_training_curves, render_generator_videos
from seal.experiments.report.convergence import convergence_line, convergence_markdown, convergence_rows
from seal.experiments.report.failure_section import write_failure_section
from seal.experiments.report.grouping import filter_datasets, label_by_algo, separate
from seal.experiments.report.stats import N_BOOT, N_BOOT_POI
from seal.experiments.report.uncertainty import uncertainty_report


def write_report(
    store_path: str | Path, out: str | Path, pipelines: Sequence[str] | None = None,
    settings: Sequence[str] | None = None, plots: bool = True, videos: int = 0, video_format: str = "mp4",
    progress: bool = True, datasets: Sequence[str] | None = None, failure_videos: int = 0, n_boot: int = N_BOOT,
    n_boot_poi: int = N_BOOT_POI,
) -> dict[str, Any]:
    """Write ``report.md``, ``table_6_1.csv``, ``table_6_2.csv``, ``episodes_per_run.csv``, the outcome /
    failure tables (`seal.experiments.report.failure_section`) and (``plots``) the figures, (``videos`` > 0) that
    many videos per generator, (``failure_videos`` > 0) that many videos of each failure kind per ego and setting,
    into ``out``; returns the tables. ``datasets``: only episodes on these datasets (paths or folder names);
    datasets, egos without a pipeline and egos of different algorithms are kept apart
    (`seal.experiments.report.grouping`). The first page (`seal.experiments.report.first_page`) and the
    statistics files come from `seal.experiments.report.uncertainty`; ``n_boot`` / ``n_boot_poi``: bootstrap
    resamples of the intervals / of the probabilities of improvement."""
    out = Path(out)
    rows, runs, settings_info = _read_store(store_path, pipelines, settings, datasets)
    ego_rows = label_by_algo(rows, runs)  # egos of different algorithms stay apart in the ego tables
    t61, t62 = ego_table(ego_rows), generator_table_by_group(ego_rows, settings_info)
    per_run = [
        {"pipeline": p, "setting": setting_label(s), "run": run, **rates}
        for (p, s), by_run in per_run_rates(ego_rows).items() for run, rates in by_run.items()
    ]
    atomic_write_bytes(out / "table_6_1.csv", to_csv(t61))
    atomic_write_bytes(out / "table_6_2.csv", to_csv(t62))
    atomic_write_bytes(out / "rates_per_run.csv", to_csv(per_run))
    convergence, training_line, training_md = _convergence(runs, out)
    stats = uncertainty_report(ego_rows, t62, out, plots=plots, n_boot=n_boot, n_boot_poi=n_boot_poi,
                               training_lines=training_line)
    figures: list[str] = list(stats.figures)
    video_files: list[str] = []
    if plots:
        figures += [str(p.name) for p in plot_setting_bars(t61, out)]
        curves = plot_training_curves(runs, out / "training_curves.png")
        if curves is not None:
            figures.append(curves.name)
    if videos > 0:
        video_files = [str(p.relative_to(out)) for p in render_generator_videos(
            rows, runs, settings_info, out / "videos", per_generator=videos, fmt=video_format, progress=progress
        )]
    # Labelled rows: the outcome shares keep egos of different algorithms apart, as the ego tables do.
    where = write_failure_section(ego_rows, runs, settings_info, out, failure_videos, video_format, plots, progress)
    figures += where["figures"]
    n_runs = len({r["run"] for r in rows})
    md = [
        "# Evaluation report\n",
        f"Store `{Path(store_path).resolve()}`: {len(rows)} scored episodes of {n_runs} egos "
        f"(pipelines: {', '.join(ordered_pipelines({r['pipeline'] for r in ego_rows}))}).\n",
        stats.first_page,
        "## Egos per training pipeline (thesis Table 6.1)\n",
        "Rates in %: median over seeds, [25th-75th percentile]; each seed's rate is over the setting's "
        "scenarios. Generator settings: the last of K perturbation passes against the same ego.\n",
        ego_markdown(t61),
        *stats.sections,
        "## Generators (thesis Table 6.2)\n",
        "Ego success / crash averaged over egos; realism = Wasserstein distances of the pooled adversary yaw rate, "
        "acceleration and out-of-road rate to the logged adversaries (lower = more realistic); collision speed "
        "along the contact normal over colliding episodes; head-on rates of all episodes. `normal` = logged "
        "adversary (reference); `normal-reactive` = the same with reacting background traffic (the crashes the "
        "replayed background caused are the difference). yaw+acc WD: the mean of the yaw and acceleration "
        "distances alone (thesis Table 7.6 leaves the out-of-road term out); per scenario: each episode's own yaw and "
        "acceleration WDs to its scenario's logged adversary, averaged over the episodes (the thesis's \"profiles "
        "derived from the original X_adv in s\" read per scenario; larger, as one episode's histograms are sparse).\n",
        generator_markdown(t62) if t62 else "(no generator settings evaluated)\n",
        where["markdown"],
        *training_md,
    ]
    if figures:
        md.append("## Figures\n")
        md += [f"![{f}]({f})\n" for f in figures if f not in where["figures"]]
    if video_files:
        md.append("## Videos\n")
        md += [f"- [{v}]({v})" for v in video_files]
        md.append("")
    atomic_write_bytes(out / "report.md", "\n".join(md).encode())
    return {"table_6_1": t61, "table_6_2": t62, "ego_ci": stats.ego_ci, "improvement": stats.improvement,
            "improvement_per_setting": stats.improvement_per_setting, "paired": stats.paired,
            "generator_ci": stats.generator_ci, "agreement": stats.agreement, "success_differences": stats.differences,
            "figures": figures, "videos": video_files, "episodes": len(rows), "outcomes": where["outcomes"],
            "by_layout": where["by_layout"], "by_source": where["by_source"], "failures": where["failures"],
            "failure_videos": where["videos"], "convergence": convergence}


Rows = list[dict[str, Any]]


def _convergence(runs: Rows, out: Path) -> tuple[Rows, list[str], list[str]]:
    """Write ``convergence.csv`` (`seal.experiments.report.convergence`); return its rows, the first page's line
    (none without periodic evaluations) and the report section."""
    rows = convergence_rows(runs)
    atomic_write_bytes(out / "convergence.csv", to_csv(rows))
    if not rows:
        return rows, [], []
    line = convergence_line(rows)
    section = ["## Training convergence\n",
               "Slope of each run's periodic Normal-eval success over the last half of its evaluations (least "
               "squares), averaged per pipeline, with its standard error from the evaluations' binomial noise; "
               "*still improving*: at least +1 point per 10k env steps and more than 2 standard errors above 0 "
               "(convergence.csv).\n", convergence_markdown(rows)]
    return rows, [line] if line else [], section


def _read_store(store_path: str | Path, pipelines: Sequence[str] | None, settings: Sequence[str] | None,
                datasets: Sequence[str] | None) -> tuple[Rows, Rows, Rows]:
    """The filtered episode rows (relabelled by `seal.experiments.report.grouping.separate`), runs and settings."""
    with ResultsStore(store_path) as store:
        setting_filter = _expand_settings(settings, store) if settings else None
        rows = store.episodes(pipeline=pipelines or None, setting=setting_filter, decode_hists=True)
        runs = store.runs(pipeline=pipelines or None)
        settings_info = store.settings()
    if datasets:
        rows = filter_datasets(rows, datasets)
    if not rows:
        raise ValueError(
            f"{store_path}: no evaluation episodes match (pipelines {pipelines or 'all'}, settings "
            f"{settings or 'all'}, datasets {datasets or 'all'}); run `seal eval runs ...` first"
        )
    return separate(rows), runs, settings_info


def _expand_settings(settings: Sequence[str], store: Any) -> list[str]:
    """Setting filters as given, with ``real:NAME`` also matching ``real:/any/path/NAME``."""
    known = {s["setting"] for s in store.settings()}
    out = []
    for s in settings:
        out.append(s)
        out += [k for k in known if k.startswith(REAL_PREFIX) and setting_label(k) == s]
    return out
