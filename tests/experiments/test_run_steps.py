"""`run_steps`: fits run one after the other with one worker, side by side with more when neither uses the other's
model, never before the fits they use; a failure stops new starts and is raised."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import pytest
from run_builders import FakeTasks, run, write_preset

from seal.experiments.pipeline.steps import StepJob, Steps, run_steps


def _steps() -> list[StepJob]:
    # the decisive preset's shape: objective uses prior and skills, ego_skills uses skills
    after = {"goose": (), "prior": (), "skills": (), "objective": ("fit-prior", "fit-skills"),
             "ego_skills": ("fit-skills",), "behavior": ()}
    return [StepJob(f"fit-{n}", n, {}, deps) for n, deps in after.items()]


def test_one_worker_runs_the_steps_in_their_order() -> None:
    order: list[str] = []
    run_steps(_steps(), lambda s: order.append(s.name), workers=1)
    assert order == [s.name for s in _steps()]


def test_two_workers_overlap_independent_steps_and_keep_dependencies() -> None:
    events: list[tuple[str, str]] = []
    lock = threading.Lock()
    both_running = threading.Barrier(2, timeout=10)

    def one(step: StepJob) -> None:
        with lock:
            events.append(("start", step.name))
        if step.name in ("fit-goose", "fit-prior"):
            both_running.wait()  # the first two independent fits must run at the same time (else: timeout)
        time.sleep(0.01)
        with lock:
            events.append(("end", step.name))

    run_steps(_steps(), one, workers=2)
    at = {e: i for i, e in enumerate(events)}
    assert len(at) == 12
    for step in _steps():
        for dep in step.after:
            assert at[("end", dep)] < at[("start", step.name)]
    assert max(sum(1 for k, n in events[:i + 1] if k == "start") - sum(1 for k, n in events[:i + 1] if k == "end")
               for i in range(len(events))) == 2


def test_a_failure_stops_new_starts_and_is_raised_after_the_running_steps_end() -> None:
    ran: list[str] = []
    lock = threading.Lock()

    def one(step: StepJob) -> None:
        if step.name == "fit-prior":
            raise RuntimeError("step fit-prior failed: diverged")
        time.sleep(0.05)
        with lock:
            ran.append(step.name)

    with pytest.raises(RuntimeError, match="fit-prior failed"):
        run_steps(_steps(), one, workers=2)
    assert "fit-goose" in ran and "fit-objective" not in ran  # goose was running; objective needs the prior


def test_seal_run_with_two_fit_workers_fits_every_model_once(tmp_path: Path) -> None:
    preset = write_preset(tmp_path, backend={"fit_workers": 2},
                          generators={"cat": {"prior": "${fit.prior}"}, "seal": {
                              "prior": "${fit.prior}", "skills": "${fit.skills}"}},
                          pipelines=["noadv", "cat", "seal"])
    out = tmp_path / "out"
    tasks = FakeTasks()
    summary = run(preset, out, tasks)
    fitted = sorted(c[0] for c in tasks.calls if c[0] not in ("generate", "score", "split"))
    assert fitted == ["prior", "skills"] and not summary["errors"]
    assert all(Steps(out).marker(f"fit-{name}") is not None for name in fitted)
