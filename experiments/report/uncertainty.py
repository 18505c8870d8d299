"""The statistics part of the report folder: the interval and improvement tables
(`seal.experiments.report.stats`), the generator intervals (`seal.experiments.report.generator_stats`), the
per-scenario paired view (`seal.experiments.report.paired`), the interval figures
(`seal.experiments.report.ci_plots`) and the first page (`seal.experiments.report.first_page`), written as CSV /
PNG files and returned as Markdown sections for ``report.md``."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_bytes
from seal.experiments.report.agreement import agreement_markdown, agreement_table
from seal.experiments.report.ci_plots import plot_success_differences, plot_success_intervals
from seal.experiments.report.compare import to_csv
from seal.experiments.report.differences import difference_markdown, difference_table
from seal.experiments.report.first_page import first_page_markdown, leader_pairs, reference_pairs
from seal.experiments.report.gaps import gap_table
from seal.experiments.report.generator_stats import (
    generator_ci_markdown,
    generator_ci_table,
    generator_difference_markdown,
    generator_difference_table,
)
from seal.experiments.report.grouping import ego_groups, group_heading, in_group, tag_by_group
from seal.experiments.report.paired import (
    discrimination_counts,
    discrimination_markdown,
    paired_counts,
    paired_markdown,
    scenario_rates,
)
from seal.experiments.report.stats import (
    N_BOOT,
    N_BOOT_POI,
    ci_markdown,
    ego_ci_table,
    improvement_markdown,
    improvement_table,
    seed_profile_markdown,
    seed_profile_table,
)

FILES = ("ego_ci.csv", "improvement.csv", "improvement_per_setting.csv", "paired.csv", "per_scenario.csv",
         "generator_ci.csv", "discrimination.csv", "generator_differences.csv", "seed_profile.csv", "agreement.csv",
         "success_differences.csv", "gaps.csv")


@dataclass
class Uncertainty:
    """What `uncertainty_report` computed and wrote."""

    ego_ci: list[dict[str, Any]]
    improvement: list[dict[str, Any]]
    improvement_per_setting: list[dict[str, Any]]
    paired: list[dict[str, Any]]
    generator_ci: list[dict[str, Any]]
    generator_differences: list[dict[str, Any]]
    first_page: str
    sections: list[str]
    figures: list[str] = field(default_factory=list)
    agreement: list[dict[str, Any]] = field(default_factory=list)
    differences: list[dict[str, Any]] = field(default_factory=list)


GENERATOR_DIFFERENCES_INTRO = (
    "Row minus column, paired: the scenarios both generators perturbed drawn with replacement, each with all its "
    "episodes in both [95 % interval]; an interval below 0 = the row is lower (more realistic, slower collisions) on "
    "the same scenarios. The matched collision speed holds the ego fixed too: the mean, over the episodes where the "
    "same ego in the same scenario met a contact in both settings, of the row's collision speed minus the column's "
    "(the plain difference also compares which scenarios end in a contact). All statistics: "
    "`generator_differences.csv` (`matched_contacts`: the matched episodes).\n")


def uncertainty_report(ego_rows: Sequence[Mapping[str, Any]], t62: Sequence[Mapping[str, Any]], out: Path,
                       plots: bool = True, n_boot: int = N_BOOT, n_boot_poi: int = N_BOOT_POI, seed: int = 0,
                       training_lines: Sequence[str] = ()) -> Uncertainty:
    """Write `FILES` (and with ``plots`` the interval figures) into ``out`` from the episode rows (pipelines
    already labelled by algorithm, `seal.experiments.report.grouping.label_by_algo`) and Table 6.2 rows;
    ``training_lines`` go onto the first page (`first_page_markdown`)."""
    cis = ego_ci_table(ego_rows, n_boot, seed)
    poi = improvement_table(ego_rows, n_boot_poi, seed)
    # Per setting only the leader vs runner-up pairs the first page reads (all 840: ~42 s more on the decisive store).
    poi_setting = improvement_table(ego_rows, n_boot_poi, seed, per_setting=True, only=leader_pairs(cis))
    paired = paired_counts(ego_rows)
    discrimination = discrimination_counts(ego_rows)
    groups = ego_groups(ego_rows)  # all egos, and each algorithm's apart when there are several
    generator_settings = [r["setting"] for r in t62]
    gen_ci = tag_by_group(groups, lambda rows: generator_ci_table(rows, generator_settings, seed=seed))
    gen_diff = tag_by_group(groups, lambda rows: generator_difference_table(rows, generator_settings, seed=seed))
    seeds = seed_profile_table(ego_rows)
    agreement = agreement_table(ego_rows, seed=seed)
    differences = difference_table(ego_rows)
    gaps = gap_table(ego_rows, leader_pairs(cis) + reference_pairs(cis), n_boot, seed)
    for name, table in zip(FILES, (cis, poi, poi_setting, paired, scenario_rates(ego_rows), gen_ci, discrimination,
                                   gen_diff, seeds, agreement, differences, gaps), strict=True):
        atomic_write_bytes(out / name, to_csv(table))
    figures = []
    if plots:
        figures = [p.name for s in ("mean", "iqm") if (p := plot_success_intervals(cis, out, s)) is not None]
        figures += [p.name for p in plot_success_differences(differences, out)]
    sections = [
        "## Uncertainty (rliable)\n",
        "Success rate in %: mean over seeds and scenarios [95 % crossed-bootstrap interval: seeds and scenarios "
        "resampled, the same scenarios for every drawn seed, so it holds on scenarios not seen; rliable's stratified "
        "interval, which redraws the scenarios per seed and covers too little, is in `ego_ci.csv`].\n",
        ci_markdown(cis) if cis else "(none)\n",
        "Success rate in %: IQM (interquartile mean) of the seeds' rates [95 % interval, same bootstrap].\n",
        ci_markdown(cis, statistic="iqm") if cis else "(none)\n",
        "Crash rate in %: mean [95 % interval].\n",
        ci_markdown(cis, metric="crash") if cis else "(none)\n",
        "Probability that the row's egos beat the column's in success rate (per-seed rates, averaged over the "
        "settings both were evaluated on; 95 % bootstrap interval drawing whole egos, each seed with its rates in "
        "every setting; 0.5 = no difference). Per setting, for each setting's leader and runner-up: "
        "`improvement_per_setting.csv`.\n",
        improvement_markdown(poi) if poi else "(fewer than two comparable pipelines)\n",
        "How large a difference the data allow: each pipeline's success rate minus the No-Adv pipeline's, in points "
        "[Welch's 95 % interval over the seeds' rates, on the scenarios both played; the seeds' bootstrap covers too "
        "little with 4 seeds] (`success_differences.csv`).\n",
        difference_markdown(differences) if differences else "(no No-Adv pipeline to compare with)\n",
        "Each seed's success rate averaged over its pipeline's settings: the probability of improvement above compares "
        "these egos whole, so one seed far from its siblings moves every comparison of its pipeline "
        "(`seed_profile.csv`).\n",
        seed_profile_markdown(seeds) if seeds else "(no trained egos)\n",
        "## Per scenario: what one pipeline solves and another does not\n",
        "A pipeline solves a scenario when its egos succeed on it in more than half of the seeds. Every "
        "scenario's success share per pipeline: `per_scenario.csv`; all counts: `paired.csv`.\n",
        paired_markdown(paired) if paired else "(fewer than two comparable pipelines)\n",
        "How much of each setting can tell the egos apart: the scenarios on which every trained ego (every pipeline "
        "and seed) succeeds, every one fails, and the rest. Only the rest can move a difference between "
        "pipelines.\n",
        discrimination_markdown(discrimination) if discrimination else "(no trained egos)\n",
        "Does the pipeline change what the egos do? Two egos agree on a scenario when both succeed or both fail. "
        "Mean agreement of the pairs of egos from the same pipeline (its seeds) and from different pipelines, the "
        "difference, and the share of random relabellings of the egos with a difference at least as large (p; "
        "small = the egos of one pipeline are more alike than the seeds' spread explains); each reference ego's "
        "agreement with the trained egos (`agreement.csv`).\n",
        agreement_markdown(agreement) if agreement else "(no trained egos)\n",
        "## Generators with intervals (Table 6.2)\n",
        "Realism Wasserstein distances and collision speed as in Table 6.2 [95 % bootstrap interval; the "
        "setting's scenarios resampled, each with all its episodes]"
        + ("; over all egos, then against each ego algorithm's egos apart (a generator perturbs the scenario "
           "against the ego's own roll-outs, so its adversary depends on the ego)" if len(groups) > 1 else "")
        + ".\n",
        *_per_group(gen_ci, groups, generator_ci_markdown, "(no generator settings evaluated)\n"),
        GENERATOR_DIFFERENCES_INTRO,
        *_per_group(gen_diff, groups, generator_difference_markdown, "(fewer than two generator settings)\n"),
    ]
    first_page = first_page_markdown(cis, poi, poi_setting, gen_ci, training_lines, gen_diff, agreement, differences,
                                     gaps)
    return Uncertainty(cis, poi, poi_setting, paired, gen_ci, gen_diff, first_page, sections, figures, agreement,
                       differences)


def _per_group(table: Sequence[Mapping[str, Any]], groups: Sequence[tuple[str, Any]],
               markdown: Callable[[Sequence[Mapping[str, Any]]], str], empty: str) -> list[str]:
    """``markdown`` of each ego group's rows of ``table``, each under its heading (`group_heading`)."""
    out = []
    for group, _ in groups:
        rows = in_group(table, group)
        out += [group_heading(group, len(groups)), markdown(rows) if rows else empty]
    return [part for part in out if part]
