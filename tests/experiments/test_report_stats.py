"""Uncertainty statistics of the report (rliable): the score matrices, mean and IQM intervals over seeds and
scenarios, the improvement table over every pair (the estimator itself: `test_report_poi.py`), algorithm groups kept
apart, the per-scenario paired view and the first page written from the numbers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from seal.experiments.report.compare import ordered_pipelines
from seal.experiments.report.first_page import (
    first_page_markdown,
    generator_lines,
    leader_pairs,
    overall_lines,
    reference_pairs,
    setting_verdicts,
)
from seal.experiments.report.gaps import gap_table
from seal.experiments.report.grouping import algo_of, base_pipeline, comparable, label_by_algo
from seal.experiments.report.paired import (
    discrimination_counts,
    discrimination_markdown,
    paired_counts,
    scenario_rates,
)
from seal.experiments.report.stats import (
    ScoreMatrix,
    crossed_bootstrap,
    ego_ci_table,
    improvement_markdown,
    improvement_table,
    iqm_columns,
    mean_iqm_intervals,
    score_matrices,
    seed_profile_markdown,
    seed_profile_table,
)


def _rows(pipeline: str, run_rates: list[float], setting: str = "normal", n: int = 10, run_prefix: str = ""
          ) -> list[dict]:
    """Seed k succeeds on the first round(rate * n) scenarios s0.. and crashes on the others."""
    rows = []
    for k, rate in enumerate(run_rates):
        wins = round(rate * n)
        rows += [{"pipeline": pipeline, "setting": setting, "run": f"{run_prefix}{pipeline}-s{k}",
                  "scenario_id": f"s{i:03d}", "success": i < wins, "crash": i >= wins, "out_of_road": False}
                 for i in range(n)]
    return rows


def test_seed_profile_shows_the_seed_that_moves_every_comparison() -> None:
    # No-Adv's seed 0 is weak in both settings; the replayed ego is no pipeline's seed
    rows = (_rows("noadv", [0.5, 0.8, 0.8], "normal") + _rows("noadv", [0.1, 0.4, 0.5], "cat")
            + _rows("cat", [0.8, 0.8, 0.7], "normal") + _rows("cat", [0.4, 0.4, 0.4], "cat") + _rows("replay", [0.9]))
    table = seed_profile_table(rows)
    assert [(r["pipeline"], r["run"], r["settings"]) for r in table] == [
        ("noadv", f"noadv-s{k}", 2) for k in range(3)] + [("cat", f"cat-s{k}", 2) for k in range(3)]
    assert [r["success"] for r in table] == pytest.approx([0.3, 0.6, 0.65, 0.6, 0.6, 0.55])
    md = seed_profile_markdown(table)
    assert "| noadv | 2 | s0 30.0, s1 60.0, s2 65.0 | 35.0 |" in md
    assert "| cat | 2 | s0 60.0, s1 60.0, s2 55.0 | 5.0 |" in md


def test_score_matrix_keeps_the_scenarios_every_seed_played() -> None:
    rows = _rows("cat", [0.2, 0.4])
    rows = [r for r in rows if not (r["run"] == "cat-s1" and r["scenario_id"] == "s009")]
    m = score_matrices(rows)[("cat", "normal")]
    assert m.values.shape == (9, 2, 3) and m.runs == ("cat-s0", "cat-s1")
    assert m.rates().tolist() == pytest.approx([2 / 9, 4 / 9])


def test_mean_and_iqm_intervals_contain_the_estimates_and_shrink_with_more_scenarios() -> None:
    rng = np.random.default_rng(0)
    widths = []
    for n in (20, 400):
        rows = [{"pipeline": "cat", "setting": "normal", "run": f"s{k}", "scenario_id": str(i),
                 "success": bool(rng.random() < 0.6), "crash": False, "out_of_road": False}
                for k in range(4) for i in range(n)]
        est = mean_iqm_intervals(score_matrices(rows)[("cat", "normal")], n_boot=400)["success"]
        assert est["mean_low"] <= est["mean"] <= est["mean_high"]
        assert est["iqm_low"] <= est["iqm"] <= est["iqm_high"]
        widths.append(est["mean_high"] - est["mean_low"])
    assert widths[1] < widths[0] / 2


def _crossed_matrix(rng: np.random.Generator, seeds: int, scenarios: int) -> ScoreMatrix:
    """0/1 successes of a crossed design: a scenario's difficulty (logit sd 3) is shared by every seed, each seed
    has its own skill (logit sd 0.3)."""
    logit = rng.normal(0.0, 3.0, scenarios)[:, None] + rng.normal(0.0, 0.3, seeds)[None, :]
    success = rng.random((scenarios, seeds)) < 1 / (1 + np.exp(-logit))
    values = np.stack([success, ~success, np.zeros_like(success)], axis=2).astype(np.float64)
    return ScoreMatrix(tuple(map(str, range(scenarios))), tuple(map(str, range(seeds))), values)


def test_crossed_interval_covers_the_population_rate_where_the_stratified_one_does_not() -> None:
    """New seeds on new scenarios of the same kind: the population rate (E sigmoid(a + b), a ~ N(0, 3^2),
    b ~ N(0, 0.3^2), 0.5 by symmetry) lies in the crossed 95 % interval about 95 % of the time (measured 94 %), and
    in rliable's stratified one (scenarios redrawn per seed) far less often (72 %), because that one divides the
    scenario variance by the 8 seeds."""
    rng = np.random.default_rng(7)
    covered = {"crossed": 0, "stratified": 0}
    trials = 120
    for t in range(trials):
        est = mean_iqm_intervals(_crossed_matrix(rng, seeds=8, scenarios=150), n_boot=400, seed=t)["success"]
        covered["crossed"] += est["mean_low"] <= 0.5 <= est["mean_high"]
        covered["stratified"] += est["stratified_low"] <= 0.5 <= est["stratified_high"]
        assert est["stratified_high"] - est["stratified_low"] < est["mean_high"] - est["mean_low"]
    assert covered["crossed"] / trials >= 0.88
    assert covered["stratified"] / trials <= 0.8


def test_crossed_bootstrap_draws_one_scenario_set_for_all_seeds() -> None:
    """Two seeds with identical outcomes stay identical in every resample (the scenarios are drawn once for both),
    so the IQM and the mean resample alike; a seed's resampled rate is a rate of the drawn scenarios."""
    values = np.zeros((5, 2, 1))
    values[:2, :, 0] = 1.0  # scenarios 0-1 solved by both seeds
    boot = crossed_bootstrap(values, n_boot=300, seed=1)
    assert boot.shape == (300, 2, 1)
    assert np.array_equal(boot[:, 0, 0], boot[:, 1, 0])
    assert set(np.round(boot[:, 0, 0] * 5).astype(int)) <= set(range(6))
    assert 0.3 < boot[:, 0, 0].mean() < 0.5  # centred on the rate 2 / 5

