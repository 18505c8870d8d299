"""A fit that labels against a trained ego of the same plan (``"${runs.NAME}"`` in its options, issue 16: pi_score
labelled by SEAL against learning egos): it runs after that run, and the runs whose generator needs its model after
it; the plan check refuses runs that are not in the plan or that need the fit themselves."""

from __future__ import annotations

from pathlib import Path

import pytest
from run_builders import FakeTasks, fake_train, run, write_preset

from seal.experiments.pipeline.references import late_fits, late_runs


def _preset(tmp_path: Path, egos: list[str], seeds=(0,)) -> Path:
    return write_preset(
        tmp_path, seeds=seeds,
        fit={"prior": {"epochs": 1, "no_progress": True},
             "objective": {"preset": "quick", "prior": "${fit.prior}", "behavior": "replay", "egos": egos}},
        generators={"cat": {"prior": "${fit.prior}", "follow": "replay"},
                    "seal": {"prior": "${fit.prior}", "objective": "${fit.objective}/objective.pt"}},
        pipelines=["noadv", "cat", "seal"])


def _recording(tasks: FakeTasks):
    def train(job) -> dict:
        tasks.calls.append(("train", job["name"]))
        return fake_train(job)
    return train


def test_an_objective_labelled_against_a_trained_ego_fits_between_the_trainings(tmp_path: Path) -> None:
    preset = _preset(tmp_path, ["heuristic", "${runs.noadv-s0}"])
    out = tmp_path / "out"
    tasks = FakeTasks()
    summary = run(preset, out, tasks, train=_recording(tasks))
    order = [c[0] if c[0] != "train" else c[1] for c in tasks.calls if c[0] in ("prior", "objective", "train")]
    assert order == ["prior", "noadv-s0", "cat-s0", "objective", "seal-s0"]
    objective = next(c for c in tasks.calls if c[0] == "objective")
    assert objective[3]["egos"] == ["heuristic", str(out.resolve() / "runs" / "noadv-s0")]
    assert summary["train_jobs"] == 3 and len(summary["runs"]) == 3 and not summary["errors"]

    before = len(tasks.calls)
    run(preset, out, tasks, train=_recording(tasks))
    assert len(tasks.calls) == before  # all done: nothing runs again


def test_late_fits_and_the_runs_waiting_for_them(tmp_path: Path) -> None:
    import yaml

    config = yaml.safe_load(_preset(tmp_path, ["${runs.cat-s0}"], seeds=(0, 1)).read_text())
    assert late_fits(config) == ["objective"]
    assert late_runs(config) == ["seal-s0", "seal-s1"]
    config["fit"]["objective"]["egos"] = ["heuristic"]
    assert late_fits(config) == [] and late_runs(config) == []


@pytest.mark.parametrize(("ego", "message"), [
    ("${runs.goose-s0}", "is not a training run of this plan"),
    ("${runs.seal-s0}", "a circle"),
])
def test_the_plan_refuses_a_run_it_cannot_train_first(tmp_path: Path, ego: str, message: str) -> None:
    tasks = FakeTasks()
    with pytest.raises(ValueError, match=message):
        run(_preset(tmp_path, ["heuristic", ego]), tmp_path / "out", tasks)
    assert tasks.calls == [] and not (tmp_path / "out").exists()  # checked before anything is written


def test_a_failed_labelling_run_leaves_the_fit_and_its_runs_for_the_next_time(tmp_path: Path) -> None:
    tasks = FakeTasks()
    with pytest.raises(RuntimeError, match="did not finish"):
        run(_preset(tmp_path, ["${runs.noadv-s13}"], seeds=(13,)), tmp_path / "out", tasks, train=_recording(tasks))
    assert [c[0] for c in tasks.calls if c[0] == "objective"] == []
    assert ("train", "seal-s13") not in tasks.calls
