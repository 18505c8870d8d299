"""Step functions for `seal run` tests: a recorder of the data / fit step jobs that writes small real outputs."""

from __future__ import annotations

from pathlib import Path

import scenario_factory as sf

from seal.core.dataset import Dataset, write_dataset


class FakeTasks:
    """Records the data / fit step jobs as (task or fit model, dataset, out, options); `generate` / `split` and the
    fits write small real outputs."""

    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def __call__(self, job) -> None:
        kind = job["model"] if job["task"] == "fit" else job["task"]
        self.calls.append((kind, job["dataset"], job.get("out"), job["options"]))
        if job["task"] == "generate":
            write_dataset(job["dataset"], [sf.highway_scenario(i) for i in range(3)])
        elif job["task"] == "split":
            ds = Dataset.open(job["dataset"])
            ids = [s.scenario_id for s in ds.load()]
            ds.update_manifest(splits={"train": ids[:1], "eval": ids[1:], "hard": ids[:1]})
        elif job["task"] == "fit":
            Path(job["out"]).write_text("model")
