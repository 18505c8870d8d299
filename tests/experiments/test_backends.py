"""Job backends: inline, local process pool (spawn) and a Ray smoke run on a private 2-CPU local instance that
evaluates two egos into one results store."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest
import scenario_factory as sf

from seal.core.dataset import Dataset, write_dataset
from seal.experiments.backends import InlineBackend, LocalBackend, make_backend
from seal.experiments.evaluation.evaluate import parse_settings, resolve_eval_config
from seal.experiments.evaluation.results_store import ResultsStore


def square(job) -> dict:
    if job["x"] < 0:
        raise ValueError(f"negative x {job['x']}")
    return {"y": job["x"] ** 2, "pid": os.getpid()}


def test_inline_backend_keeps_order_and_reports_failures() -> None:
    results = InlineBackend().map(square, [{"x": 3}, {"x": -1}, {"x": 2}])
    assert [r.ok for r in results] == [True, False, True]
    assert results[0].value["y"] == 9 and results[2].value["y"] == 4
    assert "ValueError: negative x -1" in results[1].error and results[1].job == {"x": -1}


def test_local_backend_runs_jobs_in_spawned_processes() -> None:
    results = LocalBackend(2).map(square, [{"x": i} for i in (4, -2, 5, 6)])
    assert [r.value["y"] if r.ok else None for r in results] == [16, None, 25, 36]
    assert "negative x -2" in results[1].error
    assert all(r.value["pid"] != os.getpid() for r in results if r.ok)


def loaded_modules(job) -> dict:
    import sys

    return {"pid": os.getpid(), "warm": job["module"] in sys.modules}


def test_local_backend_start_spawns_warm_workers_once_for_every_map() -> None:
    """`start`: the workers import the warm modules as they start and serve every `map` until `shutdown`."""
    backend = LocalBackend(2, warm=("json.tool",)).start()
    try:
        first = backend.map(loaded_modules, [{"module": "json.tool"} for _ in range(4)])
        second = backend.map(square, [{"x": 3}])
    finally:
        backend.shutdown()
    assert all(r.ok and r.value["warm"] for r in first)
    pids = {r.value["pid"] for r in first}
    assert second[0].value["y"] == 9 and second[0].value["pid"] in pids and os.getpid() not in pids
    backend.shutdown()  # shutting down twice is harmless


def test_make_backend() -> None:
    assert isinstance(make_backend("local", 0), InlineBackend)
    assert make_backend("local", 3).workers == 3
    with pytest.raises(ValueError, match="--backend must be one of"):
        make_backend("slurm")


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="ray is not installed (pip install -e '.[ray]')")
def test_ray_backend_smoke(tmp_path: Path) -> None:
    from seal.experiments.backends import RayBackend
    from seal.experiments.evaluation.evaluate import evaluate_job

    data = tmp_path / "data"
    scenarios = [sf.highway_scenario(i) for i in range(2)]
    write_dataset(data, scenarios)
    Dataset.open(data).update_manifest(splits={"eval": [s.scenario_id for s in scenarios], "hard": []})
    settings = [vars(s) for s in parse_settings("normal,rule", data)]
    store = str(tmp_path / "r.sqlite")
    config = resolve_eval_config(k=1)
    jobs = [{"store": store, "run": ego, "settings": settings, "config": config} for ego in ("replay", "heuristic")]
    jobs.append({"store": store, "run": str(tmp_path / "missing-run"), "settings": settings, "config": config})
    backend = RayBackend(local_cpus=2)
    try:
        results = backend.map(evaluate_job, jobs, desc="ray smoke")
    finally:
        backend.shutdown()
    assert [r.ok for r in results] == [True, True, False], [r.error for r in results]
    assert "missing-run" in results[2].error
    assert results[0].value == {"run": "replay", "written": {"normal": 2, "rule": 2}}
    with ResultsStore(store) as s:  # both tasks wrote into the same store
        assert s.count() == 8
        assert {(r["run"], r["setting"]) for r in s.episodes()} == {
            (e, st) for e in ("replay", "heuristic") for st in ("normal", "rule")
        }