def test_iqm_columns_equal_rliables_iqm() -> None:
    from rliable import metrics

    rng = np.random.default_rng(3)
    for runs in range(1, 9):
        scores = rng.random((runs, 3)).round(1)  # ties included
        assert iqm_columns(scores) == pytest.approx([metrics.aggregate_iqm(scores[:, j]) for j in range(3)])


def test_iqm_is_over_the_seeds_rates_and_ignores_an_outlying_seed() -> None:
    rows = _rows("cat", [0.0, 0.5, 0.6, 1.0], n=10)
    cis = {(r["setting"], r["metric"]): r for r in ego_ci_table(rows, n_boot=200)}
    assert cis[("normal", "success")]["mean"] == pytest.approx(0.525)
    assert cis[("normal", "success")]["iqm"] == pytest.approx(0.55)  # mean of the middle two seeds
    assert cis[("normal", "success")]["seeds"] == 4 and cis[("normal", "success")]["scenarios"] == 10
    again = {(r["setting"], r["metric"]): r for r in ego_ci_table(rows, n_boot=200)}
    assert again == cis  # seeded: the same intervals each time


def test_improvement_table_covers_every_pair_both_ways() -> None:
    rows = _rows("cat", [0.2, 0.4]) + _rows("cat-rcg", [0.5, 0.7]) + _rows("noadv", [0.3, 0.3])
    rows += _rows("cat", [0.1, 0.1], setting="hard") + _rows("cat-rcg", [0.1, 0.3], setting="hard")
    rows += _rows("replay", [0.9], setting="normal")  # a built-in ego: in the tables, in no comparison
    poi = {(r["pipeline"], r["reference"]): r for r in improvement_table(rows, n_boot=200)}
    # normal: all four pairs better -> 1; hard: (0.1 = 0.1) 0.5 twice, (0.3 > 0.1) 1 twice -> 0.75
    assert poi[("cat-rcg", "cat")]["p_improvement"] == pytest.approx((1.0 + 0.75) / 2)
    assert poi[("cat", "cat-rcg")]["p_improvement"] == pytest.approx(1 - (1.0 + 0.75) / 2)
    assert poi[("cat", "cat-rcg")]["ci_low"] == pytest.approx(1 - poi[("cat-rcg", "cat")]["ci_high"])
    assert poi[("cat-rcg", "cat")]["settings"] == 2 and poi[("cat-rcg", "noadv")]["settings"] == 1
    assert poi[("cat", "noadv")]["p_improvement"] == pytest.approx(0.5)  # 0.2 < 0.3 < 0.4
    assert not any("replay" in key for key in poi) and len(poi) == 6
    per_setting = {(r["pipeline"], r["reference"], r["setting"]): r
                   for r in improvement_table(rows, n_boot=200, per_setting=True)}
    assert per_setting[("cat-rcg", "cat", "hard")]["p_improvement"] == pytest.approx(0.75)
    md = improvement_markdown(list(poi.values()))
    assert "| cat-rcg | 1.00 [1.00-1.00] p=0.33 | 0.88 [" in md and md.index("| noadv |") < md.index("| cat-rcg |")


