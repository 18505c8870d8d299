"""A finished fit whose settings the code now resolves otherwise (a default changed since): kept as fitted, and said
by `seal run` (a warning) and `--status` (a line under the step)."""

from __future__ import annotations

import logging
from pathlib import Path

import yaml
from run_builders import FakeTasks, run, write_preset

from seal.experiments.pipeline.drift import describe_drift, fit_drift, settings_drift
from seal.experiments.pipeline.status import format_status, run_status
from seal.experiments.pipeline.steps import StepJob
from seal.experiments.pipeline.tasks import FIT_CONFIGS

OBJECTIVE_OPTIONS = {"preset": "quick", "prior": "/models/prior.pt", "behavior": "seal", "skills": "/models/skills"}


def _recorded(options: dict, out: Path, **changes) -> None:
    """Write ``out/config.yaml`` as ``seal fit objective`` records it, with ``changes`` as the values of then."""
    settings = {**FIT_CONFIGS["objective"](options).to_dict(), "dataset": "/data", "out": str(out), **changes}
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(yaml.safe_dump(settings, sort_keys=True))


def test_settings_drift_reports_values_that_changed_but_not_paths_machines_or_new_keys() -> None:
    recorded = {"a": 1, "b": {"c": 2, "d": "/old/place/p.pt", "e": [1, 2]}, "workers": 2, "gone": 1,
                "egos": ["heuristic/x", "/old/runs/r"]}
    resolved = {"a": 1, "b": {"c": 3, "d": "/new/place/p.pt", "e": [1, 3]}, "workers": 4, "new": 5,
                "egos": ["heuristic/x", "/new/runs/r"]}
    assert settings_drift(recorded, resolved) == [("b.c", 2, 3), ("b.e", [1, 2], [1, 3])]
    assert settings_drift(recorded, recorded) == []
    assert describe_drift([("b.c", 2, 3), ("k", None, 10)]) == "b.c: 2 -> 3; k: None -> 10"


def test_fit_drift_of_an_objective_fit_made_before_a_default_changed(tmp_path: Path) -> None:
    out = tmp_path / "models" / "objective"
    step = StepJob("fit-objective", [], {"task": "fit", "model": "objective", "dataset": "/data", "out": str(out),
                                         "options": OBJECTIVE_OPTIONS})
    assert fit_drift(step) == []  # not fitted yet: nothing recorded
    now = FIT_CONFIGS["objective"](OBJECTIVE_OPTIONS).to_dict()
    _recorded(OBJECTIVE_OPTIONS, out)
    assert fit_drift(step) == []
    _recorded(OBJECTIVE_OPTIONS, out, adversarial_steps=None, workers=7, prior="/elsewhere/prior.pt")
    assert fit_drift(step) == [("adversarial_steps", None, now["adversarial_steps"])]
    # a fit without a settings file of its own (the prior) has none to compare
    assert fit_drift(StepJob("fit-prior", [], {"task": "fit", "model": "prior", "dataset": "/data",
                                               "out": str(tmp_path / "prior.pt"), "options": {}})) == []


class _ObjectiveFits(FakeTasks):
    """FakeTasks whose objective fit records its settings as `seal fit objective` does, with an old default."""

    def __call__(self, job) -> None:
        super().__call__(job) if job.get("model") != "objective" else self.calls.append(("objective",))
        if job.get("model") == "objective":
            _recorded(dict(job["options"]), Path(job["out"]), adversarial_steps=None)


def test_status_and_run_say_which_settings_drifted_and_keep_the_fit(tmp_path: Path, caplog) -> None:
    preset = write_preset(
        tmp_path, seeds=(0,),
        fit={"prior": {"epochs": 1, "no_progress": True},
             "objective": {"preset": "quick", "prior": "${fit.prior}", "behavior": "replay"}},
        generators={"cat": {"prior": "${fit.prior}", "follow": "replay"},
                    "seal": {"prior": "${fit.prior}", "objective": "${fit.objective}/objective.pt"}},
        pipelines=["seal"])
    out = tmp_path / "out"
    tasks = _ObjectiveFits()
    run(preset, out, tasks)
    steps = {s["name"]: s for s in run_status(preset, out)["steps"]}
    assert steps["fit-objective"]["state"] == "done"
    assert [change[:2] for change in steps["fit-objective"]["drift"]] == [("adversarial_steps", None)]
    assert steps["fit-prior"]["drift"] == []
    assert "fitted with settings the code now resolves otherwise" in format_status(run_status(preset, out))

    fitted = len(tasks.calls)
    caplog.clear()  # the first run's records (INFO ones too, when an earlier test set the seal logger's level)
    with caplog.at_level(logging.WARNING):
        run(preset, out, tasks)
    assert len(tasks.calls) == fitted  # kept as fitted: nothing ran again
    warned = [r.getMessage() for r in caplog.records
              if r.levelno >= logging.WARNING and "fit-objective" in r.getMessage()]
    assert len(warned) == 1 and "adversarial_steps: None -> 10" in warned[0]
