"""The evaluation results store: one SQLite file holding every scored evaluation episode, the evaluated runs and
the configuration of each setting, so evaluations can be added incrementally and re-queried (`seal eval runs`,
`seal compare`, `seal run`).

Tables (schema version `SCHEMA_VERSION`, recorded in ``meta``):

* ``episodes``: one row per (run, dataset, setting, scenario_id), the scored episode of an ego on a scenario
  (`EPISODE_COLUMNS`): outcome flags, route completion, ego-adversary interaction (close call, collision speed
  along the contact normal in m/s, head-on flags), the adversary's realism (per-episode Wasserstein distances
  and the yaw-rate / acceleration histogram counts on `seal.scoring.realism`'s bins, so set-level distances can be
  computed from pooled episodes) and generation time.
* ``runs``: one row per evaluated ego (a trained run folder, or ``replay`` / ``heuristic``): pipeline, seed,
  path, its config as JSON.
* ``settings``: one row per (dataset, setting): which split and generator (with constructor kwargs) it used.

Concurrency: several processes (local workers, Ray tasks on one machine) may write at once. The database runs in
WAL mode with a busy timeout, and every write is one ``BEGIN IMMEDIATE`` transaction (the write lock is taken up
front, so two writers never deadlock upgrading read locks). Writes are upserts: re-inserting a key replaces it.
Queries return plain ``dict`` rows (no pandas).
"""

from __future__ import annotations

import json
import sqlite3
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from seal.core.errors import SealError
from seal.core.paths import rebase, rebase_tree

SCHEMA_VERSION = 1
BUSY_TIMEOUT_S = 120.0

EPISODE_KEY = ("run", "dataset", "setting", "scenario_id")
EPISODE_COLUMNS: dict[str, str] = {
    "run": "TEXT NOT NULL",  # run folder (absolute path) or a built-in ego name
    "dataset": "TEXT NOT NULL",  # dataset directory (absolute path)
    "setting": "TEXT NOT NULL",  # normal | hard | <generator name> | real:<dir>
    "scenario_id": "TEXT NOT NULL",
    "pipeline": "TEXT NOT NULL",  # training pipeline of the ego (noadv | goose | cat | seal | replay | ...)
    "seed": "INTEGER NOT NULL",
    "ego": "TEXT NOT NULL",
    "split": "TEXT",  # dataset split the scenario came from (None = whole dataset)
    "k": "INTEGER NOT NULL",  # perturbation passes (0 for replayed-adversary settings)
    "outcome": "TEXT NOT NULL",  # success | crash | out_of_road | timeout
    "success": "INTEGER NOT NULL",
    "crash": "INTEGER NOT NULL",
    "out_of_road": "INTEGER NOT NULL",
    "timeout": "INTEGER NOT NULL",
    "route_completion": "REAL NOT NULL",
    "episode_return": "REAL NOT NULL",
    "adv_collision": "INTEGER NOT NULL",  # the ego touched the adversary
    "min_gap_m": "REAL",  # closest body gap ego-adversary (m), NULL if never both present
    "close_call": "INTEGER NOT NULL",  # body gap <= CLOSE_CALL_M or a collision with the adversary
    "collision_speed_mps": "REAL",  # relative speed along the contact normal, NULL without a collision
    "head_on": "INTEGER NOT NULL",
    "severe_head_on": "INTEGER NOT NULL",
    "yaw_wd": "REAL",  # this episode's adversary vs its logged adversary (NULL when a sample is empty)
    "acc_wd": "REAL",
    "road_wd": "REAL",
    "realism": "REAL",
    "adv_offroad_share": "REAL NOT NULL",
    "log_offroad_share": "REAL NOT NULL",
    "adv_yaw_hist": "TEXT NOT NULL",  # JSON int counts on seal.scoring.realism.YAW_RATE_BINS
    "adv_acc_hist": "TEXT NOT NULL",  # JSON int counts on seal.scoring.realism.ACC_BINS
    "log_yaw_hist": "TEXT NOT NULL",
    "log_acc_hist": "TEXT NOT NULL",
    "generations": "INTEGER NOT NULL",  # generation calls for this scenario (K, or 0)
    "generation_ms_mean": "REAL",
    "generation_ms_max": "REAL",
    "created_at": "REAL NOT NULL",
}
HIST_COLUMNS = ("adv_yaw_hist", "adv_acc_hist", "log_yaw_hist", "log_acc_hist")

