"""The held-out report of ``seal fit objective`` / ``seal eval objective`` as files and text: ``report.json``,
``report.md`` (`format_report`) and the terminal summary (`format_summary`). The metrics themselves are computed by
`seal.experiments.fitting.objective_eval.evaluate`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_bytes, atomic_write_json

K_PREV = 5
"""Previous roll-outs per scenario in the K-roll-out ranking metric (SEAL's K)."""


def write_report(out: Path, report: dict[str, Any]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "report.json", report)
    atomic_write_bytes(out / "report.md", format_report(report).encode())


def format_report(r: dict[str, Any]) -> str:
    """Markdown report of `evaluate`'s metrics."""
    lab = r["labels"]
    lines = [
        f"# pi_score on held-out split `{r['eval_split']}` of `{r['dataset']}`",
        "",
        f"{lab['scenarios']} held-out scenarios x {lab['candidates']} candidates; ego crashes into the adversary in "
        f"{lab['crash_share']:.1%} of candidate episodes; mean f_coll {lab['f_coll_mean']:.3f}, mean f_diff "
        f"{lab['f_diff_mean_logged_prev']:.3f} (logged previous roll-out) / {lab['f_diff_mean_all_prev']:.3f} (any).",
        *([f"In a scenario, {lab['near_tie_share_logged_prev']:.0%} of the candidate pairs have simulated f_coll + "
           "f_diff (logged previous roll-out) within 0.01 of each other: the Spearman means below rank those too."]
          if "near_tie_share_logged_prev" in lab else []),
        "",
        "## MSE per head",
        "",
        f"Label variance (the MSE of predicting the mean): f_coll {lab.get('f_coll_var', float('nan')):.5f}, f_diff "
        f"{lab.get('f_diff_var_all_prev', float('nan')):.5f} (all previous roll-outs).",
        "",
        "| previous roll-out | f_coll | f_diff | pairs |",
        "|---|---|---|---|",
    ]
    for k, v in r["mse"].items():
        lines.append(f"| {k.replace('_', ' ')} | {v['f_coll']:.5f} | {v['f_diff']:.5f} | {v['pairs']} |")
    for key, title in (("ranking_logged_prev", "previous roll-out = logged-adversary episode"),
                       ("ranking_k5_prev", f"K = {K_PREV} previous roll-outs (mean score)")):
        lines += ["", f"## Ranking the candidates, {title}", "",
                  "| score | Spearman mean | median | share >= 0.6 | top-1 in sim. top-3 | sim. value of top-1 "
                  "| best possible | top-1 a crash (of scenarios with one) |", "|---|---|---|---|---|---|---|---|"]
        for name, m in r[key].items():
            crash = m.get("crash_chosen_when_any")
            lines.append(f"| {name} | {m['spearman_mean']:.3f} | {m['spearman_median']:.3f} | "
                         f"{m['share_spearman_ge_0.6']:.2f} | {m['top1_in_top3']:.2f} | {m['chosen_target_mean']:.3f} "
                         f"| {m['best_target_mean']:.3f} | {'-' if crash is None else f'{crash:.3f}'} |")
    if "ranking_per_head" in r:
        lines += ["", "## Each head against its own label (previous roll-out = logged episode; Spearman mean)", "",
                  "| label | pi_score head | closeness |", "|---|---|---|"]
        lines += [f"| {k} | {v['pi_score_head']:.3f} | {v['closeness']:.3f} |"
                  for k, v in r["ranking_per_head"].items()]
    if "oracle_bounds_logged_prev" in r:
        ob = r["oracle_bounds_logged_prev"]
        lines += ["", "## How far above closeness a score can get (previous roll-out = logged episode)", "",
                  "Closeness with the true crash flags (crashes first): Spearman "
                  f"**{ob['closeness_plus_true_crash']:.3f}**, the most a crash predictor can add; closeness + the "
                  "true f_diff: "
                  f"**{ob['closeness_plus_true_f_diff']:.3f}** (where the rest of the headroom is)."]
    if "label_retest" in r:
        rt = r["label_retest"]
        lines += ["", "## Label reproducibility (a second draw of the held-out labels, another skill-noise seed)", "",
                  f"Spearman of the two draws' f_coll + f_diff (previous roll-out = logged episode): "
                  f"**{rt['label_spearman']:.3f}**: one draw ranks the other this well, and a score predicting the "
                  f"expected label would reach about its square root ({rt['label_spearman'] ** 0.5:.3f}) against one "
                  f"draw; a score below that is short of what the labels allow, not held back by their noise "
                  f"(f_coll {rt['label_spearman_per_head']['f_coll']:.3f}, f_diff "
                  f"{rt['label_spearman_per_head']['f_diff']:.3f}; f_diff > 0.5 agrees in "
                  f"{rt['f_diff_above_half_agreement']:.1%} of the candidates).", "",
                  "| score | Spearman against the second draw |", "|---|---|"]
        lines += [f"| {k} | {v:.3f} |" for k, v in rt["scores_on_second_draw"].items()]
    lat = r["rank_latency"]
    lines += ["", f"rank() latency, {lat['candidates']} candidates x K = {lat['rollouts']}, one thread: median "
              f"{lat['median_ms']} ms, p95 {lat['p95_ms']} ms.", "", f"Timings (s): {r['timings']}"]
    if "fit" in r:
        lines.append(f"Training: {r['fit']}")
    return "\n".join(lines) + "\n"


def format_summary(r: dict[str, Any]) -> str:
    """Short plain-text summary for the terminal."""
    m = r["ranking_logged_prev"]
    p, c = m["pi_score"], m["closeness"]
    return (f"pi_score written to {r['out']}\n"
            f"held-out MSE (logged prev): f_coll {r['mse']['logged_prev']['f_coll']:.5f}, f_diff "
            f"{r['mse']['logged_prev']['f_diff']:.5f}; all prev: f_coll {r['mse']['all_prev']['f_coll']:.5f}, f_diff "
            f"{r['mse']['all_prev']['f_diff']:.5f}\n"
            f"Spearman mean {p['spearman_mean']:.3f} (closeness baseline {c['spearman_mean']:.3f}"
            + (f", CAT {m['cat']['spearman_mean']:.3f}" if "cat" in m else "") + f"), top-1 in top-3 "
            f"{p['top1_in_top3']:.2f} (baseline {c['top1_in_top3']:.2f}); K={K_PREV}: Spearman "
            f"{r['ranking_k5_prev']['pi_score']['spearman_mean']:.3f} (closeness "
            f"{r['ranking_k5_prev']['closeness']['spearman_mean']:.3f}"
            + (f", CAT {r['ranking_k5_prev']['cat']['spearman_mean']:.3f}" if "cat" in r["ranking_k5_prev"] else "")
            + ")\n"
            f"rank() {r['rank_latency']['median_ms']} ms median; timings {r['timings']}\n"
            + (f"fit: {r['fit']['diagnosis']}\n" if "diagnosis" in r.get("fit", {}) else "") +
            f"full report: {Path(r['out']) / 'report.md'}")
