"""The `seal run` evaluation's episode bar: the rows a complete evaluation writes, and a bar that follows rows written
by someone else while it is open."""

from __future__ import annotations

import io
import threading
import time
from pathlib import Path

import scenario_factory as sf
from results_builders import episode

from seal.core.dataset import Dataset, write_dataset
from seal.experiments.evaluation.evaluate import parse_settings
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.evaluation.store_progress import StoreProgress, expected_rows


def _dataset(root: Path) -> Path:
    scenarios = [sf.highway_scenario(i) for i in range(5)]
    write_dataset(root, scenarios)
    ids = [s.scenario_id for s in scenarios]
    Dataset.open(root).update_manifest(splits={"train": ids[:1], "eval": ids[1:4], "hard": ids[4:]})
    return root


def test_expected_rows_counts_every_ego_setting_and_scenario(tmp_path: Path) -> None:
    data = _dataset(tmp_path / "data")
    real = tmp_path / "real"
    write_dataset(real, [sf.highway_scenario(i) for i in range(4)])  # unsplit: every scenario is evaluated
    settings = parse_settings(f"normal,hard,rule,real:{real}", data)
    # eval 3 + hard 1 + rule (eval) 3 + real (every scenario) 4, per ego
    assert expected_rows(["a", "b"], settings, None) == 2 * (3 + 1 + 3 + 4)
    assert expected_rows(["a", "b"], settings, 2) == 2 * (2 + 1 + 2 + 2)


def test_bar_follows_rows_written_meanwhile(tmp_path: Path) -> None:
    store = tmp_path / "results.sqlite"
    with ResultsStore(store) as s:  # one row from before: counted from the start; one of another ego: never
        s.upsert_episodes([episode(run="a", scenario_id="s0"), episode(run="other", scenario_id="s0")])

    def writer() -> None:
        with ResultsStore(store) as s:
            for i in range(1, 6):
                s.upsert_episodes([episode(run="a", scenario_id=f"s{i}")])
                time.sleep(0.02)

    out = io.StringIO()
    with StoreProgress(store, ["a"], ["normal"], total=10, every_s=0.01, file=out) as progress:
        assert progress.bar.n == 1
        thread = threading.Thread(target=writer)
        thread.start()
        thread.join()
        time.sleep(0.1)
        during = progress.bar.n
    assert during == 6  # the poller saw every row before the exit's final count
    assert progress.bar.n == 6 and progress.bar.total == 10
    assert "6/10" in out.getvalue()
