"""A full disk in the middle of `seal data generate` and `seal train` (issue 24): one line naming the file, exit
code 2, no partial temp file or checkpoint folder left, and the command completes when run again."""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from seal.cli import main
from seal.core.dataset import Dataset


class _Disk:
    """Replaces ``os.fsync``: raises ENOSPC while `full` (a write that only fails when flushed to the device)."""

    def __init__(self) -> None:
        self.full = False
        self.failed = 0
        self._fsync = os.fsync

    def __call__(self, fd: int) -> None:
        if self.full:
            self.failed += 1
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._fsync(fd)


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("seal: error: ") and "Traceback" not in err[0], err
    return err[0]


def test_generate_on_a_full_disk(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                 monkeypatch: pytest.MonkeyPatch) -> None:
    disk = _Disk()
    disk.full = True
    monkeypatch.setattr(os, "fsync", disk)
    out = tmp_path / "ds"
    args = ["data", "generate", "--n", "4", "--seed", "3", "--workers", "1", "--no-progress", "--out", str(out)]
    assert main(args) == 2
    line = _one_line(capsys)
    assert "No space left on device" in line and str(out) in line and disk.failed >= 1
    assert not [p for p in tmp_path.rglob("*") if p.is_file() and p.name.endswith(".tmp")]
    assert not (out / "manifest.json").exists()
    disk.full = False  # space freed: the same command completes
    assert main(args) == 0
    assert len(Dataset.open(out).load()) == 4


def test_train_on_a_full_disk_keeps_the_previous_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:
    from train_fixtures import tiny_dataset

    from seal.experiments.training import state as ts

    disk = _Disk()
    monkeypatch.setattr(os, "fsync", disk)
    original = ts._write_checkpoint_files

    def filling_up(tmp: Path, step: int, *args: object) -> None:
        disk.full = step == 80  # the disk fills up during the second checkpoint
        original(tmp, step, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(ts, "_write_checkpoint_files", filling_up)
    run = tmp_path / "run"
    assert main(["train", "--config", "quick", "--pipeline", "cat", "--seed", "1", "--steps", "160", "--n-envs", "1",
                 "--dataset", str(tiny_dataset(tmp_path)), "--set", "checkpoint_every=40", "--set", "eval_every=0",
                 "--set", "pipelines.cat={name: rule, kwargs: {}}",
                 "--set", "hyperparams.td3={learning_starts: 30, batch_size: 16, net_arch: [16, 16], buffer_size: 400}",
                 "--no-progress", "--out", str(run)]) == 2
    line = _one_line(capsys)
    assert "No space left on device" in line and str(run / ts.CHECKPOINTS / "step_80") in line
    assert "previous checkpoint stays in force" in line
    checkpoints = run / ts.CHECKPOINTS
    assert sorted(p.name for p in checkpoints.iterdir()) == [ts.LATEST, "step_40"]  # no partial folder
    assert not [p for p in run.rglob("*") if p.name.endswith(".tmp")]
    disk.full = False
    monkeypatch.setattr(ts, "_write_checkpoint_files", original)
    assert main(["train", "--resume", str(run), "--no-progress"]) == 0
    done = ts.read_done(run)
    assert (done["steps"], done["resumed_from"]) == (160, 40)
