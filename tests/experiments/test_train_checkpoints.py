"""Damaged checkpoints on `seal train --resume` (issue 24): a corrupt ``latest.json`` is named and the run falls
back to the newest complete checkpoint (saying so); a damaged file of the checkpoint is named in one line."""

from __future__ import annotations

import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
from train_fixtures import tiny_dataset, tiny_train_config

from seal.cli import main
from seal.experiments.training import state as ts

KILL_AT = 100
"""The killed run's last checkpoint is step_80 (checkpoints every 40 steps); step_40 keeps no replay buffer."""


@pytest.fixture(scope="module")
def killed_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny one-worker TD3 run stopped at step 100 (an exception in a callback, as a kill would)."""
    from seal.experiments.training import callbacks as train_callbacks
    from seal.experiments.training.train import train_run

    tmp = tmp_path_factory.mktemp("killed")
    config = tiny_train_config(tiny_dataset(tmp))
    config.update(n_envs=1, eval_every=0)
    original = train_callbacks.EpisodeStatsCallback._on_step

    def killing_on_step(self: train_callbacks.EpisodeStatsCallback) -> bool:
        if self.num_timesteps >= KILL_AT:
            raise KeyboardInterrupt
        return original(self)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(train_callbacks.EpisodeStatsCallback, "_on_step", killing_on_step)
        with pytest.raises(KeyboardInterrupt):
            train_run(config, tmp / "run", progress=False)
    return tmp / "run"


@pytest.fixture()
def run(killed_run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(killed_run, copy)
    return copy


def _resume(run: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    capsys.readouterr()
    code = main(["train", "--resume", str(run), "--no-progress"])
    return code, capsys.readouterr().err


def test_the_killed_run_has_two_checkpoints(killed_run: Path) -> None:
    root = killed_run / ts.CHECKPOINTS
    assert sorted(p.name for p in root.glob("step_*")) == ["step_40", "step_80"]
    assert (root / "step_80" / "replay_buffer.npz").is_file()
    assert not (root / "step_40" / "replay_buffer.npz").exists()
    assert ts.latest_checkpoint(killed_run) == root / "step_80"


@pytest.mark.parametrize("damage", ["{not json", "[1, 2]", '{"step": 80}', '{"dir": "step_999", "step": 999}'])
def test_a_corrupt_latest_json_is_named_and_the_run_falls_back(
    run: Path, damage: str, capsys: pytest.CaptureFixture[str],
) -> None:
    pointer = run / ts.CHECKPOINTS / ts.LATEST
    pointer.write_text(damage)
    code, err = _resume(run, capsys)
    assert code == 0, err
    assert str(pointer) in err and "resuming from the previous complete checkpoint" in err
    assert str(run / ts.CHECKPOINTS / "step_80") in err
    done = ts.read_done(run)
    assert (done["steps"], done["resumed_from"]) == (160, 80)


def _truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


@pytest.mark.parametrize("name", ["replay_buffer.npz", "model.zip", "rng.npz", "worker_0.npz", "state.json"])
def test_a_damaged_checkpoint_file_is_named_in_one_line(
    run: Path, name: str, capsys: pytest.CaptureFixture[str],
) -> None:
    """step_40 keeps no replay buffer: an off-policy run cannot fall back to it, so the user is told which file is
    damaged and what to do, and nothing of the run changes."""
    damaged = run / ts.CHECKPOINTS / "step_80" / name
    _truncate(damaged)
    progress_before = (run / ts.PROGRESS).read_bytes()
    code, err = _resume(run, capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert str(damaged) in lines[0] and "delete" in lines[0] and "Traceback" not in err
    assert not (run / ts.DONE).exists() and (run / ts.PROGRESS).read_bytes() == progress_before


# ------------------------------------------------------------------------- synthetic checkpoint folders
def _zip(path: Path, members: dict[str, bytes]) -> None:
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)


def _fake_checkpoint(root: Path, step: int, buffer: bool = False, workers: int = 2) -> Path:
    """A checkpoint folder whose files have the right names and formats (contents are not a real model)."""
    folder = root / ts.CHECKPOINTS / f"step_{step}"
    folder.mkdir(parents=True)
    (folder / "state.json").write_text(json.dumps({"step": step, "n_workers": workers}))
    _zip(folder / "model.zip", {"data": b"{}", "policy.pth": b"weights" * 10})
    np.savez(folder / "rng.npz", torch=np.zeros(3))
    for i in range(workers):
        np.savez(folder / f"worker_{i}.npz", meta=np.zeros(2))
    if buffer:
        np.savez(folder / "replay_buffer.npz", actions=np.arange(10.0))
    return folder


def _point(root: Path, step: int) -> None:
    (root / ts.CHECKPOINTS / ts.LATEST).write_text(json.dumps({"step": step, "dir": f"step_{step}"}))


def test_no_checkpoint_yet(tmp_path: Path) -> None:
    assert ts.latest_checkpoint(tmp_path) is None
    (tmp_path / ts.CHECKPOINTS).mkdir()
    assert ts.latest_checkpoint(tmp_path) is None


def test_the_pointer_wins_over_newer_folders_and_complete_folders_are_accepted(tmp_path: Path) -> None:
    """A kill between a checkpoint's rename and its pointer leaves a newer complete folder: the pointer decides."""
    _fake_checkpoint(tmp_path, 40)
    named = _fake_checkpoint(tmp_path, 80, buffer=True)
    _fake_checkpoint(tmp_path, 120, buffer=True)
    _point(tmp_path, 80)
    assert ts.latest_checkpoint(tmp_path) == named
    assert ts.checkpoint_problem(named, {"replay_buffer.npz"}) is None


