"""`seal eval runs` at scale: egos x scenarios as chunk jobs give the rows of one process, on local workers and
on the inline backend alike; chunking and the session caches."""

from __future__ import annotations

from pathlib import Path

import pytest
import scenario_factory as sf

from seal.core.dataset import Dataset, write_dataset
from seal.experiments.backends import InlineBackend
from seal.experiments.evaluation.evaluate import parse_settings, read_run, resolve_eval_config
from seal.experiments.evaluation.parallel import chunk_jobs, evaluate_runs
from seal.experiments.evaluation.results_store import comparable_rows


def _dataset(root: Path) -> Path:
    scenarios = [sf.highway_scenario(i) for i in range(5)] + [sf.lane_change_scenario()]
    write_dataset(root, scenarios)
    ids = [s.scenario_id for s in scenarios]
    Dataset.open(root).update_manifest(splits={"train": [], "eval": ids[:4], "hard": ids[4:]})
    return root


def test_two_workers_write_the_rows_of_one_process(tmp_path: Path) -> None:
    data = _dataset(tmp_path / "data")
    config = resolve_eval_config(candidates="lanes", k=2)
    settings = "normal,hard,rule,cat"
    one = evaluate_runs(["heuristic"], settings, tmp_path / "one.sqlite", dataset=data, config=config,
                        workers=1, progress=False)
    two = evaluate_runs(["heuristic"], settings, tmp_path / "two.sqlite", dataset=data, config=config,
                        workers=2, progress=False, chunk_size=1)
    assert one == two
    assert one[0]["written"] == {"normal": 4, "hard": 2, "rule": 4, "cat": 4}
    rows_one, rows_two = comparable_rows(tmp_path / "one.sqlite"), comparable_rows(tmp_path / "two.sqlite")
    assert len(rows_one) == 2 * 14  # heuristic + replay egos, 14 rows each
    assert rows_one == rows_two
    # the generator settings really perturbed something: not every cat row equals its normal row
    outcomes = {(run, s, sid): (r["outcome"], round(r["route_completion"], 6), r["min_gap_m"])
                for (run, _, s, sid), r in rows_one.items()}
    assert any(outcomes[(run, "cat", sid)] != outcomes[(run, "normal", sid)] for run, s, sid in outcomes
               if s == "cat")


def test_chunks_cover_every_missing_scenario_once(tmp_path: Path) -> None:
    data = _dataset(tmp_path / "data")
    config = resolve_eval_config(k=1)
    settings = parse_settings("normal,hard,rule", data)
    egos = [read_run("heuristic"), read_run("replay")]
    store = str(tmp_path / "r.sqlite")
    jobs = chunk_jobs(store, egos, settings, config, n_workers=2, chunk_size=3)
    # per ego: the eval split (4 scenarios: normal + rule) and the hard split (2), in chunks of <= 3 scenarios
    assert [len(j["items"]) for j in jobs] == [3, 3, 3, 3]
    assert len({j["session"] for j in jobs}) == 1
    played = [(j["run"], d, sp, i) for j in jobs for d, sp, i, _ in j["items"]]
    assert len(played) == len(set(played)) == 12
    assert {tuple(m) for j in jobs for *_, m in j["items"]} == {("normal", "rule"), ("hard",)}
    # inline backend, bar counting episodes; then nothing is left to plan
    results = InlineBackend().map(_chunk, jobs, unit="episode",
                                  sizes=[sum(len(m) for *_, m in j["items"]) for j in jobs])
    assert all(r.ok for r in results) and sum(r.value["rows"] for r in results) == 2 * (4 * 2 + 2)
    assert chunk_jobs(store, egos, settings, config, n_workers=2) == []


