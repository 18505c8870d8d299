"""A moved or copied `seal run` folder: every step stays done, its store rows and run configs follow it, markers from
before the portable hash still count, and paths outside the folder are left alone."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import yaml
from results_builders import episode
from run_builders import FakeTasks, run, write_preset

from seal.core.paths import portable_json, rebase, rebase_tree
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.pipeline.location import LOCATION, recorded_roots, relocate
from seal.experiments.pipeline.status import format_status, run_status
from seal.experiments.pipeline.steps import Steps


def test_rebase_moves_only_the_folder_and_paths_below_it() -> None:
    assert rebase("/a/b", "/a/b", "/c") == "/c"
    assert rebase("/a/b/runs/x", "/a/b", "/c/d") == "/c/d/runs/x"
    assert rebase("/a/bc/runs/x", "/a/b", "/c") == "/a/bc/runs/x"  # a longer name, not below /a/b
    assert rebase("replay", "/a/b", "/c") == "replay"
    tree = {"data": "/a/b/data", "k": ["/a/b/m.pt", 3, "/a/b2"], "n": None}
    assert rebase_tree(tree, "/a/b", "/c") == {"data": "/c/data", "k": ["/c/m.pt", 3, "/a/b2"], "n": None}


def test_portable_json_is_the_same_wherever_the_folder_is() -> None:
    def params(root: str) -> dict:
        return {"dataset": f"{root}/data", "out": f"{root}/models/prior.pt", "other": "/a/b2/x", "n": 3}

    assert portable_json(params("/a/b"), "/a/b") == portable_json(params("/c"), "/c")
    assert '"${OUT}/data"' in portable_json(params("/a/b"), "/a/b")
    assert '"/a/b2/x"' in portable_json(params("/a/b"), "/a/b")  # a longer name, not below the folder: kept
    assert portable_json(params("/a/b"), "/a/b", as_folder="/z") == json.dumps(params("/z"), sort_keys=True)


def _legacy_marker(folder: Path, name: str, params: object) -> None:
    """A marker as `seal run` wrote it before the portable hash: the hash of the absolute-path parameters."""
    digest = hashlib.sha256(json.dumps(params, sort_keys=True, default=str).encode()).hexdigest()[:16]
    (folder / "steps").mkdir(parents=True, exist_ok=True)
    (folder / "steps" / f"{name}.json").write_text(json.dumps({"params": digest, "seconds": 7.0, "finished": 1.0}))


def test_an_absolute_path_marker_counts_in_place_and_after_a_move_and_is_rewritten(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"

    def params(root: Path) -> list:
        return [{"n": 3}, {"dataset": f"{root}/data", "out": f"{root}/models/prior.pt"}]

    _legacy_marker(a, "fit-prior", params(a))
    assert Steps(a).done("fit-prior", params(a))  # in place: the old hash still matches
    shutil.copytree(a, b)
    assert not Steps(b).done("fit-prior", params(b))  # moved, no earlier path known: stale
    steps = Steps(b, [str(a)])
    assert steps.done("fit-prior", params(b))
    assert steps.run("fit-prior", params(b), lambda: (_ for _ in ()).throw(AssertionError("ran"))) is False
    marker = steps.marker("fit-prior")
    assert marker["params"] == steps.digest(params(b)) and marker["seconds"] == 7.0  # now portable, time kept
    assert Steps(tmp_path / "c").digest(params(tmp_path / "c")) == marker["params"]


def test_store_rebase_moves_keys_paths_and_options_inside_the_folder_only(tmp_path: Path) -> None:
    a, b = "/old/run", "/new/run"
    with ResultsStore(tmp_path / "r.sqlite") as store:
        store.upsert_episodes([
            episode(run=f"{a}/runs/cat-s0", dataset=f"{a}/data", scenario_id="s1", success=1),
            episode(run=f"{b}/runs/cat-s0", dataset=f"{b}/data", scenario_id="s1", success=0),  # re-made after a move
            episode(run=f"{a}/runs/cat-s0", dataset=f"{a}/data", scenario_id="s2"),
            episode(run="replay", dataset=f"{a}/data", scenario_id="s1"),
            episode(run="/old/run2/runs/x", dataset="/elsewhere/data", scenario_id="s1"),
        ])
        store.upsert_run(f"{a}/runs/cat-s0", "cat", 0, "td3", f"{a}/runs/cat-s0", {"dataset": f"{a}/data"})
        store.upsert_setting(f"{a}/data", "cat", "generator", "eval", "cat", {"prior": f"{a}/models/prior.pt"}, 5)
        changed = store.rebase_paths(a, b)
        rows = {(e["run"], e["dataset"], e["scenario_id"]): e for e in store.episodes()}
        assert set(rows) == {(f"{b}/runs/cat-s0", f"{b}/data", "s1"), (f"{b}/runs/cat-s0", f"{b}/data", "s2"),
                             ("replay", f"{b}/data", "s1"), ("/old/run2/runs/x", "/elsewhere/data", "s1")}
        assert rows[(f"{b}/runs/cat-s0", f"{b}/data", "s1")]["success"] == 1  # the moved row replaced the clash
        (run_row,) = store.runs()
        assert (run_row["run"], run_row["path"], run_row["config"]) == (
            f"{b}/runs/cat-s0", f"{b}/runs/cat-s0", {"dataset": f"{b}/data"})
        (setting,) = store.settings()
        assert (setting["dataset"], setting["kwargs"]) == (f"{b}/data", {"prior": f"{b}/models/prior.pt"})
        assert changed == 7  # episode keys: 2 runs + 3 datasets; 1 run row; 1 setting row
        assert store.rebase_paths(a, b) == 0  # nothing left to move


def test_a_copied_run_folder_runs_nothing_again_and_its_records_follow_it(tmp_path: Path) -> None:
    preset = write_preset(tmp_path)
    a, b = tmp_path / "a", tmp_path / "b"
    run(preset, a, FakeTasks())
    with ResultsStore(a / "results.sqlite") as store:
        n_rows = store.count()
    shutil.copytree(a, b)
    shutil.rmtree(a)  # nothing of the old folder is there to be read by mistake

    status = run_status(preset, b)
    assert status["moved_from"] == [str(a)] and "run from" in format_status(status)
    assert {s["state"] for s in status["steps"]} == {"done"}
    assert status["evaluation"]["rows"] == n_rows

    tasks = FakeTasks()
    summary = run(preset, b, tasks)
    assert tasks.calls == [] and summary["steps_ran"] == [] and "eval" in summary["steps_skipped"]
    assert summary["train_jobs"] == 0
    with ResultsStore(b / "results.sqlite") as store:
        assert store.count() == n_rows
        assert all(str(a) not in e["run"] and str(a) not in e["dataset"] for e in store.episodes())
    config = yaml.safe_load((b / "runs" / "cat-s0" / "config.yaml").read_text())
    assert config["dataset"] == str(b / "data")
    assert json.loads((b / "steps" / LOCATION).read_text()) == {"out": str(b), "previous": [str(a)]}
    after = run_status(preset, b)
    assert after["moved_from"] == [] and "run from" not in format_status(after)  # relocated: nothing to say


def test_a_folder_that_never_moved_is_left_as_it_is(tmp_path: Path) -> None:
    preset = write_preset(tmp_path)
    out = tmp_path / "out"
    run(preset, out, FakeTasks())
    assert recorded_roots(out) == []
    assert relocate(out) == []
    assert json.loads((out / "steps" / LOCATION).read_text()) == {"out": str(out), "previous": []}


def test_a_folder_without_records_of_its_path_is_found_from_its_store(tmp_path: Path) -> None:
    # A first run stopped before its summary, from before location.json: the store's run paths say where it was.
    preset = write_preset(tmp_path)
    a, b = tmp_path / "a", tmp_path / "b"
    run(preset, a, FakeTasks())
    (a / "summary.json").unlink()
    (a / "steps" / LOCATION).unlink()
    shutil.copytree(a, b)
    assert recorded_roots(b) == [str(a)]
    moved = relocate(b)
    assert [m.old for m in moved] == [str(a)] and moved[0].store_rows > 0 and moved[0].run_configs == 4
