"""The report says which scenarios failed and why (issue 25): two datasets kept apart with counts in every cell,
timeout and route completion, per-layout breakdown, failures per ego and setting with videos of each kind, eval
curves, `seal render --ego --generator`."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf

from seal.cli import main
from seal.core.dataset import Dataset, scenario_facts, write_dataset
from seal.experiments.evaluation.evaluate import resolve_eval_config
from seal.experiments.evaluation.parallel import evaluate_runs
from seal.experiments.evaluation.policies import evaluate_policy
from seal.experiments.report.failures import reason
from seal.experiments.report.write import write_report


def floor_it(obs: np.ndarray) -> np.ndarray:
    return np.array([0.0, 1.0])  # full throttle, straight: crashes, leaves curves, arrives on straight roads


def brake(obs: np.ndarray) -> np.ndarray:
    return np.array([0.0, -1.0])  # never moves: every episode times out


def make_dataset(root: Path, scenarios: list) -> Path:
    write_dataset(root, scenarios)
    ids = [s.scenario_id for s in scenarios]
    Dataset.open(root).update_manifest(splits={"train": [], "eval": ids, "hard": []})
    return root


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    base = tmp_path_factory.mktemp("failures")
    mixed = make_dataset(base / "a" / "mixed", [sf.lane_change_scenario(), sf.curve_scenario(),
                                                sf.highway_scenario(0), sf.highway_scenario(1)])
    other = make_dataset(base / "b" / "other", [sf.highway_scenario(2), sf.stopped_adversary_scenario()])
    path = base / "r.sqlite"
    config = {"k": 1, "generators": {"rule": {}}}
    for ds in (mixed, other):
        evaluate_policy(floor_it, "floor-it", ds, settings="normal,rule", store=path, config=config, progress=False)
        evaluate_policy(brake, "brake", ds, settings="normal", store=path, progress=False)
    evaluate_runs(["heuristic"], "normal", path, dataset=mixed, replay_ego=False, progress=False,
                  config=resolve_eval_config())
    return path, mixed, other


def test_two_datasets_are_kept_apart_with_counts(store: tuple[Path, Path, Path], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    path, mixed, other = store
    result = write_report(path, tmp_path / "rep", plots=False, progress=False)
    cells = {(r["pipeline"], r["setting"]): r["scenarios"] for r in result["table_6_1"] if r["metric"] == "success"}
    assert cells[("floor-it", "normal@mixed")] == 4 and cells[("floor-it", "normal@other")] == 2
    assert cells[("heuristic", "normal@mixed")] == 4 and ("heuristic", "normal@other") not in cells
    md = (tmp_path / "rep" / "report.md").read_text()
    assert "normal@mixed" in md and "normal@other" in md and "(4) |" in md
    assert main(["compare", "--store", str(path), "--out", str(tmp_path / "rep3"), "--no-plots", "--json",
                 "--dataset", "mixed", "--no-progress"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert {r["setting"] for r in printed["outcomes"]} == {"normal", "rule"}  # one dataset: plain names
    assert printed["failures"] and all(f["dataset"] == str(mixed) for f in printed["failures"])
    only = write_report(path, tmp_path / "rep2", plots=False, progress=False, datasets=["other"])
    assert {(r["pipeline"], r["setting"]) for r in only["outcomes"]} == {
        ("brake", "normal"), ("floor-it", "normal"), ("floor-it", "rule")}


def test_outcomes_layouts_and_failures_with_videos(store: tuple[Path, Path, Path], tmp_path: Path) -> None:
    path, mixed, _ = store
    out = tmp_path / "rep"
    result = write_report(path, out, plots=False, progress=False, datasets=[str(mixed)], failure_videos=1,
                          pipelines=["floor-it", "brake"])
    outcomes = {(r["pipeline"], r["setting"]): r for r in result["outcomes"]}
    stopped = outcomes[("brake", "normal")]
    assert stopped["timeout"] == 1.0 and stopped["n"] == 4 and stopped["route_completion"] < 0.3
    floor = outcomes[("floor-it", "normal")]
    assert floor["success"] + floor["crash"] + floor["out_of_road"] + floor["timeout"] == pytest.approx(1.0)
    assert floor["crash"] == 0.5 and floor["out_of_road"] == 0.25  # two highways, the curve
    layouts = {s["layout"] for s in scenario_facts(mixed).values()}
    assert {r["layout"] for r in result["by_layout"]} == layouts and len(layouts) > 1
    assert sum(r["n"] for r in result["by_layout"] if r["pipeline"] == "brake") == 4
    failures = result["failures"]
    kinds = {(f["pipeline"], f["setting"], f["outcome"]) for f in failures}
    assert {("floor-it", "normal", "crash"), ("floor-it", "normal", "out_of_road"),
            ("brake", "normal", "timeout")} <= kinds
    assert all(f["outcome"] != "success" for f in failures)
    curve = next(f for f in failures if f["pipeline"] == "floor-it" and f["scenario_id"] == "curve"
                 and f["setting"] == "normal")
    assert curve["reason"].startswith("left the road at")
    with open(out / "failures.csv") as f:
        assert len(list(csv.DictReader(f))) == len(failures)
    # one video per kind, ego and setting; each linked from the failures section
    videos = result["failure_videos"]
    names = {Path(v).name.split("_")[0] for v in videos}
    assert {"crash", "out", "timeout"} <= names  # out_of_road_...
    assert all((out / v).is_file() and (out / v).stat().st_size > 0 for v in videos)
    assert any("rule" in v for v in videos)  # generator settings get videos too
    md = (out / "report.md").read_text()
    assert "## Failures" in md and "| timeout |" in md and "(failure_videos/" in md
    assert "| pipeline | setting | failed / episodes | crash-adversary |" in md  # the summary, then the listing
    assert "(failure_videos/" in (out / "failures.md").read_text()


def test_failure_summary_counts_and_many_egos_listed_apart(tmp_path: Path) -> None:
    from seal.experiments.report.failure_section import write_failure_section
    from seal.experiments.report.failures import INLINE_FAILURE_EGOS, failure_list, failure_summary_markdown

    def row(run: int, outcome: str, adv: int = 0) -> dict:
        return {"pipeline": "cat (td3)", "run": f"/r/cat-td3-s{run}", "setting": "cat", "scenario_id": f"s{run}",
                "dataset": "d", "outcome": outcome, "adv_collision": adv, "route_completion": 0.5,
                "min_gap_m": 1.0}

    rows = [row(0, "crash", 1), row(0, "crash", 0), row(1, "crash", 1), row(1, "timeout"), row(1, "success"),
            row(2, "out_of_road")]
    md = failure_summary_markdown(failure_list(rows), rows)
    assert "| cat (td3) | cat | 5 / 6 | 2 | 1 | 1 | 1 |" in md
    many = [row(i, "crash", 1) for i in range(INLINE_FAILURE_EGOS + 1)]
    section = write_failure_section(many, [], [], tmp_path, plots=False, progress=False)["markdown"]
    assert "[failures.md](failures.md) (7 egos)" in section and "crashed into the adversary" not in section
    assert (tmp_path / "failures.md").read_text().count("crashed into the adversary") == INLINE_FAILURE_EGOS + 1


def test_reason_words() -> None:
    row = {"outcome": "crash", "adv_collision": 1, "route_completion": 0.42, "min_gap_m": 0.0}
    assert reason(row) == "crashed into the adversary at 42 % of the route"
    assert reason({**row, "adv_collision": 0}) == "crashed into other traffic at 42 % of the route"
    assert reason({**row, "outcome": "timeout", "min_gap_m": 3.25}).endswith("closest gap to the adversary 3.2 m")


def test_render_any_ego_and_generator(store: tuple[Path, Path, Path], tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    _, mixed, _ = store
    out = tmp_path / "v.mp4"
    code = main(["render", "--dataset", str(mixed), "--scenario", "highway-0", "--ego", "heuristic",
                 "--generator", "rule", "--k", "1", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    summary = json.loads(capsys.readouterr().out)
    assert out.stat().st_size > 0 and summary["scenario_id"] == "highway-0" and summary["frames"] > 1
    assert main(["render", "--dataset", str(mixed), "--scenario", "nosuch", "--ego", "heuristic",
                 "--out", str(out)]) == 2
    assert "nosuch" in capsys.readouterr().err


def test_runs_without_a_pipeline_are_not_seeds_of_one() -> None:
    from seal.experiments.report.compare import ego_table
    from seal.experiments.report.grouping import separate

    rows = [{"run": f"/models/{name}", "pipeline": "unknown", "dataset": "/d", "setting": "normal",
             "scenario_id": f"s{i}", "success": i % 2, "crash": 0, "out_of_road": 1 - i % 2}
            for name in ("a", "b") for i in range(3)]
    table = ego_table(separate(rows))
    assert {(r["pipeline"], r["seeds"]) for r in table} == {("unknown:a", 1), ("unknown:b", 1)}


def test_eval_curves_from_the_runs_periodic_evaluations(tmp_path: Path) -> None:
    from seal.experiments.report.eval_curves import plot_eval_curves, read_eval_curves

    run = tmp_path / "cat-s0"
    (run / "eval").mkdir(parents=True)
    (run / "eval" / "evaluations.csv").write_text(
        "step,episodes,success_rate,crash_rate,out_of_road_rate,route_completion\n1000,20,0.1,0.5,0.4,0.3\n"
        "2000,20,0.4,0.3,0.3,0.6\n")
    runs = [{"run": str(run), "pipeline": "cat", "path": str(run)}, {"run": "replay", "pipeline": "replay"}]
    ((_, cols),) = read_eval_curves(runs)
    np.testing.assert_allclose(cols["success_rate"], [0.1, 0.4])
    path = plot_eval_curves(runs, tmp_path / "eval_curves.png")
    assert path is not None and path.stat().st_size > 0
    assert plot_eval_curves(runs[1:], tmp_path / "none.png") is None


def test_failure_videos_of_reactive_settings_replay_with_their_background(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from seal.experiments.evaluation import replay_episode
    from seal.experiments.report.failure_videos import render_failure_videos

    specs = []
    monkeypatch.setattr(replay_episode, "render", lambda spec, out: specs.append(spec))
    failures = [{"run": "heuristic", "pipeline": "heuristic", "dataset": "/d", "setting": s, "setting_name": s,
                 "scenario_id": "a", "outcome": "crash"} for s in ("cat", "cat-reactive", "normal-reactive")]
    settings = [
        {"dataset": "/d", "setting": "cat", "generator": "cat", "kwargs": {"stride": 5}, "k": 5, "seed": 0},
        {"dataset": "/d", "setting": "cat-reactive", "generator": "cat", "k": 5, "seed": 0,
         "kwargs": {"stride": 5, "background": "idm", "background_model": None}},
        {"dataset": "/d", "setting": "normal-reactive", "generator": None, "k": 0, "seed": 0,
         "kwargs": {"background": "rapid", "background_model": "m.pt"}},
    ]
    render_failure_videos(failures, [], settings, tmp_path / "v", progress=False)
    by = {(s.generator, s.background): s for s in specs}
    assert set(by) == {("cat", None), ("cat", "idm"), (None, "rapid")}
    assert by[("cat", "idm")].kwargs == {"stride": 5} == by[("cat", None)].kwargs  # the generator's own options
    assert by[(None, "rapid")].background_model == "m.pt" and by[(None, "rapid")].kwargs == {}
