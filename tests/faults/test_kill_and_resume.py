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


def _processes_mentioning(text: str) -> list[int]:
    """Live (not zombie) processes whose command line contains ``text``."""
    out = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except (FileNotFoundError, ProcessLookupError, PermissionError):
            continue
        if text in cmdline and state != "Z" and int(entry.name) != os.getpid():
            out.append(int(entry.name))
    return out


def _wait_gone(text: str, timeout_s: float = 15.0) -> list[int]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        left = _processes_mentioning(text)
        if not left:
            return []
        time.sleep(0.1)
    left = _processes_mentioning(text)
    for pid in left:  # never leave them behind, whatever the outcome
        os.kill(pid, signal.SIGKILL)
    return left


def _kill_when(cmd: list[str], ready, sig: int, marker: str, timeout_s: float = 120.0) -> None:
    """Start ``cmd``, send ``sig`` once ``ready()`` is true, wait for it and for every process naming ``marker``."""
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.monotonic() + timeout_s
    try:
        while not ready():
            assert proc.poll() is None, "the command finished before it could be interrupted"
            assert time.monotonic() < deadline, "the command never reached the point of interruption"
            time.sleep(0.05)
    finally:
        proc.send_signal(sig)
        proc.wait(timeout=60)
    assert _wait_gone(marker) == [], "worker processes outlived the killed command"


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
