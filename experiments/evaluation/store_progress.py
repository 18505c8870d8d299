"""A progress bar of the episodes an evaluation has scored, read from its results store.

Evaluation jobs that run in other processes (one job per ego in ``seal run``) write their rows into the shared
results store one scenario at a time, but report to the parent only when a whole job ends: minutes apart for a
large protocol. `StoreProgress` polls the store's row count from a background thread instead, so the bar moves with
every scored scenario and its rate reads in episodes per second.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

from seal.core.dataset import ALL, Dataset
from seal.experiments.evaluation.evaluate import Setting
from seal.experiments.evaluation.results_store import ResultsStore


def expected_rows(egos: Sequence[str], settings: Sequence[Setting], limit: int | None) -> int:
    """Rows an evaluation of ``egos`` on ``settings`` (at most ``limit`` scenarios each) writes when complete: one per
    ego, setting and scenario of the setting's split (every scenario of the dataset for split None / `ALL`)."""
    per_ego = 0
    for s in settings:
        ds = Dataset.open(s.dataset)
        n = len(ds) if s.split in (None, ALL) else len(ds.splits.get(s.split, []))
        per_ego += n if limit is None else min(n, int(limit))
    return len(egos) * per_ego


class StoreProgress:
    """``with StoreProgress(store, runs, settings, total): ...``: a tqdm bar of the rows of ``runs`` x ``settings`` in
    the results store ``store`` (out of ``total``; rows already there count from the start), updated every
    ``every_s`` seconds by a daemon thread and once more on exit."""

    def __init__(self, store: str | Path, runs: Sequence[str], settings: Sequence[str], total: int,
                 desc: str = "eval", every_s: float = 2.0, disable: bool = False, **tqdm_kwargs: Any) -> None:
        self.store, self.runs, self.settings = str(store), list(runs), list(settings)
        self.total, self.desc, self.every_s, self.disable = int(total), desc, float(every_s), disable
        self.tqdm_kwargs = tqdm_kwargs
        self.bar: Any = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def _count(self, store: ResultsStore) -> int:
        return store.count(run=self.runs, setting=self.settings)

    def __enter__(self) -> StoreProgress:
        from tqdm import tqdm

        with ResultsStore(self.store) as store:
            done = self._count(store)
        self.bar = tqdm(total=max(self.total, done), initial=done, desc=self.desc, unit="episode",
                        disable=self.disable, smoothing=0.1, **self.tqdm_kwargs)
        if not self.disable:
            self._thread = threading.Thread(target=self._poll, name="store-progress", daemon=True)
            self._thread.start()
        return self

    def _poll(self) -> None:
        with ResultsStore(self.store) as store:  # this thread's own connection (SQLite connections stay in theirs)
            while not self._stop.wait(self.every_s):
                self._advance(self._count(store))

    def _advance(self, done: int) -> None:
        if done > self.bar.n:
            if done > self.bar.total:
                self.bar.total = done
            self.bar.update(done - self.bar.n)

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        with ResultsStore(self.store) as store:
            self._advance(self._count(store))
        self.bar.close()
