"""``seal bench eval``: episodes/s of ``seal eval runs`` on N worker processes against one process, in one run.

Both variants evaluate the same egos on the same settings and scenarios, each into a fresh results store, in
interleaved repeats (1 worker, N workers, 1 worker, ...); each variant's fastest repeat counts. Two rates per
variant:

* ``episodes_per_s``: rows written / wall seconds of the whole `evaluate_runs` call. The N-worker call starts its
  own pool, so it pays the workers' start-up (a fresh interpreter, seal's imports, the first chunk's model and
  scenario loads) inside the measurement; the 1-worker call runs in this process, whose modules the previous
  repeats (and a warm-up of one scenario) have already loaded. This is the conservative headline: what a
  command that evaluates this much work gains from the workers, less only this process's own imports, which
  both variants pay alike.
* ``steady_episodes_per_s``: rows / seconds between the first and the last row's ``created_at`` (the rate once
  every worker is running: what a long evaluation, the decisive protocol's ~570k episodes, sees).

The rows of the two variants must be identical apart from the timing columns
(`seal.experiments.evaluation.results_store.TIMING_COLUMNS`); the result says
whether they are.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from seal.experiments.evaluation.results_store import ResultsStore, comparable_rows

TARGET_SPEEDUP = 1.8
"""Issue 23: episodes/s of ``seal eval runs`` on 2 workers over 1 worker."""


def _row_span_s(store_path: Path) -> float:
    with ResultsStore(store_path) as store:
        times = [float(r["created_at"]) for r in store.episodes()]
    return max(times) - min(times) if len(times) > 1 else 0.0


def bench_dataset(out: Path, n: int, seed: int = 0) -> Path:
    """A small generated dataset (highway-env traffic on every layout, every scenario in the eval split) for a
    benchmark without ``--dataset``."""
    from seal.envs.generate import generate_dataset

    ds = generate_dataset(out, n=n, seed=seed, progress=False)
    ds.update_manifest(splits={"train": [], "eval": [s.scenario_id for s in ds.load()], "hard": []})
    return out


def run_eval_bench(
    dataset: str | Path | None = None, runs: Sequence[str] = ("heuristic",), settings: str = "normal,rule,cat",
    limit: int = 300, workers: int = 2, repeats: int = 2, candidates: str = "lanes", k: int | None = None,
    n_generated: int | None = None, seed: int = 0,
) -> dict[str, Any]:
    """Measure `evaluate_runs` with 1 and with ``workers`` local worker processes on the same work.

    Args:
        dataset: dataset directory (default: ``n_generated`` scenarios generated into a temporary folder).
        runs: egos (run folders or built-in egos); the Replay ego is added as by ``seal eval runs``.
        settings: ``seal eval runs --settings``.
        limit: scenarios per setting (default 300: the decisive protocol's Normal eval and Hard splits).
        workers: worker processes of the parallel variant (>= 2).
        repeats: measurements per variant, interleaved; the fastest counts.
        candidates: the CAT generator's candidate source (``lanes``: no trained prior needed).
        k: perturbation passes of generator settings (default: the evaluation config's).
        n_generated: scenarios of the generated dataset (default: ``limit``).
        seed: generation seed of that dataset and the evaluation seed.

    Returns:
        A JSON-ready dict: per variant the best ``episodes_per_s`` and ``steady_episodes_per_s`` with every
        repeat's seconds, ``speedup`` (N workers over 1, whole calls), ``steady_speedup``, ``identical_rows``,
        the target and whether it is met.
    """
    from seal.experiments.evaluation.evaluate import read_run, resolve_eval_config
    from seal.experiments.evaluation.parallel import evaluate_runs

    if workers < 2:
        raise ValueError(f"--workers must be at least 2 to compare with one process (got {workers})")
    with tempfile.TemporaryDirectory(prefix="seal-bench-eval-") as tmp_dir:
        tmp = Path(tmp_dir)
        source = f"dataset {dataset}"
        if dataset is None:
            n_generated = int(n_generated or limit)
            dataset = bench_dataset(tmp / "data", n_generated, seed)
            source = f"{n_generated} generated scenarios (seed {seed})"
        egos = [read_run(r) for r in runs]
        config = resolve_eval_config(run_configs=[e.config for e in egos], limit=limit, seed=seed,
                                     candidates=candidates, k=k)
        # Warm-up: this process imports and compiles what the 1-worker variant runs, so neither variant's figure
        # holds first-import costs that a real command pays before either would start (its own imports).
        warm = dict(config, limit=1)
        evaluate_runs(list(runs), settings, tmp / "warm.sqlite", dataset=dataset, config=warm, workers=1,
                      progress=False)
        one, many, identical = _measure(tmp, list(runs), settings, dataset, config, workers, repeats)
    speedup = many["episodes_per_s"] / one["episodes_per_s"]
    steady = (many["steady_episodes_per_s"] / one["steady_episodes_per_s"]
              if many["steady_episodes_per_s"] and one["steady_episodes_per_s"] else None)
    return {
        "data": source, "runs": list(runs), "settings": settings, "limit": limit, "repeats": repeats,
        "one_worker": one, "n_workers": many,
        "speedup": round(speedup, 3),
        "steady_speedup": round(steady, 3) if steady is not None else None,
        "identical_rows": identical,
        "target": f">= {TARGET_SPEEDUP}x episodes/s on {workers} workers, identical rows",
        "meets_target": bool(identical and speedup >= TARGET_SPEEDUP),
    }


def _measure(tmp: Path, runs: list[str], settings: str, dataset: str | Path, config: dict[str, Any], workers: int,
             repeats: int) -> tuple[dict[str, Any], dict[str, Any], bool]:
    """The interleaved repeats (1 worker, ``workers``, 1 worker, ...), each into a fresh store under ``tmp``: each
    variant's figures (`run_eval_bench`) and whether the last stores of the two hold the same rows."""
    from seal.experiments.backends import LocalBackend
    from seal.experiments.evaluation.parallel import evaluate_runs

    seconds: dict[int, list[float]] = {1: [], workers: []}
    spans: dict[int, list[float]] = {1: [], workers: []}
    rows: dict[int, int] = {}
    stores: dict[int, Path] = {}
    for rep in range(repeats):
        for w in (1, workers):
            store = tmp / f"w{w}_r{rep}.sqlite"
            backend = LocalBackend(w) if w > 1 else None
            start = time.perf_counter()
            evaluate_runs(runs, settings, store, dataset=dataset, config=config, workers=w, backend=backend,
                          progress=False)
            seconds[w].append(time.perf_counter() - start)
            spans[w].append(_row_span_s(store))
            with ResultsStore(store) as s:
                rows[w] = s.count()
            stores[w] = store

    def variant(w: int) -> dict[str, Any]:
        best, best_span = min(seconds[w]), min(spans[w])
        return {
            "workers": w, "episodes": rows[w], "seconds": [round(s, 3) for s in seconds[w]],
            "episodes_per_s": round(rows[w] / best, 2),
            "steady_episodes_per_s": round(rows[w] / best_span, 2) if best_span > 0 else None,
        }

    return variant(1), variant(workers), comparable_rows(stores[1]) == comparable_rows(stores[workers])
