"""`seal run --status`: the state of every step of a run folder, read from the markers the run skips on; writes
nothing."""

from __future__ import annotations

import json
from pathlib import Path

from run_builders import FakeTasks, run, write_preset

from seal.cli import main
from seal.experiments.pipeline.status import format_status, run_status

STEPS = ["data", "score", "split", "fit-prior"]  # the fits the generators in use need: the prior only


def test_status_of_a_run_before_during_and_after(tmp_path: Path) -> None:
    preset, out = write_preset(tmp_path), tmp_path / "out"
    before = run_status(preset, out)
    assert not out.exists() and not before["exists"]
    assert [(s["name"], s["state"]) for s in before["steps"]] == [(n, "pending") for n in STEPS]
    assert before["training"]["done"] == 0 and before["training"]["planned"] == 4
    assert before["evaluation"] == {"rows": 0, "expected_rows": None, "egos": 5, "complete_egos": None}

    run(preset, out, FakeTasks())
    after = run_status(preset, out)
    assert [(s["name"], s["state"]) for s in after["steps"]] == [(n, "done") for n in STEPS]
    assert all(s["seconds"] >= 0 for s in after["steps"]) and after["report"] == "done"
    assert after["training"]["done"] == 4
    # 4 egos + Replay x (normal: 2 eval scenarios, hard: 1, cat: 2); the fake evaluation wrote one row a setting
    assert after["evaluation"] == {"rows": 15, "expected_rows": 25, "egos": 5, "complete_egos": 0}
    # a reference ego in eval.egos is counted with the others (and the Replay ego not twice)
    with_heuristic = run_status(preset, out, ["eval.egos=[heuristic, replay]"])["evaluation"]
    assert with_heuristic == {"rows": 15, "expected_rows": 30, "egos": 6, "complete_egos": 0}

    # one run killed at its 40-step checkpoint, the others with their wall times: the time left at their pace
    runs = out / "runs"
    for name, wall in (("noadv-s0", 50.0), ("noadv-s1", 70.0), ("cat-s0", 90.0)):
        (runs / name / "done.json").write_text(json.dumps({"steps": 100, "wall_s": wall}))
    (runs / "cat-s1" / "done.json").unlink()
    (runs / "cat-s1" / "checkpoints").mkdir()
    (runs / "cat-s1" / "checkpoints" / "latest.json").write_text(json.dumps({"step": 40, "dir": "step_40"}))
    mid = run_status(preset, out)["training"]
    assert mid["done"] == 3 and mid["mean_run_s"] == {"td3": 70.0} and mid["left_s_estimate"] == 42.0
    # two local train workers play the runs left side by side: half the time
    assert run_status(preset, out, ["backend.train_workers=2"])["training"]["left_s_estimate"] == 21.0
    assert [r for r in mid["runs"] if r["name"] == "cat-s1"] == [
        {"name": "cat-s1", "algo": "td3", "total": 100, "state": "in progress", "steps": 40}]

    # changed parameters: the split and the fit run again (the fits depend on the data)
    changed = run_status(preset, out, ["data.split.n_eval=1"])
    assert [s["state"] for s in changed["steps"]] == ["done", "done", "stale", "stale"]

    # a fit whose output is there without its marker: running now or stopped part way
    (out / "steps" / "fit-prior.json").unlink()
    assert run_status(preset, out)["steps"][-1] == {"name": "fit-prior", "state": "started"}


def test_the_command_prints_the_status_as_text_or_json(tmp_path: Path, capsys) -> None:
    preset, out = write_preset(tmp_path), tmp_path / "out"
    run(preset, out, FakeTasks())
    assert main(["run", str(preset), "--out", str(out), "--status"]) == 0
    text = capsys.readouterr().out
    assert text == format_status(run_status(preset, out)) + "\n"
    assert "training           4 of 4 runs done, 0 in progress, 0 not started" in text
    assert "evaluation         15 of 25 rows (0 of 5 egos complete)" in text
    assert main(["run", str(preset), "--out", str(out), "--status", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["training"]["done"] == 4
