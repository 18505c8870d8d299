"""The thesis's findings, checked one by one against the report's numbers (issue 26's closing question).

Ego claims (thesis Table 6.1 / 7.2) are read from the averaged probability of improvement over all settings
(`seal.experiments.report.stats.improvement_table`): a claim "X > Y" *holds* when P(X > Y)'s 95 % interval lies
above 0.5 and its permutation test gives p < `seal.experiments.report.stats.ALPHA`, is *reversed* when the interval
lies below and p < ALPHA, and is *not shown* otherwise (`seal.experiments.report.stats.poi_verdict`; with fewer than
`seal.experiments.report.stats.MIN_SEEDS_FOR_POI` seeds a side: *too few seeds*). Generator claims (Table 6.2)
are read from the paired generator differences (`seal.experiments.report.generator_stats.generator_difference_table`:
SEAL minus each other generator, scenario by scenario): "SEAL is the most realistic" / "SEAL has the lowest collision
speed" hold when every difference's 95 % interval lies below 0, are reversed when one lies above 0, and are not
shown otherwise; with several ego algorithms, against all egos and against each algorithm's egos apart
(`seal.experiments.report.grouping.ego_groups`). Without differences (a caller that has only the per-generator
intervals) the same reading is made from those intervals: SEAL's below every other's, another's below SEAL's (a
weaker test: two overlapping intervals can still differ when paired). A claim whose pipelines or generators were
not evaluated is *not tested*.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from seal.experiments.report.generator_stats import MATCHED_SPEED, generator_rows
from seal.experiments.report.grouping import ALL_EGOS, algo_of, base_pipeline, groups_in, in_group
from seal.experiments.report.stats import ALPHA, MIN_SEEDS_FOR_POI, ci_cell, enough_seeds, poi_verdict

EGO_CLAIMS = (("seal", "cat"), ("cat", "goose"), ("cat", "noadv"), ("seal", "goose"), ("seal", "noadv"),
              ("cat-rcg", "cat"), ("seal-rcg", "seal"))
"""``(X, Y)``: the thesis finds X's egos more successful than Y's (6.1: SEAL > CAT > GOOSE / No-Adv; 7.2: the RCG
variants over their bases)."""
GENERATOR_CLAIMS = (("realism", "SEAL is the most realistic generator (lowest mean WD)"),
                    ("collision_speed_mps", "SEAL's collisions are the slowest (lowest collision speed)"))


def ego_claims(poi: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """One row per (claim, algorithm): ``claim``, ``algo``, ``verdict`` (holds | reversed | not shown | not
    tested) and the probability row it rests on (``poi``, None when not tested)."""
    rows = {(base_pipeline(r["pipeline"]), base_pipeline(r["reference"]), algo_of(r["pipeline"])): r for r in poi}
    algos = list(dict.fromkeys(algo_of(r["pipeline"]) for r in poi)) or [""]
    out = []
    for x, y in EGO_CLAIMS:
        for algo in algos:
            r = rows.get((x, y, algo))
            verdict = ("not tested" if r is None else f"too few seeds (< {MIN_SEEDS_FOR_POI})" if not enough_seeds(r)
                       else poi_verdict(r))
            out.append({"claim": f"{x} > {y} (success)", "algo": algo, "verdict": verdict, "poi": r})
    return out


def generator_claims(gen_ci: Sequence[Mapping[str, Any]], gen_diff: Sequence[Mapping[str, Any]] = ()
                     ) -> list[dict[str, Any]]:
    """One row per generator claim: ``claim``, ``verdict``, the ``seal`` / best-other rows it rests on and, when
    ``gen_diff`` has the pair, ``diff``: SEAL minus the best other, paired (module docstring)."""
    gens = {r["setting"]: r for r in generator_rows(gen_ci)}
    diffs = diffs_of(gen_diff)
    out = []
    for key, claim in GENERATOR_CLAIMS:
        seal = gens.get("seal")
        others = [r for s, r in gens.items() if s != "seal" and math.isfinite(r.get(key, math.nan))]
        if seal is None or not others or not math.isfinite(seal.get(key, math.nan)):
            out.append({"claim": claim, "verdict": "not tested", "seal": seal, "other": None})
            continue
        best = min(others, key=lambda r: r[key])
        all_paired = all(r["setting"] in diffs for r in others)
        if all_paired:
            bounds = [(diffs[r["setting"]][f"{key}_low"], diffs[r["setting"]][f"{key}_high"]) for r in others]
        else:  # SEAL's interval against each other's, unpaired
            bounds = [(seal[f"{key}_low"] - r[f"{key}_high"], seal[f"{key}_high"] - r[f"{key}_low"]) for r in others]
        verdict = ("too few scenarios" if not all(map(math.isfinite, (b for pair in bounds for b in pair))) else
                   "holds" if all(high < 0 for _, high in bounds) else
                   "reversed" if any(low > 0 for low, _ in bounds) else "not shown")
        out.append({"claim": claim, "verdict": verdict, "seal": seal, "other": best, "key": key,
                    "diff": diffs[best["setting"]] if all_paired else None})
    return out


def diffs_of(gen_diff: Sequence[Mapping[str, Any]]) -> dict[str, Mapping[str, Any]]:
    """SEAL's paired difference rows by the other generator."""
    return {r["reference"]: r for r in gen_diff if r["setting"] == "seal"}


