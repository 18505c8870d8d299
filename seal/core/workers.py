"""Worker processes that die with their parent.

A pool worker blocked on its task pipe outlives a parent that was killed (``kill -9``, an out-of-memory kill):
it is re-parented to init and waits forever. `die_with_parent` is the initializer every process pool of seal
passes: on Linux it asks the kernel to SIGKILL the worker when its parent dies (``prctl(PR_SET_PDEATHSIG)``), and
exits at once if the parent is already gone. Elsewhere it does nothing (those platforms keep the old behaviour).
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable
from typing import Any

_PR_SET_PDEATHSIG = 1  # from <linux/prctl.h>


def die_with_parent(parent_pid: int | None = None) -> None:
    """Make this (worker) process receive SIGKILL when its parent exits; ``parent_pid`` (the pool owner's pid,
    if known) lets it notice a parent that died before the request took effect."""
    if not sys.platform.startswith("linux"):
        return
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(1)  # the parent is already gone: nobody would read this worker's results


def initializer(then: Callable[..., Any] | None = None, *args: Any) -> tuple[Callable[..., Any], tuple[Any, ...]]:
    """``(initializer, initargs)`` for a process pool: `die_with_parent` for the current process, then ``then(*args)``
    if given."""
    return _init, (os.getpid(), then, args)


def _init(parent_pid: int, then: Callable[..., Any] | None, args: tuple[Any, ...]) -> None:
    die_with_parent(parent_pid)
    if then is not None:
        then(*args)
