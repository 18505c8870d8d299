"""Resumable per-scenario work in chunk files: simulate or label a list of scenarios in worker processes, one
``part_NNNNN.npz`` file per chunk, so a killed build resumes from its finished chunks.

A ``state.json`` in the chunk folder carries a fingerprint of the settings and scenarios; chunks written under
another fingerprint are discarded (the folder starts over), so a re-run never mixes results of different settings.
"""

from __future__ import annotations

import hashlib
import json
import logging
import multiprocessing as mp
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

from seal.core.atomic import atomic_write_json
from seal.core.workers import initializer

T = TypeVar("T")
logger = logging.getLogger(__name__)


def fingerprint(settings: Any) -> str:
    """Short (16 hex digits) SHA-256 digest of ``settings`` as JSON: dict key order does not matter, tuples count as
    lists, and values JSON cannot encode count by their ``str()`` (so a `pathlib.Path` is its path). The one
    fingerprint of the project: chunk folders, demonstrations, labels and the skill fit's resume checks use it."""
    return hashlib.sha256(json.dumps(settings, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run_chunked(
    items: Sequence[Any],
    folder: Path,
    settings_fingerprint: str,
    state: dict[str, Any],
    work: Callable[[tuple[Any, ...]], tuple[int, T]],
    work_args: tuple[Any, ...],
    save: Callable[[T, Path], None],
    workers: int,
    chunk_size: int,
    progress: bool,
    desc: str,
    start_over: bool = True,
) -> list[Path]:
    """Run ``work((i, chunk_i, *work_args)) -> (i, result)`` for every chunk of ``chunk_size`` items that has no
    file in ``folder`` yet, ``save(result, path)`` each (atomically, by the caller's writer); return every chunk's
    path, in item order.

    Args:
        items: what to split into chunks (e.g. scenarios).
        folder: chunk folder (created; emptied first when it holds chunks of another fingerprint).
        settings_fingerprint: `fingerprint` of everything the results depend on, the items included.
        state: extra fields for ``state.json`` (for people reading the folder).
        work: module-level function (spawned workers pickle it by name).
        work_args: arguments after the chunk index and items.
        save: writes one result.
        workers: processes (spawned, not forked: the parent may hold torch / OpenMP state that does not survive
            a fork); 1 runs in this process.
        chunk_size: items per chunk file.
        progress: show a tqdm bar labelled ``desc``.
        start_over: a folder holding chunks of another fingerprint is emptied (a run's own cache); False raises
            ValueError instead, leaving the folder as it is (a folder the user named, whose chunks another command
            wrote and may still need).

    Resuming / restarting is reported to this module's logger (INFO).
    """
    from tqdm import tqdm

    state_path = folder / "state.json"
    if folder.exists() and any(folder.glob("part_*.npz")):
        try:
            same = json.loads(state_path.read_text()).get("fingerprint") == settings_fingerprint
        except (OSError, json.JSONDecodeError):
            same = False
        if not same and not start_over:
            raise ValueError(f"{folder} holds chunks ({desc}) of other scenarios or settings (its state.json); "
                             "give another folder, or delete this one to rebuild it there")
        if not same:
            logger.info(f"{desc}: {folder} holds chunks of other scenarios or settings; starting over")
            shutil.rmtree(folder)
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_json(state_path, {"fingerprint": settings_fingerprint, "n_items": len(items),
                                   "chunk_size": chunk_size, **state})
    chunks = [list(items[i : i + chunk_size]) for i in range(0, len(items), chunk_size)]
    paths = [folder / f"part_{i:05d}.npz" for i in range(len(chunks))]
    todo = [i for i in range(len(chunks)) if not paths[i].exists()]
    if len(todo) < len(chunks):
        logger.info(f"{desc}: resuming, {len(chunks) - len(todo)} of {len(chunks)} chunks already done")
    pending = set(todo)
    bar = tqdm(total=len(items), desc=desc, unit="scenario", disable=not progress,
               initial=sum(len(c) for i, c in enumerate(chunks) if i not in pending))
    jobs = [(i, chunks[i], *work_args) for i in todo]
    if workers > 1 and len(jobs) > 1:
        init, init_args = initializer()  # workers die with this process (no orphans after a kill)
        with mp.get_context("spawn").Pool(min(workers, len(jobs)), init, init_args) as pool:
            for i, result in pool.imap_unordered(work, jobs):
                save(result, paths[i])
                bar.update(len(chunks[i]))
    else:
        for job in jobs:
            i, result = work(job)
            save(result, paths[i])
            bar.update(len(chunks[i]))
    bar.close()
    return paths
