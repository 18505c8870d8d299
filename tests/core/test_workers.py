"""Pool workers die with their parent (no orphans blocked on a pipe after ``kill -9`` of the command)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="parent-death signal is Linux-only")

PARENT = """
import multiprocessing as mp, sys, time
from seal.core.workers import initializer

def nap(_):
    time.sleep(120)

if __name__ == "__main__":
    init, args = initializer() if sys.argv[1] == "guarded" else (None, ())
    ctx = mp.get_context(sys.argv[2])
    pool = ctx.Pool(2, init, args)
    pool.map_async(nap, range(2))
    time.sleep(1.0)
    print(" ".join(str(p.pid) for p in pool._pool), flush=True)
    time.sleep(120)
"""


def _alive(pid: int) -> bool:
    """Running or sleeping (a zombie left for init to reap counts as dead)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


def _orphans_after_kill(tmp_path: Path, mode: str, context: str) -> list[int]:
    script = tmp_path / "parent.py"
    script.write_text(PARENT)
    parent = subprocess.Popen([sys.executable, str(script), mode, context], stdout=subprocess.PIPE, text=True)
    try:
        assert parent.stdout is not None
        pids = [int(p) for p in parent.stdout.readline().split()]
        assert len(pids) == 2 and all(_alive(p) for p in pids)
    finally:
        parent.send_signal(signal.SIGKILL)
        parent.wait()
    deadline = time.monotonic() + 10.0
    while time.monotonic() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.1)
    left = [p for p in pids if _alive(p)]
    for p in left:  # never leave them behind, whatever the outcome
        os.kill(p, signal.SIGKILL)
    return left


@pytest.mark.parametrize("context", ["fork", "spawn"])
def test_workers_die_with_a_killed_parent(tmp_path: Path, context: str) -> None:
    assert _orphans_after_kill(tmp_path, "guarded", context) == []


def test_without_the_initializer_workers_are_orphaned(tmp_path: Path) -> None:
    """The check has teeth: a plain pool's workers outlive a killed parent."""
    assert len(_orphans_after_kill(tmp_path, "plain", "fork")) == 2


TORCH_THREADS = """
import sys
from seal.core.workers import torch_threads

torch_threads(3)
torch_threads(1)  # replaces the pending count
assert "torch" not in sys.modules
import torch

assert torch.get_num_threads() == 1, torch.get_num_threads()
torch_threads(2)  # torch imported: set at once
assert torch.get_num_threads() == 2
print("ok")
"""


def test_torch_threads_applies_at_torch_import_without_importing_it() -> None:
    """`torch_threads` before torch is imported: no import, and the count applies when torch is first imported."""
    out = subprocess.run([sys.executable, "-c", TORCH_THREADS], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"
