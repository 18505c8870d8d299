"""`seal run`'s prior fit goes on from a fit of the same settings that a session's end interrupted (the same model as
an uninterrupted fit: `tests/models/test_prior_model.py`), and starts over from a state of other settings."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import scenario_factory as sf

import seal.models.prior.train as train_mod
from seal.core.dataset import Dataset, write_dataset
from seal.experiments.pipeline.tasks import run_task


class _InterruptInEpoch2(logging.Handler):
    """Stands for the end of a session while epoch 2's line is logged (after epoch 1's state was saved)."""

    def emit(self, record: logging.LogRecord) -> None:
        if record.getMessage().startswith("epoch 2:"):
            raise KeyboardInterrupt


def test_the_prior_fit_resumes_an_interrupted_fit_of_the_same_settings_only(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture,
) -> None:
    monkeypatch.setattr(train_mod, "STATE_EVERY_S", 0.0)
    ds = tmp_path / "ds"
    write_dataset(ds, [sf.highway_scenario(i) for i in range(3)])
    Dataset.open(ds).update_manifest(splits={"train": [s.scenario_id for s in Dataset.open(ds).load()]})
    out = str(tmp_path / "prior.pt")
    options = {"split": "train", "epochs": 2, "no_time_budget": True, "no_progress": True}
    job = {"task": "fit", "model": "prior", "dataset": str(ds), "out": out, "options": options}
    caplog.set_level(logging.INFO, logger=train_mod.__name__)
    train_mod.logger.addHandler(interrupt := _InterruptInEpoch2())
    try:
        with pytest.raises(KeyboardInterrupt):
            run_task(job)
    finally:
        train_mod.logger.removeHandler(interrupt)
    assert train_mod.state_path(out).exists()

    caplog.clear()
    other = run_task({**job, "options": {**options, "epochs": 1}})  # other settings: from scratch, no error
    assert not any("resuming" in m for m in caplog.messages) and other["epochs_run"] == 1

    train_mod.logger.addHandler(interrupt)
    try:
        with pytest.raises(KeyboardInterrupt):
            run_task(job)
    finally:
        train_mod.logger.removeHandler(interrupt)
    caplog.clear()
    summary = run_task(job)
    assert any("resuming after epoch 1" in m for m in caplog.messages)
    assert summary["epochs_run"] == 2 and not train_mod.state_path(out).exists()
