"""Generator tables per ego algorithm (`seal.experiments.report.grouping.ego_groups`): with egos of two algorithms
Table 6.2, its intervals and the generator claims are given over all egos and against each algorithm's egos apart,
and the numbers of a group are those of its egos alone; with one algorithm nothing changes."""

from __future__ import annotations

import pytest
from results_builders import episode, hist

from seal.experiments.evaluation.metrics import pooled_realism
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.report.grouping import ALL_EGOS, ego_groups
from seal.experiments.report.write import write_report
from seal.scoring.realism import ACC_BINS


def _episodes(algo_brake: dict[str, float]) -> list[dict]:
    """cat and seal settings, 6 scenarios, one ego per algorithm and pipeline; against the egos of algorithm a,
    CAT's adversary brakes at ``algo_brake[a]`` m/s^2 and SEAL's at -0.5 (the log drives at 0)."""
    rows = []
    for algo, brake in algo_brake.items():
        for pipeline in ("noadv", "cat"):
            run = f"/runs/{pipeline}-{algo}-s0"
            for setting, acc in (("cat", brake), ("seal", -0.5)):
                rows += [episode(run=run, pipeline=pipeline, setting=setting, scenario_id=f"s{i}",
                                 adv_acc_hist=hist([acc] * 20, ACC_BINS), log_acc_hist=hist([0.0] * 20, ACC_BINS))
                         for i in range(6)]
    return rows


def _store(tmp_path, rows: list[dict], algos: list[str]):
    path = tmp_path / "r.sqlite"
    with ResultsStore(path) as store:
        store.upsert_episodes(rows)
        for algo in algos:
            for pipeline in ("noadv", "cat"):
                store.upsert_run(f"/runs/{pipeline}-{algo}-s0", pipeline, 0, "x", None, {"algo": algo})
        for setting in ("cat", "seal"):
            store.upsert_setting("/data", setting, "generator", "eval", setting, {}, 5)
    return path


def test_two_algorithms_get_their_own_generator_tables(tmp_path) -> None:
    rows = _episodes({"reskill": -3.0, "td3": 0.0})
    result = write_report(_store(tmp_path, rows, ["reskill", "td3"]), tmp_path / "rep", plots=False, n_boot=50,
                          n_boot_poi=50, progress=False)
    t62 = {(r["ego_group"], r["setting"]): r for r in result["table_6_2"]}
    assert set(t62) == {(g, s) for g in (ALL_EGOS, "reskill", "td3") for s in ("cat", "seal")}
    # against the TD3 egos CAT's adversary drives like the log; against the ReSkill egos it brakes hard
    assert t62[("td3", "cat")]["acc_wd"] == pytest.approx(0.0, abs=1e-9)
    reskill_rows = [r for r in rows if "-reskill-" in r["run"] and r["setting"] == "cat"]
    assert t62[("reskill", "cat")]["acc_wd"] == pytest.approx(pooled_realism(reskill_rows)["acc_wd"])
    assert t62[("reskill", "cat")]["egos"] == 2 and t62[(ALL_EGOS, "cat")]["egos"] == 4
    # The claim "SEAL is the most realistic" reads each group's own intervals: reversed against the TD3 egos (CAT
    # drives like the log there), holds against the ReSkill egos (CAT brakes harder than SEAL).
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "| SEAL is the most realistic generator (lowest mean WD) | td3 | reversed |" in md
    assert "| SEAL is the most realistic generator (lowest mean WD) | reskill | holds |" in md
    assert "**Against the td3 egos**" in md and "- Generators against the reskill egos:" in md
    assert {r["ego_group"] for r in result["generator_ci"]} == {ALL_EGOS, "reskill", "td3"}


def test_one_algorithm_keeps_one_generator_table(tmp_path) -> None:
    rows = [r for r in _episodes({"td3": 0.0})]
    result = write_report(_store(tmp_path, rows, ["td3"]), tmp_path / "rep", plots=False, n_boot=50, n_boot_poi=50,
                          progress=False)
    assert {r["ego_group"] for r in result["table_6_2"]} == {ALL_EGOS}
    assert "Against" not in (tmp_path / "rep" / "report.md").read_text().split("## Generators with intervals")[1][:400]
    assert [g for g, _ in ego_groups([{"pipeline": "cat (td3)"}, {"pipeline": "heuristic"}])] == [ALL_EGOS]