RUN_COLUMNS: dict[str, str] = {
    "run": "TEXT PRIMARY KEY",
    "pipeline": "TEXT NOT NULL",
    "seed": "INTEGER NOT NULL",
    "ego": "TEXT NOT NULL",
    "path": "TEXT",  # run folder, NULL for built-in egos
    "config": "TEXT NOT NULL",  # JSON
    "updated_at": "REAL NOT NULL",
}
SETTING_COLUMNS: dict[str, str] = {
    "dataset": "TEXT NOT NULL",
    "setting": "TEXT NOT NULL",
    "kind": "TEXT NOT NULL",  # replay | generator
    "split": "TEXT",
    "generator": "TEXT",
    "kwargs": "TEXT NOT NULL",  # JSON constructor kwargs of the generator
    "k": "INTEGER NOT NULL",
    "seed": "INTEGER NOT NULL",  # eval seed (episode and generator rng streams)
    "updated_at": "REAL NOT NULL",
}


TIMING_COLUMNS = ("created_at", "generation_ms_mean", "generation_ms_max")
"""Episode columns that hold wall-clock times: the only ones two evaluations of the same work may differ in."""


class StoreError(SealError, RuntimeError):
    """A results store that cannot be used (wrong schema version, not a results store)."""


def _create_sql() -> list[str]:
    cols = ", ".join(f"{k} {v}" for k, v in EPISODE_COLUMNS.items())
    return [
        "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
        f"CREATE TABLE IF NOT EXISTS episodes ({cols}, PRIMARY KEY ({', '.join(EPISODE_KEY)}))",
        "CREATE INDEX IF NOT EXISTS episodes_by_setting ON episodes (setting, pipeline, seed)",
        f"CREATE TABLE IF NOT EXISTS runs ({', '.join(f'{k} {v}' for k, v in RUN_COLUMNS.items())})",
        f"CREATE TABLE IF NOT EXISTS settings ({', '.join(f'{k} {v}' for k, v in SETTING_COLUMNS.items())}, "
        "PRIMARY KEY (dataset, setting))",
    ]


def _kwargs_json(kwargs: Mapping[str, Any]) -> str:
    """A setting's constructor options as the settings table stores them (paths and other objects as text)."""
    return json.dumps(dict(kwargs), sort_keys=True, default=str)


def _rebased_json(text: str, old: str, new: str, dump: Callable[[Any], str]) -> str:
    """The JSON ``text`` with its paths in ``old`` moved to ``new`` (`seal.core.paths.rebase_tree`), written by
    ``dump``; ``text`` itself when no path moves."""
    value = json.loads(text)
    moved = rebase_tree(value, old, new)
    return text if moved == value else dump(moved)


def _as_list(value: str | int | Iterable[Any] | None) -> list[Any] | None:
    if value is None:
        return None
    if isinstance(value, str | int):
        return [value]
    return list(value)