def test_algorithms_are_labelled_apart_and_compared_only_within() -> None:
    rows = _rows("cat", [0.2, 0.4], run_prefix="a/") + _rows("cat", [0.8, 0.9], run_prefix="b/")
    rows += _rows("noadv", [0.1, 0.2], run_prefix="a/") + _rows("replay", [0.5])
    runs = [{"run": f"a/{p}-s{k}", "pipeline": p, "config": '{"algo": "reskill"}'} for p in ("cat", "noadv")
            for k in range(2)] + [{"run": f"b/cat-s{k}", "pipeline": "cat", "config": {"algo": "td3"}}
                                  for k in range(2)] + [{"run": "replay", "pipeline": "replay", "config": "{}"}]
    labelled = label_by_algo(rows, runs)
    names = ordered_pipelines({r["pipeline"] for r in labelled})
    assert names == ["replay", "noadv (reskill)", "cat (reskill)", "cat (td3)"]
    assert algo_of("cat (td3)") == "td3" and base_pipeline("cat-rcg (td3)") == "cat-rcg"
    assert comparable("cat (reskill)", "noadv (reskill)") and not comparable("cat (reskill)", "cat (td3)")
    pairs = {(r["pipeline"], r["reference"]) for r in improvement_table(labelled, n_boot=50)}
    assert pairs == {("cat (reskill)", "noadv (reskill)"), ("noadv (reskill)", "cat (reskill)")}
    one_algo = [r for r in runs if r["run"].startswith("a/")]
    assert {r["pipeline"] for r in label_by_algo(rows, one_algo)} == {"cat", "noadv", "replay"}


def test_paired_view_counts_what_one_solves_and_the_other_does_not() -> None:
    # cat solves s0-s5 in both seeds; noadv solves s0-s2 in both seeds and s3 in one seed only (not a majority).
    rows = _rows("cat", [0.6, 0.6]) + _rows("noadv", [0.4, 0.3])
    counts = {(r["pipeline"], r["reference"]): r for r in paired_counts(rows)}
    c = counts[("cat", "noadv")]
    assert (c["both"], c["only_pipeline"], c["only_reference"], c["neither"], c["scenarios"]) == (3, 3, 0, 4, 10)
    assert counts[("noadv", "cat")]["only_reference"] == 3
    shares = {(r["pipeline"], r["scenario_id"]): r["success_share"] for r in scenario_rates(rows)}
    assert shares[("noadv", "s003")] == 0.5 and shares[("cat", "s005")] == 1.0


