"""The first page of the report: which pipeline wins where, by how much and how sure we are, written from the
numbers of `seal.experiments.report.stats` (nothing about who wins is written by hand).

Per ego algorithm and setting: the pipeline with the highest mean success rate, the runner-up, the margin in
points, both 95 % intervals and the probability that the leader's egos beat the runner-up's in that setting
(rliable, over seeds). The leader is called ahead only when that probability's 95 % interval lies above 0.5;
otherwise the setting has no clear winner. Then which pipelines beat which over all settings (the averaged
probability of improvement, same rule), the precision (the largest interval half-width against `TARGET_HALF_WIDTH`)
and, from Table 6.2, the most realistic generator and the lowest collision speed (point estimates).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from seal.experiments.report.groups import algo_of, is_trained

TARGET_HALF_WIDTH = 0.05
"""Success-interval half-width the protocol aims at (5 points, issue 26)."""


def _pct(r: Mapping[str, Any]) -> str:
    return f"{100 * r['mean']:.1f} % [{100 * r['ci_low']:.1f}-{100 * r['ci_high']:.1f}]"


def setting_verdicts(cis: Sequence[Mapping[str, Any]], poi_by_setting: Sequence[Mapping[str, Any]]
                     ) -> list[dict[str, Any]]:
    """One row per (algorithm, setting) over the trained pipelines: ``best``, ``runner_up`` (None with one
    pipeline), their CI rows, ``margin`` (rate difference), the leader's per-setting probability of improvement
    row (``poi``, or None) and ``ahead`` (its interval above 0.5)."""
    success = [r for r in cis if r["metric"] == "success" and is_trained(r["pipeline"]) and math.isfinite(r["mean"])]
    poi = {(r["pipeline"], r["reference"], r["setting"]): r for r in poi_by_setting}
    out = []
    for algo in dict.fromkeys(algo_of(r["pipeline"]) for r in success):
        for setting in dict.fromkeys(r["setting"] for r in success):
            ranked = sorted((r for r in success if r["setting"] == setting and algo_of(r["pipeline"]) == algo),
                            key=lambda r: -r["mean"])
            if not ranked:
                continue
            best, second = ranked[0], (ranked[1] if len(ranked) > 1 else None)
            p = poi.get((best["pipeline"], second["pipeline"], setting)) if second else None
            out.append({"algo": algo, "setting": setting, "best": best, "runner_up": second,
                        "margin": best["mean"] - second["mean"] if second else math.nan,
                        "poi": p, "ahead": bool(p and p["ci_low"] > 0.5)})
    return out


def _verdict_row(v: Mapping[str, Any]) -> str:
    best, second, p = v["best"], v["runner_up"], v["poi"]
    if second is None:
        return f"| {v['setting']} | {best['pipeline']} | {_pct(best)} | - | - | - | - | only one pipeline |"
    p_text = f"{p['p_improvement']:.2f} [{p['ci_low']:.2f}-{p['ci_high']:.2f}]" if p else "-"
    verdict = (f"{best['pipeline']} ahead" if v["ahead"] else
               "no clear winner (P's interval reaches 0.5)" if p else "not compared (seed counts differ)")
    return (f"| {v['setting']} | {best['pipeline']} | {_pct(best)} | {second['pipeline']} | {_pct(second)} | "
            f"{100 * v['margin']:+.1f} | {p_text} | {verdict} |")


def overall_lines(poi: Sequence[Mapping[str, Any]]) -> list[str]:
    """Sentences on which pipeline beats which over all common settings (interval of P above 0.5)."""
    lines = []
    pipelines = list(dict.fromkeys(r["pipeline"] for r in poi))
    for a in pipelines:
        beaten = [r for r in poi if r["pipeline"] == a and r["ci_low"] > 0.5]
        if beaten:
            lines.append(f"- **{a}** beats " + ", ".join(
                f"{r['reference']} (P = {r['p_improvement']:.2f} [{r['ci_low']:.2f}-{r['ci_high']:.2f}], "
                f"{r['settings']} settings)" for r in beaten))
    if not lines and poi:
        best = max((r for r in poi), key=lambda r: r["ci_low"])
        lines.append("- No pipeline beats another with 95 % confidence over the settings; the closest: "
                     f"{best['pipeline']} over {best['reference']}, P = {best['p_improvement']:.2f} "
                     f"[{best['ci_low']:.2f}-{best['ci_high']:.2f}].")
    return lines


def precision_line(cis: Sequence[Mapping[str, Any]]) -> str:
    """The largest success-interval half-width and how many (pipeline, setting) cells meet the target."""
    rows = [r for r in cis if r["metric"] == "success" and is_trained(r["pipeline"]) and math.isfinite(r["mean"])]
    if not rows:
        return "- No trained pipeline evaluated."
    worst = max(rows, key=lambda r: r["half_width"])
    met = sum(r["half_width"] <= TARGET_HALF_WIDTH for r in rows)
    return (f"- Precision: the widest success interval is +/-{100 * worst['half_width']:.1f} points "
            f"({worst['pipeline']}, {worst['setting']}, {worst['seeds']} seeds x {worst['scenarios']} scenarios); "
            f"{met} of {len(rows)} pipeline x setting cells are within +/-{100 * TARGET_HALF_WIDTH:.0f} points.")


def generator_lines(t62: Sequence[Mapping[str, Any]]) -> list[str]:
    """The most realistic generator (lowest mean Wasserstein distance) and the lowest collision speed."""
    gens = [r for r in t62 if r["setting"] != "normal"]
    lines = []
    for key, what, unit in (("realism", "most realistic generator (lowest mean WD to the logged adversaries)", ""),
                            ("collision_speed_mps", "lowest collision speed", " m/s")):
        ranked = sorted((r for r in gens if math.isfinite(r.get(key, math.nan))), key=lambda r: r[key])
        if ranked:
            rest = ", ".join(f"{r['setting']} {r[key]:.3g}{unit}" for r in ranked[1:])
            lines.append(f"- The {what}: **{ranked[0]['setting']}** {ranked[0][key]:.3g}{unit}"
                         + (f" (then {rest})" if rest else "") + "; point estimates over all egos, no interval.")
    return lines


def first_page_markdown(cis: Sequence[Mapping[str, Any]], poi: Sequence[Mapping[str, Any]],
                        poi_by_setting: Sequence[Mapping[str, Any]], t62: Sequence[Mapping[str, Any]]) -> str:
    """The report's first page (module docstring) as Markdown."""
    md = ["## Summary: who wins where\n",
          "Success rate: mean over seeds and scenarios with its 95 % stratified-bootstrap interval (rliable). "
          "P = probability that the leader's ego beats the runner-up's in that setting (per-seed success rates; "
          "0.5 = no difference); the leader is *ahead* only when P's 95 % interval lies above 0.5.\n"]
    verdicts = setting_verdicts(cis, poi_by_setting)
    for algo in dict.fromkeys(v["algo"] for v in verdicts):
        if algo:
            md.append(f"### Ego algorithm: {algo}\n")
        md += ["| setting | leader | success [95 % CI] | runner-up | success [95 % CI] | margin (points) | "
               "P(leader > runner-up) | verdict |", "|---|---|---:|---|---:|---:|---:|---|"]
        md += [_verdict_row(v) for v in verdicts if v["algo"] == algo]
        md.append("")
        md += overall_lines([r for r in poi if algo_of(r["pipeline"]) == algo]) or ["- (one pipeline only)"]
        md.append("")
    md.append(precision_line(cis))
    md += generator_lines(t62)
    md.append("")
    return "\n".join(md)