class ResultsStore:
    """A results store file (created on first open). Cheap to open; open one per process."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # isolation_level=None: no implicit transactions; writes use explicit BEGIN IMMEDIATE (see module doc).
        self._conn = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_S, isolation_level=None)
        self._conn.row_factory = sqlite3.Row
        self._conn.execute(f"PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}")
        try:
            self._conn.execute("PRAGMA journal_mode = WAL")
        except sqlite3.DatabaseError as exc:
            raise StoreError(f"{self.path} is not a SQLite results store ({exc}); choose another --store") from None
        self._conn.execute("PRAGMA synchronous = NORMAL")
        self._init_schema()

    # ------------------------------------------------------------------------------------------ plumbing
    @contextmanager
    def _write(self):
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            yield self._conn
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._conn.execute("COMMIT")

    def _init_schema(self) -> None:
        with self._write() as conn:
            for sql in _create_sql():
                conn.execute(sql)
            row = conn.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
            if row is None:
                conn.execute("INSERT INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
            elif int(row[0]) != SCHEMA_VERSION:
                raise StoreError(
                    f"{self.path}: results store schema version {row[0]}, this seal reads {SCHEMA_VERSION}; "
                    "use a new --store file"
                )

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> ResultsStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------------------------------ writes
    def upsert_episodes(self, rows: Sequence[Mapping[str, Any]]) -> int:
        """Insert or replace episode rows (one transaction); missing ``created_at`` is set to now. Histogram
        columns may be given as sequences of ints. Returns the number of rows written."""
        if not rows:
            return 0
        names = list(EPISODE_COLUMNS)
        now = time.time()
        values = []
        for row in rows:
            missing = [c for c in names if c not in row and c != "created_at"]
            if missing:
                raise ValueError(f"episode row for {row.get('scenario_id')!r}: missing column(s) {missing}")
            unknown = sorted(set(row) - set(names))
            if unknown:
                raise ValueError(f"episode row for {row.get('scenario_id')!r}: unknown column(s) {unknown}")
            values.append(tuple(_encode(c, row.get(c, now)) for c in names))
        sql = f"INSERT OR REPLACE INTO episodes ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})"
        with self._write() as conn:
            conn.executemany(sql, values)
        return len(values)

    def upsert_run(
        self, run: str, pipeline: str, seed: int, ego: str, path: str | None, config: Mapping[str, Any]
    ) -> None:
        """Record (or update) an evaluated ego."""
        with self._write() as conn:
            conn.execute(
                "INSERT OR REPLACE INTO runs VALUES (?, ?, ?, ?, ?, ?, ?)",
                (run, pipeline, int(seed), ego, path, json.dumps(config, sort_keys=True, default=str), time.time()),
            )

    def upsert_setting(
        self, dataset: str, setting: str, kind: str, split: str | None, generator: str | None,
        kwargs: Mapping[str, Any], k: int, seed: int = 0,
    ) -> None:
        """Record how ``setting`` on ``dataset`` was evaluated (the latest evaluation wins)."""
        with self._write() as conn:
            conn.execute(
                "INSERT OR REPLACE INTO settings VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (dataset, setting, kind, split, generator, _kwargs_json(kwargs),
                 int(k), int(seed), time.time()),
            )

    def rebase_paths(self, old: str, new: str) -> int:
        """Point every run and dataset key, run path and path in a run's config or a setting's options that lies in
        folder ``old`` at folder ``new`` (a moved or copied run folder, `seal.experiments.pipeline.location`); a row
        already stored under the new key is replaced by the moved one (the same ego on the same scenario). Returns
        the number of rows changed."""
        changed = 0
        with self._write() as conn:
            for column in ("run", "dataset"):
                for (value,) in conn.execute(f"SELECT DISTINCT {column} FROM episodes").fetchall():
                    moved = rebase(value, old, new)
                    if moved != value:
                        changed += conn.execute(
                            f"UPDATE OR REPLACE episodes SET {column} = ? WHERE {column} = ?", (moved, value)).rowcount
            for row in conn.execute("SELECT * FROM runs").fetchall():
                moved_row = {**dict(row), "run": rebase(row["run"], old, new),
                             "path": None if row["path"] is None else rebase(row["path"], old, new),
                             "config": _rebased_json(row["config"], old, new, lambda v: json.dumps(v, sort_keys=True))}
                changed += self._replace_row(conn, "runs", dict(row), moved_row, ("run",))
            for row in conn.execute("SELECT * FROM settings").fetchall():
                moved_row = {**dict(row), "dataset": rebase(row["dataset"], old, new),
                             "kwargs": _rebased_json(row["kwargs"], old, new, _kwargs_json)}
                changed += self._replace_row(conn, "settings", dict(row), moved_row, ("dataset", "setting"))
        return changed

    @staticmethod
    def _replace_row(conn: sqlite3.Connection, table: str, row: dict[str, Any], moved: dict[str, Any],
                     key: tuple[str, ...]) -> int:
        """Replace ``row`` of ``table`` (primary ``key``) by ``moved``; 0 when they are the same."""
        if moved == row:
            return 0
        conn.execute(f"DELETE FROM {table} WHERE {' AND '.join(f'{k} = ?' for k in key)}", [row[k] for k in key])
        conn.execute(f"INSERT OR REPLACE INTO {table} ({', '.join(moved)}) VALUES ({', '.join('?' * len(moved))})",
                     list(moved.values()))
        return 1

    def setting_differences(
        self, dataset: str, setting: str, kind: str, split: str | None, generator: str | None,
        kwargs: Mapping[str, Any], k: int, seed: int = 0,
    ) -> list[str]:
        """How a new evaluation of ``setting`` on ``dataset`` differs from the recorded one (``kwargs.KEY`` for a
        constructor option, else the column name), when the store already holds episodes of it; empty when it
        matches or nothing was played yet. Rows of one setting must come from one configuration: a comparison of
        egos met by different adversaries under one name would be wrong without a trace."""
        row = self._conn.execute("SELECT * FROM settings WHERE dataset = ? AND setting = ?",
                                 (dataset, setting)).fetchone()
        if row is None or not self._conn.execute(
                "SELECT 1 FROM episodes WHERE dataset = ? AND setting = ? LIMIT 1", (dataset, setting)).fetchone():
            return []
        old_kwargs = json.loads(row["kwargs"])
        new_kwargs = json.loads(_kwargs_json(kwargs))  # as upsert_setting would store them
        diff = [f"kwargs.{key}" for key in sorted(set(old_kwargs) | set(new_kwargs))
                if old_kwargs.get(key) != new_kwargs.get(key)]
        new = {"kind": kind, "split": split, "generator": generator, "k": int(k), "seed": int(seed)}
        return [c for c, v in new.items() if row[c] != v] + diff

    # ------------------------------------------------------------------------------------------ queries
    def episodes(
        self, run: str | Iterable[str] | None = None, pipeline: str | Iterable[str] | None = None,
        setting: str | Iterable[str] | None = None, seed: int | Iterable[int] | None = None,
        dataset: str | Iterable[str] | None = None, decode_hists: bool = False,
    ) -> list[dict[str, Any]]:
        """Episode rows matching every given filter (a value or a list of values), ordered by key. Histogram
        columns stay JSON text unless ``decode_hists``."""
        where, params = [], []
        for col, value in (("run", run), ("pipeline", pipeline), ("setting", setting), ("seed", seed),
                           ("dataset", dataset)):
            values = _as_list(value)
            if values is not None:
                where.append(f"{col} IN ({', '.join('?' * len(values))})")
                params.extend(values)
        sql = "SELECT * FROM episodes" + (f" WHERE {' AND '.join(where)}" if where else "")
        sql += " ORDER BY pipeline, seed, run, setting, dataset, scenario_id"
        rows = [dict(r) for r in self._conn.execute(sql, params)]
        if decode_hists:
            for r in rows:
                for c in HIST_COLUMNS:
                    r[c] = json.loads(r[c])
        return rows

    def done_scenarios(self, run: str, dataset: str, setting: str) -> set[str]:
        """Scenario ids already scored for (run, dataset, setting)."""
        cur = self._conn.execute(
            "SELECT scenario_id FROM episodes WHERE run = ? AND dataset = ? AND setting = ?", (run, dataset, setting)
        )
        return {r[0] for r in cur}

    def runs(self, pipeline: str | Iterable[str] | None = None) -> list[dict[str, Any]]:
        """Run rows (config decoded), ordered by pipeline, seed, run."""
        values = _as_list(pipeline)
        sql = "SELECT * FROM runs"
        if values is not None:
            sql += f" WHERE pipeline IN ({', '.join('?' * len(values))})"
        rows = [dict(r) for r in self._conn.execute(sql + " ORDER BY pipeline, seed, run", values or [])]
        for r in rows:
            r["config"] = json.loads(r["config"])
        return rows

    def settings(self) -> list[dict[str, Any]]:
        """Setting rows (kwargs decoded)."""
        rows = [dict(r) for r in self._conn.execute("SELECT * FROM settings ORDER BY setting, dataset")]
        for r in rows:
            r["kwargs"] = json.loads(r["kwargs"])
        return rows

    def count(self, run: str | Iterable[str] | None = None, setting: str | Iterable[str] | None = None) -> int:
        """Episode rows, of the given runs and settings only if given."""
        where, params = [], []
        for col, value in (("run", run), ("setting", setting)):
            values = _as_list(value)
            if values is not None:
                where.append(f"{col} IN ({', '.join('?' * len(values))})")
                params.extend(values)
        sql = "SELECT COUNT(*) FROM episodes" + (f" WHERE {' AND '.join(where)}" if where else "")
        return int(self._conn.execute(sql, params).fetchone()[0])


def comparable_rows(store_path: str | Path) -> dict[tuple[str, str, str, str], dict[str, Any]]:
    """Every episode row of a results store keyed by (run, dataset, setting, scenario), without the timing columns
    (the only columns two evaluations of the same work may differ in)."""
    with ResultsStore(store_path) as store:
        return {(r["run"], r["dataset"], r["setting"], r["scenario_id"]):
                {k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in store.episodes()}


def _encode(column: str, value: Any) -> Any:
    if column in HIST_COLUMNS and not isinstance(value, str):
        return json.dumps([int(v) for v in value])
    if isinstance(value, bool):
        return int(value)
    if hasattr(value, "item"):  # numpy scalars
        value = value.item()
    if isinstance(value, float) and value != value:  # NaN -> NULL
        return None
    return value