def test_discrimination_counts_scenarios_every_trained_ego_solves_or_fails() -> None:
    # s0-s2 every seed of both pipelines solves; s3-s5 only some egos; s6-s9 none. The built-in heuristic ego is
    # not a trained ego (it solves everything here and changes nothing); TD3 egos are counted apart.
    rows = _rows("cat", [0.6, 0.3]) + _rows("noadv", [0.4, 0.5]) + _rows("heuristic", [1.0])
    rows += _rows("cat (td3)", [0.0, 0.0]) + _rows("cat", [1.0, 1.0], setting="hard")
    counts = {(r["setting"], r["algo"]): r for r in discrimination_counts(rows)}
    assert set(counts) == {("normal", ""), ("normal", "td3"), ("hard", "")}
    c = counts[("normal", "")]
    assert (c["egos"], c["scenarios"], c["all_succeed"], c["all_fail"], c["differ"]) == (4, 10, 3, 4, 3)
    assert (counts[("normal", "td3")]["all_fail"], counts[("hard", "")]["all_succeed"]) == (10, 10)
    md = discrimination_markdown(discrimination_counts(rows))
    assert "| normal | 4 | 10 | 3 | 4 | 3 (30 %) |" in md and "| normal (td3) | 2 | 10 | 0 | 10 | 0 (0 %) |" in md


def test_first_page_names_the_leader_from_the_numbers() -> None:
    rows = _rows("cat", [0.9, 0.95, 0.85, 0.9], n=40) + _rows("noadv", [0.4, 0.5, 0.45, 0.5], n=40)
    rows += _rows("cat", [0.5, 0.4, 0.45, 0.5], setting="hard", n=40)
    rows += _rows("noadv", [0.45, 0.5, 0.4, 0.55], setting="hard", n=40)
    # Every seed of seal beats every seed of noadv, by 10 points on 10 scenarios: P = 1, but within the noise.
    rows += _rows("seal", [0.6, 0.6, 0.7, 0.6], setting="seal") + _rows("noadv", [0.5, 0.5, 0.5, 0.4], setting="seal")
    # the heuristic driver as a reference ego: below cat on normal (intervals apart), level with it on hard
    rows += _rows("heuristic", [0.5], n=40) + _rows("heuristic", [0.45], setting="hard", n=40)
    cis = ego_ci_table(rows, n_boot=300)
    pairs = leader_pairs(cis)
    assert sorted(pairs) == [("cat", "noadv", "normal"), ("noadv", "cat", "hard"), ("seal", "noadv", "seal")]
    poi, per_setting = improvement_table(rows, n_boot=300), improvement_table(rows, n_boot=300, per_setting=True,
                                                                              only=pairs)
    assert {r["setting"] for r in per_setting} == {"normal", "hard", "seal"} and len(per_setting) == 6
    gaps = gap_table(rows, pairs + reference_pairs(cis), n_boot=300)
    assert sorted(reference_pairs(cis)) == [("cat", "heuristic", "normal"), ("noadv", "heuristic", "hard")]
    verdicts = {v["setting"]: v for v in setting_verdicts(cis, per_setting, gaps)}
    assert verdicts["normal"]["best"]["pipeline"] == "cat" and verdicts["normal"]["ahead"]
    assert verdicts["normal"]["margin"] == pytest.approx(0.9 - 0.4625)
    assert not verdicts["hard"]["ahead"]  # noadv 47.5 vs cat 46.3 %: no clear winner
    assert verdicts["seal"]["seeds_agree"] and not verdicts["seal"]["apart"] and not verdicts["seal"]["ahead"]
    gen_ci = [{"setting": "normal", "realism": 0.0, "collision_speed_mps": 1.0},
              {"setting": "cat", "realism": 0.3, "realism_low": 0.25, "realism_high": 0.35,
               "collision_speed_mps": 4.0, "collision_speed_mps_low": 3.0, "collision_speed_mps_high": 5.0},
              {"setting": "seal", "realism": 0.2, "realism_low": 0.15, "realism_high": 0.24,
               "collision_speed_mps": 5.0, "collision_speed_mps_low": 4.5, "collision_speed_mps_high": 5.5}]
    md = first_page_markdown(cis, poi, per_setting, gen_ci, gaps=gaps)
    assert "| normal | cat | 90.0 % [" in md and "| cat ahead |" in md and "| no clear winner |" in md
    assert "| +15.0 [+0.0, +38.8] |" in md  # paired: every scenario's gap >= 0, 3 of 10 scenarios differ
    assert "seal ahead on the seeds, but the margin is within the scenarios' noise: not sure" in md
    assert ("- Reference ego **heuristic** (no training): normal 50.0 %, hard 45.0 %; the leading pipeline is above "
            "it in 1, below it in 0 of 2 settings (paired 95 % interval of the gap on the same scenarios).") in md
    assert ("most realistic generator (lowest mean WD to the logged adversaries): **seal 0.2 [0.15-0.24]** (then "
            "cat 0.3 [0.25-0.35]); its interval lies below the next one's.") in md
    assert "lowest collision speed: **cat 4 m/s [3-5]** (then seal 5 m/s [4.5-5.5]); its interval overlaps" in md
    assert "of 6 pipeline x setting cells are within +/-5 points" in md
    no_bounds = [{**r, "realism_low": math.nan} if r["setting"] == "cat" else r for r in gen_ci]
    assert generator_lines(no_bounds)[0].endswith("; too few scenarios for intervals: not sure.")


