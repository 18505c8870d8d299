"""Fault injection: kill `seal` commands (SIGKILL / SIGTERM) in the middle of their work, then check that no
process is left behind and that running the command again gives exactly what an uninterrupted run gives."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and parent-death signals")

SEAL = [sys.executable, "-m", "seal"]


def _live_processes(match) -> list[int]:  # noqa: ANN001
    """Live (not zombie) processes, other than this one, for which ``match(cmdline, session_id)`` is true."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
        state, session = fields[0], int(fields[3])
        if match(cmdline, session) and state != "Z" and int(entry.name) != os.getpid():
            out.append(int(entry.name))
    return out


def _processes_mentioning(text: str) -> list[int]:
    """Live processes whose command line contains ``text``."""
    return _live_processes(lambda cmdline, _session: text in cmdline)


def _wait_gone(text: str, session: int, timeout_s: float = 15.0) -> list[int]:
    """Wait until no live process names ``text`` or belongs to ``session``; those left then (killed here)."""
    def left() -> list[int]:
        return _live_processes(lambda cmdline, sid: text in cmdline or sid == session)

    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if not left():
            return []
        time.sleep(0.1)
    stragglers = left()
    for pid in stragglers:  # never leave them behind, whatever the outcome
        os.kill(pid, signal.SIGKILL)
    return stragglers


def _kill_when(cmd: list[str], ready, sig: int, marker: str, timeout_s: float = 120.0) -> int:
    """Start ``cmd`` in a new session, send ``sig`` once ``ready()`` is true, wait for it and for every process
    naming ``marker`` or left in its session (its workers); the command's exit status."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + timeout_s
    try:
        while not ready():
            assert proc.poll() is None, "the command finished before it could be interrupted"
            assert time.monotonic() < deadline, "the command never reached the point of interruption"
            time.sleep(0.05)
    finally:
        proc.send_signal(sig)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            raise AssertionError(f"the command did not stop within 60 s of signal {sig}") from None
    assert _wait_gone(marker, proc.pid) == [], "worker processes outlived the killed command"
    return proc.returncode


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _shards(root: Path) -> dict[str, str]:
    return {p.name: _sha(p) for p in sorted((root / "shards").glob("*.npz"))}


GENERATE = ["data", "generate", "--n", "48", "--seed", "5", "--workers", "2", "--no-progress",
            "--layouts", "highway", "merge"]


@pytest.fixture(scope="module")
def whole_build(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The uninterrupted build every interrupted one is compared with."""
    whole = tmp_path_factory.mktemp("whole") / "ds"
    subprocess.run([*SEAL, *GENERATE, "--out", str(whole)], check=True, capture_output=True)
    return whole


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_generate_killed_then_resumed_equals_an_uninterrupted_build(
    tmp_path: Path, whole_build: Path, sig: int,
) -> None:
    args, whole, cut = GENERATE, whole_build, tmp_path / "cut"

    def one_shard_written() -> bool:
        state = cut / "build.json"
        return state.is_file() and len(json.loads(state.read_text()).get("shards", {})) >= 1

    _kill_when([*SEAL, *args, "--out", str(cut)], one_shard_written, sig, str(cut))
    assert not (cut / "manifest.json").exists()
    done = subprocess.run([*SEAL, *args, "--out", str(cut)], check=True, capture_output=True, text=True)
    assert "resum" in (done.stdout + done.stderr).lower()  # the user is told the build resumed
    assert _shards(cut) == _shards(whole)
    assert not list(cut.rglob("*.tmp"))  # no partial temp files left


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_score_killed_leaves_no_worker_and_a_rerun_scores_as_usual(
    tmp_path: Path, whole_build: Path, sig: int,
) -> None:
    data = tmp_path / "ds"
    subprocess.run(["cp", "-r", str(whole_build), str(data)], check=True)
    started = time.monotonic()

    def workers_busy() -> bool:
        return time.monotonic() - started > 2.5 or len(_processes_mentioning(str(data))) >= 3

    _kill_when([*SEAL, "data", "score", str(data), "--workers", "2", "--no-progress"], workers_busy, sig,
               str(data))
    manifest = json.loads((data / "manifest.json").read_text())
    assert "scores" not in manifest  # nothing half-recorded
    subprocess.run([*SEAL, "data", "score", str(data), "--workers", "2", "--no-progress"], check=True,
                   capture_output=True)
    copy = tmp_path / "copy"
    subprocess.run(["cp", "-r", str(data), str(copy)], check=True)
    subprocess.run([*SEAL, "data", "score", str(copy), "--workers", "1", "--no-progress"], check=True,
                   capture_output=True)
    with np.load(data / "scores.npz") as a, np.load(copy / "scores.npz") as b:
        for key in a.files:
            if key != "meta_json":
                np.testing.assert_array_equal(a[key], b[key], err_msg=key)


# ------------------------------------------------------------------------------------------------ seal train
TRAIN = ["train", "--config", "quick", "--pipeline", "cat", "--seed", "1", "--steps", "600", "--n-envs", "2",
         "--set", "checkpoint_every=200", "--set", "eval_every=0", "--set", "pipelines.cat={name: rule, kwargs: {}}",
         "--set", "hyperparams.td3={learning_starts: 30, batch_size: 16, net_arch: [16, 16], buffer_size: 2000, "
         "train_freq: 1, gradient_steps: 1}", "--no-progress"]
"""A tiny TD3 run in the closed loop (rule adversary) on 2 env workers: 600 steps, a checkpoint every 200."""


def _policy(run: Path) -> dict:
    import io
    import zipfile

    import torch

    with zipfile.ZipFile(run / "final_model.zip") as zf:
        return torch.load(io.BytesIO(zf.read("policy.pth")), weights_only=True)


def test_train_killed_by_either_signal_resumes_to_the_same_model(tmp_path: Path) -> None:
    """SIGKILL and SIGTERM right after the first checkpoint: no worker is left, SIGTERM exits with 130, and both
    resumed runs end with bit-identical weights (the checkpoint holds everything the rest of the run depends on;
    a resumed run restarts its envs' episodes, so it does not replay the uninterrupted run's trajectory)."""
    import csv

    import torch
    from train_fixtures import tiny_dataset

    data = tiny_dataset(tmp_path)
    finals = []
    for sig in (signal.SIGKILL, signal.SIGTERM):
        run = tmp_path / f"run-{sig.name}"
        pointer = run / "checkpoints" / "latest.json"
        code = _kill_when([*SEAL, *TRAIN, "--dataset", str(data), "--out", str(run)], pointer.is_file, sig, str(run))
        assert code == (-signal.SIGKILL if sig == signal.SIGKILL else 130)
        assert not (run / "done.json").exists()
        checkpoint = json.loads(pointer.read_text())["step"]
        resumed = subprocess.run([*SEAL, "train", "--resume", str(run), "--no-progress", "--json"], check=True,
                                 capture_output=True, text=True)
        done = json.loads(resumed.stdout)
        assert (done["steps"], done["resumed_from"]) == (600, checkpoint)
        steps = [int(r["time/total_timesteps"]) for r in csv.DictReader((run / "progress.csv").open())
                 if r["time/total_timesteps"]]
        assert steps == sorted(set(steps)) and steps[-1] <= 600  # rows after the checkpoint dropped, not doubled
        finals.append((checkpoint, _policy(run)))
    (from_kill, kill_policy), (from_term, term_policy) = finals
    assert from_kill == from_term == 200
    assert kill_policy.keys() == term_policy.keys()
    for key, value in kill_policy.items():
        assert torch.equal(value, term_policy[key]), key
