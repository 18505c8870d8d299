"""`seal fit behavior` on a tiny scored dataset: report, variants, unsafe cache, the model cat-rcg loads; errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf

from seal.cli import main
from seal.core.dataset import Dataset, write_dataset
from seal.scoring.store import score_dataset

TINY = ["--preset", "quick", "--set", "model.d_model=16", "--set", "model.n_heads=2", "--set", "model.latent_dim=32",
        "--set", "train.epochs=2", "--set", "train.finetune_epochs=2", "--set", "analysis_max=200",
        "--no-progress"]


def _rear_end(i: int):
    road = sf.straight_road(3)
    lane = road.lanes[1].centerline
    lead = sf.simulate_track(lane, 60.0 + 5 * i, 10.0, substeps=2)
    follow = sf.simulate_track(lane, 30.0, 20.0, substeps=2)
    side = sf.simulate_track(road.lanes[0].centerline, 20.0, 15.0, substeps=2)
    return sf.make_scenario(road, [follow, lead, side], f"crash{i}")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("behavior_cli") / "ds"
    scenarios = [sf.highway_scenario(i, scenario_id=f"h{i}") for i in range(5)] + [_rear_end(i) for i in range(3)]
    write_dataset(root, scenarios)
    Dataset.open(root).update_manifest(splits={"train": ["h0", "h1", "h2", "crash0", "crash1"],
                                               "eval": ["h3", "h4", "crash2"], "hard": []})
    score_dataset(root, workers=1, progress=False)
    return root


def test_fit_behavior_writes_models_report_and_cache(dataset: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "b"
    assert main(["fit", "behavior", str(dataset), "--out", str(out), "--split", "train", *TINY, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["samples"]["crash"]["samples"] == 4  # two rear-end pairs, both agents each
    assert report["crash_sources"]["training split"]["cause"] == {"behind": 2}
    assert set(report["table_7_5"]) == {"no_cl", "no_cl_ft", "cl", "full"}
    for row in report["table_7_5"].values():
        assert -1.0 <= row["silhouette"] <= 1.0 and row["davies_bouldin"] > 0 and 0.0 <= row["probe_accuracy"] <= 1.0
    assert {p.name for p in (out / "variants").glob("*.pt")} == {f"{v}-s0.pt" for v in report["table_7_5"]}
    # The held-out split's own crash pair (crash2: both agents) is analysed apart, with the crash roles as classes.
    assert report["samples"]["held_out_crash"]["samples"] == 2
    assert set(report["crash_table"]) == set(report["table_7_5"])
    for row in report["crash_table"].values():
        assert -1.0 <= row["silhouette"] <= 1.0 and 0.0 <= row["probe_accuracy"] <= 1.0
        assert row["majority_share"] == 0.5  # one striker, one recipient
    assert set(report["full_beats_on_crash"]) == {"no_cl", "no_cl_ft", "cl"}
    for name in ("report.md", "train_log.csv", "config.yaml", "behavior.json"):
        assert (out / name).is_file()
    from seal.models.behavior.model import BehaviorModel

    model = BehaviorModel.load(out / "behavior.pt")
    counts = model.info["unsafe_cache"]
    assert model.lora and counts["crash_unsafe"] == 2
    assert model.unsafe_cache is not None and len(model.unsafe_cache) == counts["everyday_unsafe"] + 2
    assert not BehaviorModel.load(out / "variants" / "cl-s0.pt").lora
    # Pre-training leaves the adapter alone: the no-fine-tuning variant's B is still zero.
    assert not np.any(BehaviorModel.load(out / "variants" / "cl-s0.pt").net.lora_b.weight.detach().numpy())
    # The model drives cat-rcg.
    from seal.adversaries.base import make_generator
    from seal.adversaries.history import RolloutHistory

    s = Dataset.open(dataset).get("h3")
    gen = make_generator("cat-rcg", candidates="constant_velocity", behavior=str(out / "behavior.pt"))
    assert gen.generate(s, RolloutHistory().queue(s), np.random.default_rng(0)).chosen_candidate is not None


def test_fit_behavior_errors_name_the_culprit(dataset: Path, tmp_path: Path, capsys) -> None:
    unscored = tmp_path / "unscored"
    write_dataset(unscored, [sf.highway_scenario(0, scenario_id="h0")])
    Dataset.open(unscored).update_manifest(splits={"train": ["h0"], "eval": ["h0"], "hard": []})
    assert main(["fit", "behavior", str(unscored), "--out", str(tmp_path / "o"), "--split", "train", *TINY]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seal data score" in err[0]
    assert main(["fit", "behavior", str(dataset), "--out", str(tmp_path / "o"), "--set", "train.tau=0",
                 *TINY]) == 2
    assert "tau" in capsys.readouterr().err
    assert main(["fit", "behavior", str(dataset), "--out", str(tmp_path / "o"), "--split", "train",
                 "--set", "crash.near_miss_m=-1", *TINY]) == 2
    assert "crash set is empty" in capsys.readouterr().err


def _state(path: Path) -> dict:
    from seal.models.behavior.model import BehaviorModel

    m = BehaviorModel.load(path)
    return {"net": m.net.state_dict(), "cache": m.unsafe_cache, "centroids": m.prototypes.centroids}


def _same(a: dict, b: dict) -> bool:
    import torch

    return (all(torch.equal(a["net"][k], b["net"][k]) for k in a["net"]) and np.array_equal(a["cache"], b["cache"])
            and torch.equal(a["centroids"], b["centroids"]))


def test_an_interrupted_fit_goes_on_after_its_last_stage_and_writes_the_same_models(
        dataset: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    import seal.models.behavior.train as train

    args = ["--split", "train", *TINY, "--json"]
    assert main(["fit", "behavior", str(dataset), "--out", str(tmp_path / "whole"), *args]) == 0
    whole = json.loads(capsys.readouterr().out)
    assert whole["resumed_stages"] == [] and not (tmp_path / "whole" / "stages").exists()

    real_finetune, calls = train.finetune, []

    def interrupted_finetune(*a, **k):  # the session ends during the second fine-tuning (the 4th stage)
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_finetune(*a, **k)

    out = tmp_path / "resumed"
    monkeypatch.setattr(train, "finetune", interrupted_finetune)
    assert main(["fit", "behavior", str(dataset), "--out", str(out), *args]) == 130  # seal's exit code on Ctrl-C
    assert sorted(p.name for p in (out / "stages").glob("*.pt")) == ["cl-s0.pt", "no_cl-s0.pt", "no_cl_ft-s0.pt"]
    monkeypatch.setattr(train, "finetune", real_finetune)
    capsys.readouterr()

    assert main(["fit", "behavior", str(dataset), "--out", str(out), *args]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["resumed_stages"] == ["no_cl-s0", "no_cl_ft-s0", "cl-s0"]
    assert report["table_7_5"] == whole["table_7_5"]
    for v in ("no_cl", "no_cl_ft", "cl", "full"):
        assert _same(_state(out / "variants" / f"{v}-s0.pt"), _state(tmp_path / "whole" / "variants" / f"{v}-s0.pt"))
    assert (out / "train_log.csv").read_text() == (tmp_path / "whole" / "train_log.csv").read_text()
    assert not (out / "stages").exists()


def test_stages_of_other_settings_are_trained_again(dataset: Path, tmp_path: Path, capsys) -> None:
    from seal.experiments.fitting.behavior_stages import StageStore

    out = tmp_path / "b"
    old = StageStore(out, {"config": "other settings"})
    (old.folder / "cl-s0.pt").write_bytes(b"a stage of other settings")
    assert main(["fit", "behavior", str(dataset), "--out", str(out), "--split", "train", *TINY, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["resumed_stages"] == []
    # Same settings, an unreadable stage file: trained again, not an error.
    store = StageStore(out, {"config": "x"})
    (store.folder / "cl-s0.pt").write_bytes(b"truncated")
    assert store.load("cl", 0) is None and store.load("full", 0) is None and store.loaded == []
