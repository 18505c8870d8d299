"""Fixtures of the experiments tests."""

from __future__ import annotations

from pathlib import Path

import pytest
import scenario_factory as sf

from seal.core.dataset import Dataset, write_dataset


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three hand-built highway scenarios: eval = the last two, hard = the first, train empty."""
    root = tmp_path_factory.mktemp("eval") / "data"
    scenarios = [sf.highway_scenario(i) for i in range(3)]
    write_dataset(root, scenarios)
    ids = [s.scenario_id for s in scenarios]
    Dataset.open(root).update_manifest(splits={"train": [], "eval": ids[1:], "hard": ids[:1]})
    return root
