"""The first page of the report: which pipeline wins where, by how much and how sure we are, written from the
numbers of `seal.experiments.report.stats` (nothing about who wins is written by hand).

Per ego algorithm and setting: the pipeline with the highest mean success rate, the runner-up, the margin in points,
both 95 % intervals and the probability that the leader's egos beat the runner-up's in that setting (rliable, over
seeds). The leader is called ahead only when that probability beats 0.5 (its 95 % interval above 0.5 and its
permutation test's p below `seal.experiments.report.stats.ALPHA`: `poi_verdict`) *and* the margin's paired interval
(`seal.experiments.report.gaps`: the scenarios drawn once for both) lies above 0: with few seeds that probability
can be 1 [1-1] (every leader seed beats every runner-up seed) while the margin is within the scenario-to-scenario
noise that only the scenarios' resampling sees. Then which pipelines beat which over all settings (the averaged
probability of improvement, by the same `poi_verdict`; a seed-level statement), the precision (the largest interval
half-width against `TARGET_HALF_WIDTH`) and, from Table 6.2's intervals and the paired generator differences, the
most realistic generator and the lowest collision speed; the reference egos (Replay, the heuristic driver) against
each setting's leader (paired gaps); whether the pipeline leaves a trace in what the egos do
(`seal.experiments.report.agreement`: egos of one pipeline against egos of different pipelines, scenario by
scenario); last, the thesis's findings checked one by one (`seal.experiments.report.thesis_claims`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from seal.experiments.report.agreement import ALL_SETTINGS, agreement_line
from seal.experiments.report.differences import bound_line
from seal.experiments.report.gaps import gap_lookup
from seal.experiments.report.generator_stats import generator_rows
from seal.experiments.report.grouping import algo_of, group_name, groups_in, in_group, is_trained
from seal.experiments.report.stats import ALPHA, MIN_SEEDS_FOR_POI, enough_seeds, poi_verdict
from seal.experiments.report.thesis_claims import claims_markdown

TARGET_HALF_WIDTH = 0.05
"""Success-interval half-width the protocol aims at (5 points, issue 26)."""


def _pct(r: Mapping[str, Any]) -> str:
    return f"{100 * r['mean']:.1f} % [{100 * r['ci_low']:.1f}-{100 * r['ci_high']:.1f}]"


def _ranked(cis: Sequence[Mapping[str, Any]]) -> dict[tuple[str, str], list[Mapping[str, Any]]]:
    """``{(algo, setting): success CI rows of the trained pipelines, highest mean first}``."""
    success = [r for r in cis if r["metric"] == "success" and is_trained(r["pipeline"]) and math.isfinite(r["mean"])]
    out: dict[tuple[str, str], list[Mapping[str, Any]]] = {}
    for r in success:
        out.setdefault((algo_of(r["pipeline"]), r["setting"]), []).append(r)
    return {k: sorted(v, key=lambda r: -r["mean"]) for k, v in out.items()}


def leader_pairs(cis: Sequence[Mapping[str, Any]]) -> list[tuple[str, str, str]]:
    """``(leader, runner-up, setting)`` per algorithm and setting with two pipelines or more: the per-setting
    probabilities of improvement the first page needs."""
    return [(r[0]["pipeline"], r[1]["pipeline"], setting) for (_, setting), r in _ranked(cis).items() if len(r) > 1]


def reference_pairs(cis: Sequence[Mapping[str, Any]]) -> list[tuple[str, str, str]]:
    """``(leader, reference ego, setting)`` per algorithm and setting for every reference ego (trained by no
    pipeline) evaluated there: the paired gaps `reference_lines` reads."""
    refs = {(r["pipeline"], r["setting"]) for r in cis if r["metric"] == "success" and not is_trained(r["pipeline"])
            and math.isfinite(r["mean"])}
    return [(ranked[0]["pipeline"], ref, setting) for (_, setting), ranked in _ranked(cis).items()
            for ref, s in sorted(refs) if s == setting]


def setting_verdicts(cis: Sequence[Mapping[str, Any]], poi_by_setting: Sequence[Mapping[str, Any]],
                     gaps: Sequence[Mapping[str, Any]] = ()) -> list[dict[str, Any]]:
    """One row per (algorithm, setting) over the trained pipelines: ``best``, ``runner_up`` (None with one
    pipeline), their CI rows, ``margin`` (rate difference), ``gap`` (the leader-minus-runner-up row of ``gaps``,
    `seal.experiments.report.gaps.gap_table`, or None), the leader's per-setting probability of improvement row
    (``poi``, or None), ``seeds_agree`` (`poi_verdict` holds), ``apart`` (the gap's paired interval lies above 0)
    and ``ahead`` (both)."""
    poi = {(r["pipeline"], r["reference"], r["setting"]): r for r in poi_by_setting}
    gap_rows = gap_lookup(gaps)
    out = []
    for (algo, setting), ranked in _ranked(cis).items():
        best, second = ranked[0], (ranked[1] if len(ranked) > 1 else None)
        p = poi.get((best["pipeline"], second["pipeline"], setting)) if second else None
        gap = gap_rows.get((best["pipeline"], second["pipeline"], setting)) if second else None
        agree = bool(p and poi_verdict(p) == "holds")
        apart = bool(gap and gap["gap_low"] > 0)
        out.append({"algo": algo, "setting": setting, "best": best, "runner_up": second,
                    "margin": best["mean"] - second["mean"] if second else math.nan, "gap": gap,
                    "poi": p, "seeds_agree": agree, "apart": apart, "ahead": agree and apart})
    return out


def _verdict(v: Mapping[str, Any]) -> str:
    """The verdict words, from the two tests: the seeds' P beats 0.5 (`poi_verdict`) and the intervals apart."""
    leader = v["best"]["pipeline"]
    if v["ahead"]:
        return f"{leader} ahead"
    if v["seeds_agree"]:
        return f"{leader} ahead on the seeds, but the margin is within the scenarios' noise: not sure"
    few = bool(v["poi"]) and not enough_seeds(v["poi"])
    if v["apart"]:
        return f"{leader}'s margin is beyond the scenarios' noise, but " + (
            f"fewer than {MIN_SEEDS_FOR_POI} seeds: not sure" if few else "P does not beat 0.5: not sure")
    if few:
        return f"no clear winner (fewer than {MIN_SEEDS_FOR_POI} seeds a side for P)"
    return "no clear winner" if v["poi"] else "not compared (seed counts differ)"


def _verdict_row(v: Mapping[str, Any]) -> str:
    best, second, p = v["best"], v["runner_up"], v["poi"]
    if second is None:
        return f"| {v['setting']} | {best['pipeline']} | {_pct(best)} | - | - | - | - | only one pipeline |"
    p_text = f"{p['p_improvement']:.2f} [{p['ci_low']:.2f}-{p['ci_high']:.2f}], p = {p['p_perm']:.2f}" if p else "-"
    verdict = _verdict(v)
    g = v["gap"]
    margin = f"{100 * v['margin']:+.1f}" + (f" [{100 * g['gap_low']:+.1f}, {100 * g['gap_high']:+.1f}]" if g else "")
    return (f"| {v['setting']} | {best['pipeline']} | {_pct(best)} | {second['pipeline']} | {_pct(second)} | "
            f"{margin} | {p_text} | {verdict} |")


def reference_lines(cis: Sequence[Mapping[str, Any]], verdicts: Sequence[Mapping[str, Any]],
                    gaps: Sequence[Mapping[str, Any]] = ()) -> list[str]:
    """One sentence per reference ego (``replay``, ``heuristic``: trained by no pipeline) in the settings of
    ``verdicts`` (one algorithm's): its success rate per setting, and in how many of them the leading pipeline is
    above / below it beyond the noise (the paired gap's interval of ``gaps`` above / below 0; the question "does
    training beat the heuristic driver?")."""
    leaders = {v["setting"]: v["best"] for v in verdicts}
    gap_rows = gap_lookup(gaps)
    refs = [r for r in cis if r["metric"] == "success" and not is_trained(r["pipeline"])
            and r["setting"] in leaders and math.isfinite(r["mean"])]
    lines = []
    for name in dict.fromkeys(r["pipeline"] for r in refs):
        rows = [r for r in refs if r["pipeline"] == name]
        found = [g for r in rows if (g := gap_rows.get((leaders[r["setting"]]["pipeline"], name, r["setting"])))]
        above = sum(g["gap_low"] > 0 for g in found)
        below = sum(g["gap_high"] < 0 for g in found)
        cells = ", ".join(f"{r['setting']} {100 * r['mean']:.1f} %" for r in rows)
        lines.append(f"- Reference ego **{name}** (no training): {cells}; the leading pipeline is above it in "
                     f"{above}, below it in {below} of {len(found)} settings (paired 95 % interval of the gap on "
                     "the same scenarios).")
    return lines


def overall_lines(poi: Sequence[Mapping[str, Any]]) -> list[str]:
    """Sentences on which pipeline beats which over all common settings (`poi_verdict`)."""
    lines = []
    if poi and not any(enough_seeds(r) for r in poi):
        return [f"- Fewer than {MIN_SEEDS_FOR_POI} seeds a pipeline: no pipeline is said to beat another."]
    poi = [r for r in poi if enough_seeds(r)]
    pipelines = list(dict.fromkeys(r["pipeline"] for r in poi))
    for a in pipelines:
        beaten = [r for r in poi if r["pipeline"] == a and poi_verdict(r) == "holds"]
        if beaten:
            lines.append(f"- **{a}** beats " + ", ".join(
                f"{r['reference']} ({_p_text(r)}, {r['settings']} settings)" for r in beaten))
    if not lines and poi:
        best = max((r for r in poi), key=lambda r: r["ci_low"])
        lines.append("- No pipeline beats another with 95 % confidence over the settings (P's interval above 0.5 "
                     f"and permutation p < {ALPHA}); the closest: {best['pipeline']} over {best['reference']}, "
                     f"{_p_text(best)}.")
    return lines


def _p_text(r: Mapping[str, Any]) -> str:
    return (f"P = {r['p_improvement']:.2f} [{r['ci_low']:.2f}-{r['ci_high']:.2f}], permutation p = "
            f"{r['p_perm']:.3f}")


def precision_line(cis: Sequence[Mapping[str, Any]]) -> str:
    """The largest success-interval half-width and how many (pipeline, setting) cells meet the target."""
    rows = [r for r in cis if r["metric"] == "success" and is_trained(r["pipeline"]) and math.isfinite(r["mean"])]
    if not rows:
        return "- No trained pipeline evaluated."
    worst = max(rows, key=lambda r: r["half_width"])
    met = sum(r["half_width"] <= TARGET_HALF_WIDTH for r in rows)
    flat = sum(r["ci_low"] == r["ci_high"] for r in rows)
    span = (f"; its seeds' own rates span {100 * worst['seed_min']:.0f}-{100 * worst['seed_max']:.0f} %"
            if worst["seeds"] > 1 and math.isfinite(worst.get("seed_min", math.nan)) else "")
    return (f"- Precision: the widest success interval is +/-{100 * worst['half_width']:.1f} points "
            f"({worst['pipeline']}, {worst['setting']}, {worst['seeds']} seeds x {worst['scenarios']} scenarios"
            f"{span}); "
            f"{met} of {len(rows)} pipeline x setting cells are within +/-{100 * TARGET_HALF_WIDTH:.0f} points"
            + (f" ({flat} of them at a rate of 0 or 100 %, where the bootstrap interval has zero width)" if flat
               else "") + ".")


GENERATOR_CLAIMS = (("realism", "most realistic generator (lowest mean WD to the logged adversaries)", ""),
                    ("collision_speed_mps", "lowest collision speed", " m/s"))


def generator_lines(gen_ci: Sequence[Mapping[str, Any]], gen_diff: Sequence[Mapping[str, Any]] = ()) -> list[str]:
    """The most realistic generator (lowest mean Wasserstein distance) and the lowest collision speed, with their
    intervals (`seal.experiments.report.generator_stats`); the leader is *lowest* when its paired difference to the
    runner-up (``gen_diff``, scenario by scenario) lies below 0, or without it when its interval lies below the
    runner-up's; else not separated."""
    gens = generator_rows(gen_ci)
    diffs = {(r["setting"], r["reference"]): r for r in gen_diff}
    lines = []
    for key, what, unit in GENERATOR_CLAIMS:
        ranked = sorted((r for r in gens if math.isfinite(r.get(key, math.nan))), key=lambda r: r[key])
        if not ranked:
            continue
        cells = [f"{r['setting']} {r[key]:.3g}{unit} " + (f"[{r[f'{key}_low']:.3g}-{r[f'{key}_high']:.3g}]" if
                                                          math.isfinite(r[f"{key}_low"]) else "[too few scenarios]")
                 for r in ranked]
        lines.append(f"- The {what}: **{cells[0]}**" + (f" (then {', '.join(cells[1:])})" if cells[1:] else "")
                     + (_leader_verdict(ranked[0], ranked[1], key, unit, diffs) if len(ranked) > 1 else "") + ".")
    return lines


def _leader_verdict(first: Mapping[str, Any], second: Mapping[str, Any], key: str, unit: str,
                    diffs: Mapping[tuple[str, str], Mapping[str, Any]]) -> str:
    d = diffs.get((first["setting"], second["setting"]))
    if d is not None:
        low, high = d[f"{key}_low"], d[f"{key}_high"]
        if not (math.isfinite(low) and math.isfinite(high)):
            return "; too few scenarios for intervals: not sure"
        cell = f"{d[key]:+.3g}{unit} [{low:+.3g} to {high:+.3g}] over {d['scenarios']} scenarios"
        return (f"; paired with {second['setting']} scenario by scenario: {cell}, "
                + ("below 0" if high < 0 else "includes 0: not sure"))
    bounds = (first[f"{key}_high"], second[f"{key}_low"])
    return ("; too few scenarios for intervals: not sure" if not all(map(math.isfinite, bounds)) else
            "; its interval lies below the next one's" if bounds[0] < bounds[1] else
            "; its interval overlaps the next one's: not sure")


def first_page_markdown(cis: Sequence[Mapping[str, Any]], poi: Sequence[Mapping[str, Any]],
                        poi_by_setting: Sequence[Mapping[str, Any]], gen_ci: Sequence[Mapping[str, Any]],
                        training_lines: Sequence[str] = (), gen_diff: Sequence[Mapping[str, Any]] = (),
                        agreement: Sequence[Mapping[str, Any]] = (), differences: Sequence[Mapping[str, Any]] = (),
                        gaps: Sequence[Mapping[str, Any]] = ()) -> str:
    """The report's first page (module docstring) as Markdown; ``training_lines`` (e.g.
    `seal.experiments.report.convergence.convergence_line`) follow the precision line; ``agreement``
    (`seal.experiments.report.agreement.agreement_table`) adds, per ego algorithm, whether the pipeline leaves a
    trace in what the egos do; ``differences`` (`seal.experiments.report.differences.difference_table`) how large a
    success difference from the No-Adv pipeline the data allow; ``gaps`` (`seal.experiments.report.gaps.gap_table`
    of `leader_pairs` and `reference_pairs`) the paired margins of each setting's leader."""
    pooled = {r["algo"]: r for r in agreement if r["setting"] == ALL_SETTINGS}
    md = ["## Summary: who wins where\n",
          "Success rate: mean over seeds and scenarios with its 95 % interval (seeds and scenarios resampled). "
          "P = probability that the leader's ego beats the runner-up's in that setting (per-seed success rates; "
          "0.5 = no difference). The leader is *ahead* only when both tests agree: its seeds beat the runner-up's (P's "
          f"95 % interval lies above 0.5 and a permutation test of P, whole egos relabelled, gives p < {ALPHA}; "
          "the interval alone covers too little with 4 seeds) and the margin's paired 95 % interval (the same "
          "scenarios drawn for both, each side's seeds apart) lies above 0 (it is larger than the "
          "scenario-to-scenario noise).\n"]
    verdicts = setting_verdicts(cis, poi_by_setting, gaps)
    for algo in dict.fromkeys(v["algo"] for v in verdicts):
        if algo:
            md.append(f"### Ego algorithm: {algo}\n")
        md += ["| setting | leader | success [95 % CI] | runner-up | success [95 % CI] | margin (points) [95 % CI] | "
               "P(leader > runner-up) | verdict |", "|---|---|---:|---|---:|---:|---:|---|"]
        md += [_verdict_row(v) for v in verdicts if v["algo"] == algo]
        md.append("")
        md += overall_lines([r for r in poi if algo_of(r["pipeline"]) == algo]) or ["- (one pipeline only)"]
        if line := bound_line(differences, algo):
            md.append(line)
        md += reference_lines(cis, [v for v in verdicts if v["algo"] == algo], gaps)
        if algo in pooled and (line := agreement_line(pooled[algo])):
            md.append(line)
        md.append("")
    md.append(precision_line(cis))
    md += list(training_lines)
    groups = groups_in(gen_ci)
    for group in groups:  # with several ego algorithms: all egos, then each algorithm's apart
        lines = generator_lines(in_group(gen_ci, group), in_group(gen_diff, group))
        if len(groups) > 1 and lines:
            md.append(f"- Generators against {group_name(group)}:")
            lines = ["  " + line for line in lines]
        md += lines
    md.append("")
    md.append(claims_markdown(poi, gen_ci, gen_diff))
    return "\n".join(md)
