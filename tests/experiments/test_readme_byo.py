"""The README's "Use your own policy / generator" section, run as written (issue 25): train your own SAC through
`ClosedLoopEnv` on the train split, evaluate the saved zip with the CLI lines, evaluate a Python policy, compare.
Only sizes shrink (steps), so the test runs in seconds."""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest
import scenario_factory as sf
from readme_blocks import block, blocks

from seal.cli import main
from seal.core.dataset import Dataset, write_dataset
from seal.experiments.evaluation.results_store import ResultsStore

SECTION = "Use your own policy / generator"


@pytest.fixture
def demo_data(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``runs/demo/data`` (the path the README uses) in a fresh working directory: train, eval and hard splits."""
    monkeypatch.chdir(tmp_path)
    root = Path("runs/demo/data")
    scenarios = [sf.lane_change_scenario(), sf.curve_scenario(), sf.stopped_adversary_scenario(),
                 *(sf.highway_scenario(i) for i in range(3))]
    write_dataset(root, scenarios)
    ids = [s.scenario_id for s in scenarios]
    Dataset.open(root).update_manifest(splits={"train": ids[:3], "eval": ids[3:5], "hard": ids[5:]})
    return root


def test_readme_train_your_own_then_evaluate_and_compare(demo_data: Path, capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    import torch

    train = block(SECTION, "import gymnasium as gym")
    assert "1_000" in train and "learning_starts=200" in train
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a script's own choice; on a loaded machine more threads only contend
    try:
        exec(compile(train.replace("1_000", "30").replace("learning_starts=200", "learning_starts=60"), "README",
                     "exec"), {})
    finally:
        torch.set_num_threads(threads)
    assert Path("my_sac.zip").is_file()
    for line in blocks(SECTION, "bash")[0].strip().splitlines():
        argv = shlex.split(line)
        assert argv[0] == "seal"
        assert main([*argv[1:], *(["--workers", "1", "--no-progress"] if argv[1] == "eval" else ["--no-progress"])]
                    ) == 0, capsys.readouterr().err
    with ResultsStore("results.sqlite") as store:
        runs = {r["run"]: r["pipeline"] for r in store.runs()}
        settings = {r["setting"] for r in store.episodes()}
    assert str(Path("my_sac.zip").resolve()) in runs and "replay" in runs
    assert settings == {"normal", "hard", "rule"}
    report = Path("report/report.md").read_text()
    assert "## Failures" in report and "## Outcomes" in report


def test_readme_python_policy(demo_data: Path) -> None:
    namespace: dict = {}
    exec(compile(block(SECTION, "import numpy as np"), "README", "exec"), namespace)
    with ResultsStore("results.sqlite") as store:
        rows = store.episodes(run="cautious")
    assert {r["setting"] for r in rows} == {"normal", "rule"} and len(rows) == 4
