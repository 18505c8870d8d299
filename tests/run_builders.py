"""Step functions for `seal run` tests: a recorder of the data / fit step jobs that writes small real outputs, train
and eval jobs that write what a finished run folder and a results store hold, a small preset and a run of it."""

from __future__ import annotations

from pathlib import Path

import scenario_factory as sf
import yaml
from results_builders import episode

from seal.core.dataset import Dataset, write_dataset
from seal.experiments.backends import InlineBackend
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.pipeline.run import run_pipeline


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


def fake_train_config(config, preset_path, pipeline, seed, dataset, generators) -> dict:
    gen = None if pipeline == "noadv" else pipeline
    return {"algo": "td3", "pipeline": pipeline, "seed": seed, "dataset": dataset,
            "generator": {"name": gen, "kwargs": generators.get(gen, {})} if gen else None}


def fake_train(job) -> dict:
    """Writes what a finished run folder holds (config.yaml, done.json); fails for seed 13."""
    if job["config"]["seed"] == 13:
        raise RuntimeError("diverged")
    out = Path(job["out"])
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.yaml").write_text(yaml.safe_dump(job["config"]))
    (out / "done.json").write_text("{}")
    return {"run": str(out)}


def fake_eval(job) -> dict:
    """One episode row per (setting, first scenario) for the job's ego, into the job's store."""
    builtin = job["run"] in ("replay", "heuristic")
    cfg = yaml.safe_load((Path(job["run"]) / "config.yaml").read_text()) if not builtin else {}
    pipeline, seed = cfg.get("pipeline", job["run"]), cfg.get("seed", 0)
    with ResultsStore(job["store"]) as store:
        store.upsert_episodes([
            episode(run=job["run"], setting=s["name"], pipeline=pipeline, seed=seed, dataset=s["dataset"])
            for s in job["settings"]
        ])
        for s in job["settings"]:
            store.upsert_setting(s["dataset"], s["name"], "generator" if s["generator"] else "replay", s["split"],
                                 s["generator"], job["config"]["generators"].get(s["generator"] or "", {}), 2)
    return {"run": job["run"]}


def write_preset(tmp_path: Path, seeds=(0, 1), **changes) -> Path:
    preset = {
        "data": {"generate": {"n": 3, "seed": 0}, "split": {"n_train": 1, "n_eval": 2, "n_hard": 1}},
        "fit": {"prior": {"epochs": 1, "no_progress": True}, "goose": {"path": "/models/goose.zip"},
                "skills": {"preset": "quick"}},
        "generators": {"cat": {"prior": "${fit.prior}", "follow": "replay"}, "rule": {}},
        "pipelines": ["noadv", "cat"],
        "seeds": list(seeds),
        "eval": {"settings": ["normal", "hard", "cat"], "k": 2, "limit": 2},
        "report": {"plots": False, "reps": 50, "poi_reps": 20},  # few resamples: the statistics are not tested here
        "train": {"algo": "td3", "total_timesteps": 100},
        **changes,
    }
    path = tmp_path / "preset.yaml"
    path.write_text(yaml.safe_dump(preset, sort_keys=False))
    return path


def run(preset: Path, out: Path, commands: FakeTasks, train=fake_train, evaluate=fake_eval) -> dict:
    return run_pipeline(preset, out, backend=InlineBackend(), task_fn=commands, train_fn=train, eval_fn=evaluate,
                        train_config_fn=fake_train_config, progress=False)