def _matched(claim: Mapping[str, Any], diffs: Mapping[str, Mapping[str, Any]]) -> str:
    """The collision speed claim's second reading, not its verdict: SEAL minus each other generator on matched
    contacts (`MATCHED_SPEED`), the other generators whose interval lies above or below 0 named."""
    rows = [d for d in diffs.values() if math.isfinite(d.get(f"{MATCHED_SPEED}_low", math.nan))]
    d = diffs.get(claim["other"]["setting"])
    if d is None or not rows:
        return ""
    k = MATCHED_SPEED
    above = [r["reference"] for r in rows if r[f"{k}_low"] > 0]
    below = [r["reference"] for r in rows if r[f"{k}_high"] < 0]
    return (f"; on matched contacts (same ego and scenario, both with a contact) {d[k]:+.3f} [{d[f'{k}_low']:+.3f} "
            f"to {d[f'{k}_high']:+.3f}] over {d['matched_contacts']} episodes; matched, SEAL faster than "
            f"{', '.join(above) or 'none'}, slower than {', '.join(below) or 'none'}")


def claims_markdown(poi: Sequence[Mapping[str, Any]], gen_ci: Sequence[Mapping[str, Any]],
                    gen_diff: Sequence[Mapping[str, Any]] = ()) -> str:
    """The claims as a Markdown table with the numbers each verdict rests on."""
    seeds = min((min(r["seeds"], r["reference_seeds"]) for r in poi), default=0)
    md = ["### The thesis's findings, checked\n",
          "holds / reversed: the 95 % interval lies on one side (P above or below 0.5, and its permutation test, "
          f"whole egos relabelled, gives p < {ALPHA}; SEAL minus another generator, scenario by scenario, below or "
          "above 0); not shown: it does not. P compares the pipelines' "
          f"seeds (each seed's success rate per setting; here as few as {seeds} seeds a pipeline), so it says how "
          "consistently one training pipeline beats another, not by how much: read it with the success intervals "
          "above.\n",
          "| claim | ego | verdict | evidence |", "|---|---|---|---|"]
    for c in ego_claims(poi):
        r = c["poi"]
        evidence = (f"P = {r['p_improvement']:.2f} [{r['ci_low']:.2f}-{r['ci_high']:.2f}], permutation p = "
                    f"{r['p_perm']:.3f}, over {r['settings']} settings" if r else "-")
        md.append(f"| {c['claim']} | {c['algo'] or '-'} | {c['verdict']} | {evidence} |")
    groups = groups_in(gen_ci) or [ALL_EGOS]
    claims = [(g, c) for g in groups for c in generator_claims(in_group(gen_ci, g), in_group(gen_diff, g))]
    for group, c in claims:
        if c["other"] is None:
            md.append(f"| {c['claim']} | {group} | {c['verdict']} | - |")
            continue
        key, s, o = c["key"], c["seal"], c["other"]
        seal_cell = ci_cell(s[key], s[f"{key}_low"], s[f"{key}_high"], 1.0, 3)
        other_cell = ci_cell(o[key], o[f"{key}_low"], o[f"{key}_high"], 1.0, 3)
        d = c.get("diff")
        paired = (f"; paired difference {d[key]:+.3f} [{d[f'{key}_low']:+.3f} to {d[f'{key}_high']:+.3f}] over "
                  f"{d['scenarios']} scenarios" if d else "")
        if d and key == "collision_speed_mps" and MATCHED_SPEED in d:
            paired += _matched(c, diffs_of(in_group(gen_diff, group)))
        md.append(f"| {c['claim']} | {group} | {c['verdict']} | seal {seal_cell}, best other {o['setting']} "
                  f"{other_cell}{paired} |")
    return "\n".join(md) + "\n"
