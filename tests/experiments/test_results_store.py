"""Results store: round-trip, upsert idempotency, filtered re-query, schema check, concurrent writers."""

from __future__ import annotations

import multiprocessing as mp
import sqlite3

import pytest
from results_builders import episode

from seal.experiments.evaluation.results_store import EPISODE_COLUMNS, ResultsStore, StoreError


def test_round_trip_values_and_types(tmp_path):
    with ResultsStore(tmp_path / "r.sqlite") as store:
        assert store.upsert_episodes([episode(collision_speed_mps=4.25, outcome="crash")]) == 1
        store.upsert_run("r0", "noadv", 0, "r0", "/runs/r0", {"algo": "td3", "seed": 0})
        store.upsert_setting("/data", "cat", "generator", "eval", "cat", {"candidates": "lanes"}, k=5, seed=3)
    with ResultsStore(tmp_path / "r.sqlite") as store:  # re-opened: persisted
        (row,) = store.episodes(decode_hists=True)
        assert row["outcome"] == "crash" and row["crash"] == 1 and row["success"] == 0
        assert row["collision_speed_mps"] == pytest.approx(4.25)
        assert sum(row["adv_yaw_hist"]) == 3 and len(row["adv_yaw_hist"]) == 60 and sum(row["log_acc_hist"]) == 3
        assert row["generation_ms_mean"] is None
        assert set(row) == set(EPISODE_COLUMNS)
        (run,) = store.runs()
        assert run["config"] == {"algo": "td3", "seed": 0} and run["path"] == "/runs/r0"
        (setting,) = store.settings()
        assert setting["kwargs"] == {"candidates": "lanes"} and setting["k"] == 5 and setting["seed"] == 3


def test_nan_is_stored_as_null(tmp_path):
    with ResultsStore(tmp_path / "r.sqlite") as store:
        store.upsert_episodes([episode()])
        assert store.episodes()[0]["collision_speed_mps"] is None


def test_upsert_is_idempotent_and_replaces(tmp_path):
    with ResultsStore(tmp_path / "r.sqlite") as store:
        store.upsert_episodes([episode(outcome="crash")])
        store.upsert_episodes([episode(outcome="crash")])
        assert store.count() == 1
        store.upsert_episodes([episode(outcome="success")])  # same key: replaced, not duplicated
        rows = store.episodes()
        assert len(rows) == 1 and rows[0]["outcome"] == "success"


def test_filters_and_done_scenarios(tmp_path):
    rows = [
        episode(run=f"{p}-{s}", pipeline=p, seed=s, setting=setting, scenario_id=f"sc{i}")
        for p in ("noadv", "cat") for s in (0, 1) for setting in ("normal", "hard", "cat") for i in range(3)
    ]
    with ResultsStore(tmp_path / "r.sqlite") as store:
        store.upsert_episodes(rows)
        assert store.count() == 36
        assert len(store.episodes(pipeline="cat")) == 18
        assert len(store.episodes(pipeline=["cat", "noadv"], setting="hard")) == 12
        assert len(store.episodes(pipeline="cat", seed=1, setting=["normal", "cat"])) == 6
        assert {r["run"] for r in store.episodes(run="noadv-1")} == {"noadv-1"}
        assert store.episodes(setting="goose") == []
        assert store.done_scenarios("cat-0", "/data", "hard") == {"sc0", "sc1", "sc2"}
        assert store.done_scenarios("cat-0", "/other", "hard") == set()


def test_bad_rows_are_rejected_naming_the_column(tmp_path):
    with ResultsStore(tmp_path / "r.sqlite") as store:
        bad = episode()
        del bad["outcome"]
        with pytest.raises(ValueError, match="outcome"):
            store.upsert_episodes([bad])
        with pytest.raises(ValueError, match="bogus"):
            store.upsert_episodes([episode(bogus=1)])
        assert store.count() == 0  # nothing half-written


def test_schema_version_mismatch_is_an_error(tmp_path):
    path = tmp_path / "r.sqlite"
    ResultsStore(path).close()
    con = sqlite3.connect(path)
    con.execute("UPDATE meta SET value = '999' WHERE key = 'schema_version'")
    con.commit()
    con.close()
    with pytest.raises(StoreError, match="schema version 999"):
        ResultsStore(path)


def _writer(path: str, worker: int, n: int) -> None:
    with ResultsStore(path) as store:
        for i in range(n):  # one transaction per episode, interleaved with the other writer
            store.upsert_episodes([episode(run=f"w{worker}", scenario_id=f"s{i}", seed=worker)])
            store.upsert_run(f"w{worker}", "noadv", worker, f"w{worker}", None, {"i": i})


def test_two_processes_write_concurrently(tmp_path):
    path = str(tmp_path / "r.sqlite")
    ResultsStore(path).close()
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_writer, args=(path, w, 60)) for w in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=120)
        assert p.exitcode == 0
    with ResultsStore(path) as store:
        assert store.count() == 120
        assert {r["run"]: r["config"]["i"] for r in store.runs()} == {"w0": 59, "w1": 59}
        assert sorted(store.done_scenarios("w1", "/data", "normal")) == sorted(f"s{i}" for i in range(60))
        assert store._conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"


def test_setting_differences_only_once_episodes_exist(tmp_path):
    with ResultsStore(tmp_path / "r.sqlite") as store:
        rec = ("/data", "cat", "generator", "eval", "cat", {"prior": "/m/prior.pt"}, 5, 0)
        store.upsert_setting(*rec)
        other = ("/data", "cat", "generator", "eval", "cat", {"prior": "/m/prior.pt", "noise_scale": 0.5}, 3, 0)
        assert store.setting_differences(*other) == []  # nothing played yet: a new configuration may replace it
        store.upsert_episodes([episode(setting="cat")])
        assert store.setting_differences(*rec) == []
        assert store.setting_differences(*other) == ["k", "kwargs.noise_scale"]
        assert store.setting_differences("/other", *other[1:]) == []  # another dataset is another setting