def test_planning_reads_each_split_once_for_all_egos(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A split is read from every shard of the pool (~3 s at 10,000 scenes): the plans of several egos share it."""
    import seal.core.dataset as dataset_module

    data = _dataset(tmp_path / "data")
    reads: list[str | None] = []
    real = dataset_module.load_split
    monkeypatch.setattr(dataset_module, "load_split", lambda root, split, *a, **k: reads.append(split) or
                        real(root, split, *a, **k))
    egos = [read_run("heuristic"), read_run("replay"), read_run("heuristic")]
    jobs = chunk_jobs(str(tmp_path / "r.sqlite"), egos, parse_settings("normal,hard", data), resolve_eval_config(k=1),
                      chunk_size=10)
    assert sorted(reads) == ["eval", "hard"]
    assert [len(j["items"]) for j in jobs] == [6, 6, 6]  # each ego still gets its whole plan


def test_automatic_chunks_end_in_halves(tmp_path: Path) -> None:
    """Automatic sizes: the last ``n_workers`` chunks are cut in two (a shorter final round), every scenario once."""
    data = _dataset(tmp_path / "data")
    settings = parse_settings("normal,hard", data)
    egos = [read_run("heuristic"), read_run("replay")]
    from seal.experiments.evaluation import parallel

    jobs = chunk_jobs(str(tmp_path / "r.sqlite"), egos, settings, resolve_eval_config(k=1), n_workers=1)
    assert [len(j["items"]) for j in jobs] == [1] * 12  # one worker: as before, no halving
    halves = parallel._halve_tail([(egos[0], [1, 2, 3]), (egos[0], [4, 5, 6]), (egos[1], [7, 8, 9]), (egos[1], [10])],
                                  n_workers=2)
    assert [(e.run, items) for e, items in halves] == [
        ("heuristic", [1, 2, 3]), ("heuristic", [4, 5, 6]), ("replay", [7, 8]), ("replay", [9]), ("replay", [10])]


def _chunk(job: dict) -> dict:
    from seal.experiments.evaluation.parallel import evaluate_chunk

    return evaluate_chunk(job)


def test_ray_backend_writes_the_same_rows(tmp_path: Path) -> None:
    import pytest

    pytest.importorskip("ray")
    from seal.experiments.backends import RayBackend

    data = _dataset(tmp_path / "data")
    config = resolve_eval_config(k=1)
    evaluate_runs(["heuristic"], "normal,rule", tmp_path / "one.sqlite", dataset=data, config=config, workers=1,
                  progress=False)
    backend = RayBackend(local_cpus=2)
    try:
        evaluate_runs(["heuristic"], "normal,rule", tmp_path / "ray.sqlite", dataset=data, config=config,
                      backend=backend, progress=False, chunk_size=1)
    finally:
        backend.shutdown()
    assert comparable_rows(tmp_path / "one.sqlite") == comparable_rows(tmp_path / "ray.sqlite")


def test_eval_bench_measures_both_variants_on_the_same_rows(tmp_path: Path) -> None:
    from seal.experiments.bench.evaluation import run_eval_bench

    data = _dataset(tmp_path / "data")
    result = run_eval_bench(data, settings="normal,cat", limit=3, workers=2, repeats=1, k=1)
    assert result["identical_rows"] is True
    for variant, workers in (("one_worker", 1), ("n_workers", 2)):
        assert result[variant]["workers"] == workers
        assert result[variant]["episodes"] == 2 * 2 * 3  # heuristic + replay egos x 2 settings x 3 scenarios
        assert len(result[variant]["seconds"]) == 1 and result[variant]["episodes_per_s"] > 0
    expected = result["n_workers"]["episodes_per_s"] / result["one_worker"]["episodes_per_s"]
    assert abs(result["speedup"] - expected) < 1e-2
    assert result["meets_target"] == (result["speedup"] >= 1.8)


def test_a_failing_ego_gives_one_line_naming_it_and_keeps_the_other_rows(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    from seal.core.errors import SealError
    from seal.experiments.training import egos

    data = _dataset(tmp_path / "data")
    real_make_ego = egos.make_ego

    def failing_make_ego(spec: str, algo: str | None = None) -> egos.Ego:
        if spec == "heuristic":  # a model that passes the up-front checks and fails in the job
            raise egos.EgoError("cannot load this ego\nsecond line of the traceback")
        return real_make_ego(spec, algo)

    monkeypatch.setattr(egos, "make_ego", failing_make_ego)  # the worker cache imports it at call time
    store = tmp_path / "r.sqlite"
    with pytest.raises(SealError) as err:
        evaluate_runs(["heuristic"], "normal", store, dataset=data, config=resolve_eval_config(), workers=1,
                      progress=False, chunk_size=2)
    message = str(err.value)
    assert "\n" not in message and message.startswith("2 of 4 evaluation jobs failed (1 egos: heuristic)")
    assert "first error: EgoError: cannot load this ego." in message
    assert {run for run, *_ in comparable_rows(store)} == {"replay"}  # the finished jobs' rows are kept


def test_two_pools_with_the_same_scenario_ids_keep_their_own_rows(tmp_path: Path) -> None:
    """`seal run`'s held-out pools repeat every setting name on another dataset, whose scenario ids may be the
    run's own (two traffic runs number their windows alike): each pool's rows are those of evaluating it alone."""
    import dataclasses

    from seal.experiments.evaluation.evaluate import evaluate_job

    own = _dataset(tmp_path / "own")
    ids = [s.scenario_id for s in Dataset.open(own).load()]
    other = [dataclasses.replace(sf.highway_scenario(10 + i), scenario_id=sid) for i, sid in enumerate(ids[:5])]
    write_dataset(tmp_path / "pool", [*other, sf.lane_change_scenario()])
    Dataset.open(tmp_path / "pool").update_manifest(splits={"train": [], "eval": ids[:4], "hard": ids[4:]})
    config = {**resolve_eval_config(candidates="lanes", k=2), "generators": {}}
    both = [*parse_settings("normal,hard,cat", own), *parse_settings("normal,hard,cat", tmp_path / "pool")]
    job = {"store": str(tmp_path / "both.sqlite"), "run": "heuristic", "config": config,
           "settings": [vars(s) for s in both]}
    result = evaluate_job(job)
    assert result["written"] == {f"{n}@{d}": c for d in (str(own), str(tmp_path / "pool"))
                                 for n, c in (("normal", 4), ("hard", 2), ("cat", 4))}
    rows = comparable_rows(tmp_path / "both.sqlite")
    for root in (own, tmp_path / "pool"):
        alone = tmp_path / f"{root.name}.sqlite"
        evaluate_job({**job, "store": str(alone), "settings": [vars(s) for s in parse_settings("normal,hard,cat",
                                                                                               root)]})
        assert {k: v for k, v in rows.items() if k[1] == str(root)} == comparable_rows(alone)
    # and the pools really differ: the same scenario id is another scene in the other pool
    assert rows[("heuristic", str(own), "normal", ids[0])] != rows[("heuristic", str(tmp_path / "pool"), "normal",
                                                                     ids[0])]