def test_report_folder_has_the_statistics_first_page_and_json(tmp_path, capsys) -> None:
    import json

    from results_builders import episode

    from seal.cli import main
    from seal.cli.compare import N_BOOT_DEFAULT, N_BOOT_POI_DEFAULT
    from seal.experiments.evaluation.results_store import ResultsStore
    from seal.experiments.report.stats import N_BOOT, N_BOOT_POI

    assert (N_BOOT_DEFAULT, N_BOOT_POI_DEFAULT) == (N_BOOT, N_BOOT_POI)
    rows = [episode(run=f"/runs/{p}-s{k}", pipeline=p, seed=k, setting=s, scenario_id=f"s{i}",
                    outcome="success" if i < wins + k else "crash")
            for p, wins in (("noadv", 2), ("cat", 6)) for k in range(3) for s in ("normal", "hard") for i in range(8)]
    store_path = tmp_path / "r.sqlite"
    with ResultsStore(store_path) as store:
        store.upsert_episodes(rows)
    out = tmp_path / "rep"
    assert main(["compare", "--store", str(store_path), "--out", str(out), "--reps", "200", "--poi-reps", "100",
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert {p.name for p in out.iterdir()} >= {"ego_ci.csv", "improvement.csv", "improvement_per_setting.csv",
                                               "paired.csv", "per_scenario.csv", "discrimination.csv",
                                               "ci_success_mean.png",
                                               "ci_success_iqm.png"}
    cell = next(r for r in result["ego_ci"] if (r["pipeline"], r["setting"], r["metric"]) == ("cat", "hard", "success"))
    assert cell["mean"] == pytest.approx((6 + 7 + 8) / 24) and cell["seeds"] == 3 and cell["scenarios"] == 8
    assert (cell["seed_min"], cell["seed_max"]) == pytest.approx((6 / 8, 8 / 8))  # the seeds' own rates
    from seal.experiments.report.first_page import precision_line
    widest = max((r for r in result["ego_ci"] if r["metric"] == "success" and r["pipeline"] != "replay"),
                 key=lambda r: r["half_width"])
    assert (f"{widest['seeds']} seeds x {widest['scenarios']} scenarios; its seeds' own rates span "
            f"{100 * widest['seed_min']:.0f}-{100 * widest['seed_max']:.0f} %)") in precision_line(result["ego_ci"])
    poi = next(r for r in result["improvement"] if r["pipeline"] == "cat")
    assert poi["p_improvement"] == 1.0 and poi["settings"] == 2
    # Agreement: noadv seed k wins s0..s(1+k), cat seed j s0..s(5+j); within a pipeline the seeds disagree on 1, 2
    # and 1 of 8 scenarios, across on 4 + j - k: 40 / 48 agree within, 36 / 72 across.
    pooled = next(r for r in result["agreement"] if r["setting"] == "all settings")
    assert (pooled["within"], pooled["across"], pooled["scenarios"]) == pytest.approx((40 / 48, 0.5, 16))
    assert (out / "agreement.csv").exists()
    assert poi["p_perm"] == pytest.approx(2 / 20)  # 3 + 3 egos fully apart: 2 of the 20 splits
    diff = next(r for r in result["success_differences"] if r["setting"] == "all settings")
    assert diff["difference"] == pytest.approx((6 + 7 + 8 - 2 - 3 - 4) / 24) and diff["low"] < 0.5 < diff["high"]
    assert {"success_differences.csv", "success_differences.png"} <= {p.name for p in out.iterdir()}
    md = (out / "report.md").read_text()
    assert "- How large a difference the data allow (success minus noadv" in md
    assert md.index("## Summary: who wins where") < md.index("(thesis Table 6.1)")
    assert "| normal | cat | 87.5 % [" in md and "| noadv | 87.5 % [" not in md


def test_generator_intervals_resample_scenarios_and_match_table_6_2() -> None:
    from results_builders import episode, hist

    from seal.experiments.evaluation.metrics import pooled_realism
    from seal.experiments.report.generator_stats import generator_ci_markdown, generator_ci_table
    from seal.scoring.realism import YAW_RATE_BINS

    rng = np.random.default_rng(1)
    rows = []
    for i in range(12):  # 12 scenarios x 3 egos; the adversary's yaw rates spread more in some scenarios
        for k in range(3):
            speed = float(2 + i % 4) if (i + k) % 3 == 0 else None
            rows.append(episode(run=f"r{k}", setting="cat", scenario_id=f"s{i}", collision_speed_mps=speed,
                                adv_yaw_hist=hist(rng.normal(0, 0.1 + 0.05 * (i % 3), 40), YAW_RATE_BINS)))
    rows += [episode(run="r0", setting="hard", scenario_id="h0")]  # not a Table 6.2 row
    (row,) = generator_ci_table(rows, ["cat"], n_boot=200)
    expected = pooled_realism([r for r in rows if r["setting"] == "cat"])
    assert (row["setting"], row["scenarios"], row["episodes"]) == ("cat", 12, 36)
    assert row["realism"] == pytest.approx(expected["realism"])
    assert row["realism_yaw_acc"] == pytest.approx((expected["yaw_wd"] + expected["acc_wd"]) / 2)
    speeds = [r["collision_speed_mps"] for r in rows if r["setting"] == "cat" and r["collision_speed_mps"] is not None]
    assert row["collision_speed_mps"] == pytest.approx(np.mean(speeds))
    assert row["realism_yaw_acc_per_scenario"] == pytest.approx(0.15)  # the builder's yaw_wd 0.1, acc_wd 0.2
    for name in ("realism", "collision_speed_mps"):
        assert row[f"{name}_low"] <= row[name] <= row[f"{name}_high"] and row[f"{name}_low"] < row[f"{name}_high"]
    assert "| cat | 12 | 36 | " in generator_ci_markdown([row])
    (few,) = generator_ci_table([r for r in rows if r["scenario_id"] in ("s0", "s1")], ["cat"], n_boot=50)
    assert math.isfinite(few["realism"]) and math.isnan(few["realism_low"]) and math.isnan(few["realism_high"])
    assert "[no interval]" in generator_ci_markdown([few])


def test_generator_differences_pair_the_scenarios() -> None:
    from results_builders import episode, hist

    from seal.experiments.evaluation.metrics import pooled_realism
    from seal.experiments.report.generator_stats import (
        generator_ci_table,
        generator_difference_markdown,
        generator_difference_table,
    )
    from seal.experiments.report.thesis_claims import generator_claims
    from seal.scoring.realism import YAW_RATE_BINS

    rng = np.random.default_rng(2)
    rows = []
    for i in range(12):  # scenario i: every contact at 1 + i m/s (cat) or 0.3 m/s slower (seal), 3 egos each
        for k in range(3):
            for setting, dv, spread in (("cat", 0.0, 0.3), ("seal", -0.3, 0.1)):
                rows.append(episode(run=f"r{k}", setting=setting, scenario_id=f"s{i}", collision_speed_mps=1.0 + i + dv,
                                    adv_yaw_hist=hist(rng.normal(0, spread, 40), YAW_RATE_BINS),
                                    yaw_wd=0.1 * i + (0.1 if setting == "cat" else 0.0), acc_wd=0.3))
    rows += [episode(run="r0", setting="normal", scenario_id="s0", collision_speed_mps=9.0)]  # replayed: no rival
    table = generator_difference_table(rows, ["normal", "cat", "seal"], n_boot=200)
    diff = {(r["setting"], r["reference"]): r for r in table}
    assert set(diff) == {("cat", "seal"), ("seal", "cat")} and diff[("seal", "cat")]["scenarios"] == 12
    seal, cat = (pooled_realism([r for r in rows if r["setting"] == s]) for s in ("seal", "cat"))
    d = diff[("seal", "cat")]
    assert d["realism"] == pytest.approx(seal["realism"] - cat["realism"])
    assert d["realism_yaw_acc"] == pytest.approx((seal["yaw_wd"] + seal["acc_wd"] - cat["yaw_wd"] - cat["acc_wd"]) / 2)
    # the same scenarios in every resample: the speed difference is -0.3 in all of them
    assert (d["collision_speed_mps"], d["collision_speed_mps_low"], d["collision_speed_mps_high"]) == pytest.approx(
        (-0.3, -0.3, -0.3))
    # per scenario: each episode's own (yaw + acc) / 2, seal 0.05 below cat in every scenario
    assert (d["realism_yaw_acc_per_scenario"], d["realism_yaw_acc_per_scenario_low"],
            d["realism_yaw_acc_per_scenario_high"]) == pytest.approx((-0.05, -0.05, -0.05))
    back = diff[("cat", "seal")]
    assert (back["realism"], back["realism_low"], back["realism_high"]) == pytest.approx(
        (-d["realism"], -d["realism_high"], -d["realism_low"]))
    # Unpaired, the two speed intervals overlap (the scenarios' own speeds spread over 1-12 m/s): the claim is not
    # shown from them, and holds from the paired differences.
    gen_ci = generator_ci_table(rows, ["cat", "seal"], n_boot=200)
    by = {r["setting"]: r for r in gen_ci}
    assert by["seal"]["collision_speed_mps_high"] > by["cat"]["collision_speed_mps_low"]
    verdicts = {c["key"]: c["verdict"] for c in generator_claims(gen_ci)}
    paired = {c["key"]: c for c in generator_claims(gen_ci, table)}
    assert verdicts["collision_speed_mps"] == "not shown" and paired["collision_speed_mps"]["verdict"] == "holds"
    assert paired["collision_speed_mps"]["diff"] is d
    md = generator_difference_markdown(table)
    assert "| seal | **" in md and "| coll. speed (m/s): row - column | cat | seal |" in md
    assert first_page_markdown([], [], [], gen_ci, (), table).count("paired") >= 2


def test_thesis_claims_read_the_intervals() -> None:
    from seal.experiments.report.thesis_claims import claims_markdown, ego_claims, generator_claims

    def p(a: str, b: str, lo: float, hi: float, p_perm: float = 0.01) -> dict:
        return {"pipeline": a, "reference": b, "p_improvement": (lo + hi) / 2, "ci_low": lo, "ci_high": hi,
                "settings": 3, "seeds": 4, "reference_seeds": 3, "p_perm": p_perm}

    poi = [p("seal (td3)", "cat (td3)", 0.6, 0.9), p("cat (td3)", "goose (td3)", 0.3, 0.7),
           p("cat (td3)", "noadv (td3)", 0.1, 0.4), p("seal (td3)", "goose (td3)", 0.55, 0.9, p_perm=0.2)]
    verdicts = {c["claim"]: c["verdict"] for c in ego_claims(poi)}
    assert verdicts["seal > cat (success)"] == "holds" and verdicts["cat > goose (success)"] == "not shown"
    assert verdicts["cat > noadv (success)"] == "reversed" and verdicts["cat-rcg > cat (success)"] == "not tested"
    assert verdicts["seal > goose (success)"] == "not shown"  # interval above 0.5, permutation test not
    # One seed a side: the bootstrap interval has zero width whatever the data, so no verdict rests on it.
    lone = [{**p("seal", "cat", 0.61, 0.61), "seeds": 1, "reference_seeds": 1}]
    assert ego_claims(lone)[0]["verdict"] == "too few seeds (< 3)"
    assert overall_lines(lone) == ["- Fewer than 3 seeds a pipeline: no pipeline is said to beat another."]

    def g(name: str, lo: float, hi: float) -> dict:
        return {"setting": name, "realism": (lo + hi) / 2, "realism_low": lo, "realism_high": hi,
                "collision_speed_mps": 5.0, "collision_speed_mps_low": 4.0 + (name == "seal"),
                "collision_speed_mps_high": 6.0}

    claims = {c["claim"][:20]: c["verdict"] for c in generator_claims([g("seal", 0.1, 0.2), g("cat", 0.3, 0.4)])}
    assert claims == {"SEAL is the most rea": "holds", "SEAL's collisions ar": "not shown"}
    assert generator_claims([g("cat", 0.1, 0.2)])[0]["verdict"] == "not tested"
    md = claims_markdown(poi, [g("seal", 0.5, 0.6), g("cat", 0.1, 0.2)])
    assert ("| seal > cat (success) | td3 | holds | P = 0.75 [0.60-0.90], permutation p = 0.010, over 3 settings |"
            in md)
    assert "as few as 3 seeds a pipeline" in md
    assert ("| SEAL is the most realistic generator (lowest mean WD) | all | reversed | seal 0.550 [0.500-0.600], "
            "best other cat 0.150 [0.100-0.200] |") in md
    unbounded = [{**g("seal", 0.1, 0.2), "realism_low": math.nan}, g("cat", 0.3, 0.4)]
    assert generator_claims(unbounded)[0]["verdict"] == "too few scenarios"
    assert "seal 0.150 [no interval]" in claims_markdown(poi, unbounded)
    # The replayed-adversary rows (normal, normal-reactive: realism ~0 by construction) are no rival generator.
    replayed = [g("normal", 0.0, 0.01), g("normal-reactive", 0.0, 0.02), g("seal", 0.1, 0.2), g("cat", 0.3, 0.4)]
    assert generator_claims(replayed)[0]["verdict"] == "holds"
    from seal.experiments.report.first_page import generator_lines
    assert generator_lines(replayed)[0].startswith("- The most realistic generator (lowest mean WD to the logged "
                                                   "adversaries): **seal 0.15 [0.1-0.2]** (then cat 0.35")


def test_generator_intervals_equal_resampling_the_episodes_themselves() -> None:
    """The bootstrap sums per-scenario histogram vectors; its intervals equal recomputing Table 6.2's pooled
    statistics from the resampled scenarios' episodes (same rliable resamples)."""
    from results_builders import episode, hist
    from rliable import library as rly

    from seal.experiments.evaluation.metrics import pooled_realism
    from seal.experiments.report.generator_stats import CONFIDENCE, generator_intervals
    from seal.experiments.report.stats import seeded
    from seal.scoring.realism import ACC_BINS

    rng = np.random.default_rng(4)
    rows = [episode(run=f"r{k}", setting="seal", scenario_id=f"s{i}",
                    collision_speed_mps=float(rng.uniform(1, 8)) if rng.random() < 0.5 else None,
                    adv_acc_hist=hist(rng.normal(-0.3 * (i % 4), 1.0 + 0.2 * k, 30), ACC_BINS))
            for i in range(9) for k in range(2)]
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(r["scenario_id"], []).append(r)
    scenarios = list(groups.values())

    def episodes_realism(index: np.ndarray) -> np.ndarray:
        pooled = pooled_realism([e for i in index[:, 0] for e in scenarios[int(i)]])
        return np.array([pooled["realism"], (pooled["yaw_wd"] + pooled["acc_wd"]) / 2])

    with seeded(3), np.errstate(all="ignore"):
        points, intervals = rly.get_interval_estimates(
            {"x": np.arange(len(scenarios), dtype=np.float64)[:, None]}, episodes_realism, reps=120,
            confidence_interval_size=CONFIDENCE)
    got = generator_intervals(rows, n_boot=120, seed=3)
    for i, name in enumerate(("realism", "realism_yaw_acc")):
        assert got[name] == pytest.approx((points["x"][i], intervals["x"][0, i], intervals["x"][1, i]), abs=1e-12)
