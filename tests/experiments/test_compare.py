"""`seal compare` on a tiny fake result set: Table 6.1 medians / IQR and Table 6.2 columns checked by hand."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from results_builders import episode

from seal.cli import main
from seal.experiments.evaluation.metrics import histogram_counts, pooled_realism, wasserstein_from_counts
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.report.compare import ego_table, generator_table, setting_label
from seal.experiments.report.write import write_report
from seal.scoring.realism import (
    ACC_BINS,
    OFFROAD_BINS,
    YAW_RATE_BINS,
    acceleration_stats,
    accelerations,
    histogram_wasserstein,
    realism_wd,
    yaw_rates,
)

# successes out of 4 scenarios per seed: (pipeline, setting) -> per-seed counts
SUCCESSES = {
    ("noadv", "normal"): [4, 3, 2],
    ("noadv", "cat"): [1, 0, 2],
    ("cat", "normal"): [4, 4, 3],
    ("cat", "cat"): [3, 2, 4],
    ("replay", "normal"): [4],
    ("replay", "cat"): [0],
}


def fake_rows() -> list[dict]:
    rows = []
    for (pipeline, setting), counts in SUCCESSES.items():
        for seed, n_success in enumerate(counts):
            for i in range(4):
                outcome = "success" if i < n_success else ("crash" if i % 2 else "out_of_road")
                crash = outcome == "crash"
                rows.append(episode(
                    run=f"/runs/{pipeline}-s{seed}" if pipeline != "replay" else "replay", pipeline=pipeline,
                    seed=seed, setting=setting, scenario_id=f"sc{i}", outcome=outcome,
                    collision_speed_mps=(2.0 + i) if crash and setting == "cat" else None,
                    head_on=crash and i == 3 and setting == "cat", generations=5 if setting == "cat" else 0,
                    generation_ms_mean=10.0 * (seed + 1) if setting == "cat" else None,
                ))
    return rows


def _cell(table, pipeline, setting, metric):
    (row,) = [r for r in table if r["pipeline"] == pipeline and r["setting"] == setting and r["metric"] == metric]
    return row


def test_table_6_1_median_and_iqr_over_seeds():
    table = ego_table(fake_rows())
    row = _cell(table, "noadv", "normal", "success")  # rates 1.0, 0.75, 0.5
    assert row["seeds"] == 3 and row["scenarios"] == 12
    assert row["median"] == pytest.approx(0.75)
    assert (row["q25"], row["q75"], row["iqr"]) == pytest.approx((0.625, 0.875, 0.25))
    row = _cell(table, "cat", "cat", "success")  # 0.75, 0.5, 1.0
    assert (row["q25"], row["median"], row["q75"]) == pytest.approx((0.625, 0.75, 0.875))
    # failures of noadv on cat: seed0 3 fails (i=1 crash, i=2 oor, i=3 crash), seed1 4 (2 crash, 2 oor),
    # seed2 2 (i=2 oor, i=3 crash): crash rates 0.5, 0.5, 0.25
    row = _cell(table, "noadv", "cat", "crash")
    assert (row["q25"], row["median"], row["q75"]) == pytest.approx((0.375, 0.5, 0.5))
    row = _cell(table, "replay", "cat", "out_of_road")  # one seed: IQR 0
    assert row["seeds"] == 1 and row["median"] == pytest.approx(0.5) and row["iqr"] == 0.0
    assert [r["pipeline"] for r in table][0] == "replay"  # thesis order: replay, noadv, ..., cat


def test_table_6_2_per_generator():
    rows = fake_rows()
    for r in rows:  # decode as the store does
        r.update({k: list(r[k]) for k in ("adv_yaw_hist", "adv_acc_hist", "log_yaw_hist", "log_acc_hist")})
    settings = [{"setting": "cat", "kind": "generator"}, {"setting": "normal", "kind": "replay"}]
    table = {r["setting"]: r for r in generator_table(rows, settings)}
    cat = table["cat"]
    assert cat["egos"] == 7 and cat["episodes"] == 28
    per_ego = [1 / 4, 0, 2 / 4, 3 / 4, 2 / 4, 4 / 4, 0]
    assert cat["ego_success"] == pytest.approx(np.mean(per_ego))
    crashes = [r for r in rows if r["setting"] == "cat" and r["crash"]]
    assert cat["collision_speed_mps"] == pytest.approx(np.mean([r["collision_speed_mps"] for r in crashes]))
    assert cat["head_on_rate"] == pytest.approx(sum(r["head_on"] for r in crashes) / 28)
    assert cat["generation_ms_mean"] == pytest.approx(np.mean([10.0 * (s + 1) for s in (0, 1, 2, 0, 1, 2, 0)]))
    assert "normal" in table and np.isnan(table["normal"]["collision_speed_mps"])
    cat_rows = [r for r in rows if r["setting"] == "cat"]
    for i, r in enumerate(cat_rows):  # per-episode WDs that differ, so the mean is over episodes, not a constant
        r.update(yaw_wd=0.01 * i, acc_wd=0.5 - 0.01 * i * i)
    again = {r["setting"]: r for r in generator_table(rows, settings)}["cat"]
    assert again["realism_yaw_acc_per_scenario"] == pytest.approx(
        np.mean([(0.01 * i + 0.5 - 0.01 * i * i) / 2 for i in range(len(cat_rows))]))
    cat_rows[0]["yaw_wd"] = None  # an episode without an adversary track has no WDs: left out
    again = {r["setting"]: r for r in generator_table(rows, settings)}["cat"]
    assert again["realism_yaw_acc_per_scenario"] == pytest.approx(
        np.mean([(r["yaw_wd"] + r["acc_wd"]) / 2 for r in cat_rows[1:]]))


def test_counts_give_the_set_level_realism_of_pooled_samples():
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 0.3, 500), rng.normal(0.2, 0.5, 300)
    assert wasserstein_from_counts(histogram_counts(a, YAW_RATE_BINS), histogram_counts(b, YAW_RATE_BINS),
                                   YAW_RATE_BINS) == pytest.approx(histogram_wasserstein(a, b, YAW_RATE_BINS))
    # pooled per-episode rows == realism_wd over all tracks at once
    def track(n: int, turn: float) -> np.ndarray:
        t = np.zeros((n, 8))
        t[:, 2] = np.cumsum(rng.normal(turn, 0.05, n))
        t[:, 3] = 10 + np.cumsum(rng.normal(0, 0.3, n))
        t[:, 7] = 1.0
        return t

    gen = [track(40, 0.02), track(60, -0.01), track(30, 0.0)]
    log = [track(80, 0.0) for _ in gen]
    gen_off, log_off = [rng.random(len(t)) < 0.2 for t in gen], [np.zeros(len(t), bool) for t in log]
    rows = [{
        "adv_yaw_hist": histogram_counts(yaw_rates([g]), YAW_RATE_BINS), "log_yaw_hist":
        histogram_counts(yaw_rates([lg]), YAW_RATE_BINS), "adv_acc_hist": histogram_counts(accelerations([g]),
        ACC_BINS), "log_acc_hist": histogram_counts(accelerations([lg]), ACC_BINS),
        "adv_offroad_share": float(go.mean()), "log_offroad_share": float(lo.mean()),
    } for g, lg, go, lo in zip(gen, log, gen_off, log_off, strict=True)]
    pooled = pooled_realism(rows)
    direct = realism_wd(gen, log, gen_off, log_off)
    for key in ("yaw_wd", "acc_wd", "road_wd", "realism"):
        assert pooled[key] == pytest.approx(direct[key])
    assert OFFROAD_BINS[0] < 0  # the 0/1 flags sit inside the bins
    # The hard-braking shares from the stored histograms equal the direct ones (-3 m/s^2 is a bin edge).
    direct_acc = acceleration_stats(gen, log)
    assert pooled["hard_brake_share"] == pytest.approx(direct_acc["hard_brake_share"])
    assert pooled["logged_hard_brake_share"] == pytest.approx(direct_acc["logged_hard_brake_share"])
    assert pooled["hard_brake_share"] > 0.0


def test_report_files_tables_and_plots(tmp_path):
    run_dir = tmp_path / "noadv-s0"
    run_dir.mkdir()
    (run_dir / "progress.csv").write_text(
        "time/total_timesteps,rollout/ep_rew_mean,episode/success_rate,curriculum/p\n100,1.0,0.1,0\n200,2.0,,0.5\n"
        "300,3.0,0.4,0.9\n"
    )
    store_path = tmp_path / "r.sqlite"
    with ResultsStore(store_path) as store:
        store.upsert_episodes(fake_rows())
        store.upsert_run("/runs/noadv-s0", "noadv", 0, "x", str(run_dir), {})
        store.upsert_setting("/data", "cat", "generator", "eval", "cat", {}, 5)
    out = tmp_path / "report"
    result = write_report(store_path, out, progress=False, n_boot=200, n_boot_poi=100)
    assert {p.name for p in out.iterdir()} >= {
        "report.md", "table_6_1.csv", "table_6_2.csv", "rates_per_run.csv", "bars_success.png", "bars_crash.png",
        "bars_out_of_road.png", "training_curves.png",
    }
    with open(out / "table_6_1.csv") as f:
        rows = list(csv.DictReader(f))
    row = next(r for r in rows if r["pipeline"] == "noadv" and r["setting"] == "normal" and r["metric"] == "success")
    assert float(row["median"]) == pytest.approx(0.75) and float(row["iqr"]) == pytest.approx(0.25)
    md = (out / "report.md").read_text()
    assert "| noadv | 3 | 75.0 [62.5-87.5] (12) | 25.0 [12.5-37.5] (12) |" in md  # success: normal, cat; n episodes
    assert [r["setting"] for r in result["table_6_2"]] == ["normal", "cat"]
    # filters: one pipeline, one setting
    only = write_report(store_path, tmp_path / "r2", pipelines=["cat"], settings=["normal"], plots=False)
    assert {(r["pipeline"], r["setting"]) for r in only["table_6_1"]} == {("cat", "normal")}


def test_compare_cli_and_errors(tmp_path, capsys):
    store_path = tmp_path / "r.sqlite"
    with ResultsStore(store_path) as store:
        store.upsert_episodes(fake_rows())
    assert main(["compare", "--store", str(store_path), "--out", str(tmp_path / "rep"), "--no-plots", "--reps", "200",
                 "--poi-reps", "100"]) == 0
    assert "75.0 [62.5-87.5]" in capsys.readouterr().out
    assert main(["compare", "--store", str(store_path), "--out", str(tmp_path / "x"), "--pipeline", "seal"]) == 2
    assert "no evaluation episodes match" in capsys.readouterr().err
    assert main(["compare", "--store", str(tmp_path / "missing.sqlite"), "--out", str(tmp_path / "y")]) == 2


def test_setting_label():
    assert setting_label("real:/tmp/a/imp_ngsim") == "real:imp_ngsim" and setting_label("cat") == "cat"