def test_without_a_pointer_the_newest_complete_folder_is_used(
    tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    _fake_checkpoint(tmp_path, 40)
    newest = _fake_checkpoint(tmp_path, 120)
    _fake_checkpoint(tmp_path, 80)
    with caplog.at_level("WARNING", logger="seal.experiments.training.state"):
        assert ts.latest_checkpoint(tmp_path) == newest
    assert "latest.json is missing" in caplog.text and "step_120" in caplog.text


def test_a_damaged_checkpoint_falls_back_when_the_previous_one_is_whole(
    tmp_path: Path, caplog: pytest.LogCaptureFixture,
) -> None:
    """An on-policy run (no replay buffer): a damaged model.zip of the newest checkpoint sends it one back."""
    previous = _fake_checkpoint(tmp_path, 40)
    newest = _fake_checkpoint(tmp_path, 80)
    _point(tmp_path, 80)
    _truncate(newest / "model.zip")
    with caplog.at_level("WARNING", logger="seal.experiments.training.state"):
        assert ts.latest_checkpoint(tmp_path) == previous
    assert f"{newest / 'model.zip'} is damaged" in caplog.text and str(previous) in caplog.text


@pytest.mark.parametrize("damage", ["truncate", "flip", "remove"])
def test_each_file_of_a_checkpoint_is_checked(tmp_path: Path, damage: str) -> None:
    folder = _fake_checkpoint(tmp_path, 80, buffer=True, workers=2)
    for name in ("model.zip", "rng.npz", "worker_0.npz", "worker_1.npz", "replay_buffer.npz"):
        path = folder / name
        original = path.read_bytes()
        if damage == "truncate":
            _truncate(path)
        elif damage == "flip":  # one byte of the stored data: only the CRC check sees it
            data = bytearray(original)
            at = original.index(b"weights") if name == "model.zip" else len(original) // 3
            data[at] ^= 0xFF
            path.write_bytes(bytes(data))
        else:
            path.unlink()
        problem = ts.checkpoint_problem(folder, {"replay_buffer.npz"})
        assert problem is not None and problem.startswith(str(path)), (name, problem)
        assert ("missing" in problem) == (damage == "remove")
        path.write_bytes(original)
    assert ts.checkpoint_problem(folder, {"replay_buffer.npz"}) is None
    (folder / "state.json").write_text('{"step": 80}')  # no worker count
    assert ts.checkpoint_problem(folder) == f"{folder / 'state.json'} is damaged (KeyError: 'n_workers')"


def test_no_usable_checkpoint_names_every_problem(tmp_path: Path) -> None:
    old = _fake_checkpoint(tmp_path, 40)
    new = _fake_checkpoint(tmp_path, 80, buffer=True)
    _point(tmp_path, 80)
    _truncate(new / "replay_buffer.npz")
    with pytest.raises(ts.CheckpointError) as info:
        ts.latest_checkpoint(tmp_path)
    message = str(info.value)
    assert f"{new / 'replay_buffer.npz'} is damaged" in message
    assert f"{old / 'replay_buffer.npz'} is missing" in message
    assert message.endswith(f"delete {tmp_path / ts.CHECKPOINTS} to restart the run from step 0")


def test_stray_folders_are_not_checkpoints(tmp_path: Path) -> None:
    """Folders and files whose names only start like a checkpoint's (a user's copy, a stray file) are passed over."""
    newest = _fake_checkpoint(tmp_path, 80)
    root = tmp_path / ts.CHECKPOINTS
    for stray in ("step_x0", "step_80_old", "step_"):
        (root / stray).mkdir()
    (root / "step_90").write_text("not a folder")
    assert ts.latest_checkpoint(tmp_path) == newest


def test_checkpoints_are_ordered_by_their_step_number(tmp_path: Path) -> None:
    _fake_checkpoint(tmp_path, 7500)
    newest = _fake_checkpoint(tmp_path, 10000)
    assert ts.latest_checkpoint(tmp_path) == newest


@pytest.mark.parametrize("name", ["backup", "step_40/../backup"])
def test_a_pointer_outside_the_checkpoint_folders_is_not_followed(
    tmp_path: Path, name: str, caplog: pytest.LogCaptureFixture,
) -> None:
    """``latest.json`` names only a ``step_<N>`` folder of its own directory, even when another complete
    checkpoint sits where it points."""
    _fake_checkpoint(tmp_path, 40)
    newest = _fake_checkpoint(tmp_path, 80)
    root = tmp_path / ts.CHECKPOINTS
    shutil.copytree(newest, root / "backup")
    (root / ts.LATEST).write_text(json.dumps({"step": 40, "dir": name}))
    with caplog.at_level("WARNING", logger="seal.experiments.training.state"):
        assert ts.latest_checkpoint(tmp_path) == newest
    assert f"names {name!r}, not a checkpoint folder" in caplog.text


def test_every_model_file_of_a_checkpoint_is_checked(tmp_path: Path) -> None:
    """The extra models of a ReSkill checkpoint (``<name>.zip``) are read back like ``model.zip``."""
    folder = _fake_checkpoint(tmp_path, 80)
    _zip(folder / "residual.zip", {"data": b"{}", "policy.pth": b"weights" * 10})
    assert ts.checkpoint_problem(folder) is None
    _truncate(folder / "residual.zip")
    problem = ts.checkpoint_problem(folder)
    assert problem is not None and problem.startswith(f"{folder / 'residual.zip'} is damaged")


def test_a_model_file_cut_after_an_inner_archive_is_damaged(tmp_path: Path) -> None:
    """An SB3 model zip stores torch archives (zips) as members: cut right after one, the file opens as that
    inner archive, every CRC passes, and only the missing ``data`` entry shows the damage."""
    import io

    inner = io.BytesIO()
    with zipfile.ZipFile(inner, "w") as zf:
        zf.writestr("archive/data.pkl", b"tensor bytes" * 20)
    folder = _fake_checkpoint(tmp_path, 80)
    model = folder / "model.zip"
    with zipfile.ZipFile(model, "w") as zf:  # SB3's layout: data first, then the torch archives, stored
        zf.writestr("data", b"{}")
        zf.writestr("policy.pth", inner.getvalue())
        zf.writestr("_stable_baselines3_version", b"2.9.2")
    blob = model.read_bytes()
    with zipfile.ZipFile(model) as zf:
        info = zf.getinfo("policy.pth")
    at = info.header_offset  # a local header: 30 bytes, then the name and the extra field (lengths at 26 and 28)
    name_len, extra_len = (int.from_bytes(blob[at + k: at + k + 2], "little") for k in (26, 28))
    end = at + 30 + name_len + extra_len + info.compress_size
    model.write_bytes(blob[:end])
    with zipfile.ZipFile(model) as zf:
        assert zf.namelist() == ["archive/data.pkl"] and zf.testzip() is None  # opens as the inner archive
    assert ts.checkpoint_problem(folder) == (f"{model} is damaged (BadZipFile: no 'data' entry (a truncated "
                                             "Stable-Baselines3 file))")
