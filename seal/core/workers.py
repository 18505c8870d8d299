"""Worker processes that die with their parent.

A pool worker blocked on its task pipe outlives a parent that was killed (``kill -9``, an out-of-memory kill):
it is re-parented to init and waits forever. `die_with_parent` is the initializer every process pool of seal
passes: on Linux it asks the kernel to SIGKILL the worker when its parent dies (``prctl(PR_SET_PDEATHSIG)``), and
exits at once if the parent is already gone. Elsewhere it does nothing (those platforms keep the old behaviour).

`torch_threads` gives a job process one torch thread without importing torch: a job whose egos and generators need
no torch (the heuristic / replay egos with rule or lane-candidate CAT generators) then never pays torch's import
(about 1 s of CPU) and interpreter teardown (a few tenths of a second) in every worker.
"""

from __future__ import annotations

import ctypes
import importlib.abc
import importlib.machinery
import importlib.util
import os
import signal
import sys
from collections.abc import Callable, Sequence
from types import ModuleType
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


def torch_threads(n: int) -> None:
    """torch's intra-op threads to ``n`` in this process: now if torch is imported, otherwise right after its first
    import (a one-shot import hook), so a process that never needs torch never imports it.

    Equivalent to ``import torch; torch.set_num_threads(n)`` for everything that uses torch afterwards (same thread
    count, so the same results), without the import. A later call replaces a pending hook's count."""
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(int(n))
        return
    for finder in sys.meta_path:
        if isinstance(finder, _TorchThreadsOnImport):
            finder.threads = int(n)
            return
    sys.meta_path.insert(0, _TorchThreadsOnImport(int(n)))


class _TorchThreadsOnImport(importlib.abc.MetaPathFinder):
    """Finds nothing itself: on the first ``import torch`` it removes itself, lets the other finders find torch and
    wraps the loader so that ``torch.set_num_threads(threads)`` runs once torch's ``__init__`` has."""

    def __init__(self, threads: int) -> None:
        self.threads = threads

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname != "torch":
            return None
        if self in sys.meta_path:
            sys.meta_path.remove(self)  # one shot, and no recursion through the lookup below
        spec = importlib.util.find_spec("torch")
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        loader, threads = spec.loader, self.threads
        exec_module = loader.exec_module

        def exec_then_limit(module: ModuleType) -> None:
            exec_module(module)
            module.set_num_threads(threads)

        loader.exec_module = exec_then_limit  # type: ignore[method-assign]  # this spec's own loader instance
        return spec
