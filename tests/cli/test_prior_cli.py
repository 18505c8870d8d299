"""`seal fit prior`, `seal eval prior`, `seal bench prior` on a tiny dataset; the shipped preset."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import scenario_factory as sf
import yaml

from seal.cli import main
from seal.core.dataset import Dataset, write_dataset
from seal.models.prior import PriorConfig, PriorTrainConfig, TrajectoryPrior

PRESET = Path(__file__).resolve().parents[2] / "experiments" / "configs" / "prior_default.yaml"
TINY_YAML = {
    "model": {"features": {"n_agents": 8, "n_chunks": 8}, "d_model": 16, "n_heads": 2, "n_layers": 1, "n_knots": 8},
    "train": {"batch_size": 64, "warmup_steps": 2, "val_fraction": 0.25},
}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("prior_cli") / "ds"
    scenarios = [sf.highway_scenario(i, scenario_id=f"h{i}") for i in range(6)]
    scenarios += [sf.lane_change_scenario("lc"), sf.curve_scenario("cv")]
    write_dataset(root, scenarios)
    Dataset.open(root).update_manifest(
        splits={"train": ["h0", "h1", "h2", "h3"], "eval": ["h4", "lc"], "hard": ["cv"]}
    )
    return root


@pytest.fixture(scope="module")
def config_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("prior_cfg") / "tiny.yaml"
    path.write_text(yaml.safe_dump(TINY_YAML))
    return path


@pytest.fixture(scope="module")
def model(dataset: Path, config_file: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("prior_model") / "prior.pt"
    code = main(["fit", "prior", str(dataset), "--out", str(out), "--split", "all-but-eval", "--config",
                 str(config_file), "--epochs", "2", "--no-time-budget", "--no-progress"])
    assert code == 0
    return out


def test_fit_writes_model_with_config_and_summary(model: Path) -> None:
    prior = TrajectoryPrior.load(model)
    assert prior.config.d_model == 16 and prior.config.features.n_agents == 8
    t = prior.training
    # all-but-eval: every scenario outside the eval and hard splits (h5 has no split and is used too).
    used = set(t["train_scenario_ids"]) | set(t["val_scenario_ids"])
    assert used == {"h0", "h1", "h2", "h3", "h5"}
    assert t["data"]["split"] == "all-but-eval" and t["epochs_run"] == 2 and len(t["history"]) == 2
    assert t["train_config"]["max_minutes"] is None and t["train_config"]["batch_size"] == 64
    sidecar = json.loads(Path(str(model) + ".json").read_text())
    assert sidecar["model_config"]["d_model"] == 16 and "history" in sidecar["training"]
    assert not Path(str(model) + ".train-state").exists()  # removed after a finished run


def test_eval_reports_metrics_against_constant_velocity(model: Path, dataset: Path,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", "prior", str(model), str(dataset), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["scenarios"] == 2 and res["scenarios_seen_in_training"] == 0
    adv = res["adversary"]
    assert adv["targets"] == 2
    assert adv["min_ade_32"] <= adv["min_ade_6"] <= adv["min_ade_1"]
    assert adv["min_fde_32"] <= adv["min_fde_6"] <= adv["min_fde_1"]
    assert adv["ratio_min_ade_6_to_cv_ade"] == pytest.approx(adv["min_ade_6"] / adv["cv_ade"])
    assert adv["share_within_acc"] == 1.0 and adv["share_within_yaw_rate"] == 1.0  # bounded by construction
    assert 0.0 <= adv["share_drivable_strict"] <= adv["share_drivable"] <= 1.0
    assert res["moving"]["targets"] >= adv["targets"]
    assert main(["eval", "prior", str(model), str(dataset), "--targets", "adversary", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "minADE@6 / CV ADE" in text and "target <= 0.5" in text and "constant velocity" in text


def test_bench_prints_latencies(model: Path, dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "prior", "--model", str(model), "--dataset", str(dataset), "--repeats", "3",
                 "--batch", "4", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["candidates"] == 32
    # The verdict follows the measured numbers (the target itself is a constant).
    assert res["meets_target"] == (res["single_scenario_ms"] < res["target_single_ms"])
    assert res["single_scenario_ms"] > 0 and res["batch_4_ms"] > 0


def test_bad_split_and_config_are_named(dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fit", "prior", str(dataset), "--out", str(tmp_path / "m.pt"), "--split", "nope"]) == 2
    assert "--split 'nope'" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"model": {"d_modle": 3}}))
    assert main(["fit", "prior", str(dataset), "--out", str(tmp_path / "m.pt"), "--config", str(bad)]) == 2
    assert "d_modle" in capsys.readouterr().err
    unsplit = tmp_path / "unsplit"
    write_dataset(unsplit, [sf.curve_scenario("c1"), sf.curve_scenario("c2")])
    assert main(["fit", "prior", str(unsplit), "--out", str(tmp_path / "m.pt"), "--split", "all-but-eval"]) == 2
    assert "no eval / hard split" in capsys.readouterr().err
    assert main(["eval", "prior", str(tmp_path / "missing.pt"), str(dataset)]) == 2
    assert "missing.pt" in capsys.readouterr().err


def test_shipped_preset_matches_the_defaults() -> None:
    doc = yaml.safe_load(PRESET.read_text())
    assert PriorConfig.from_dict(doc["model"]) == PriorConfig()
    assert PriorTrainConfig.from_dict(doc["train"]) == PriorTrainConfig()


def test_config_file_options_and_set_layer_in_order(tmp_path: Path) -> None:
    from seal.cli.prior import _load_config
    from seal.core.config import ConfigError

    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"model": {"n_modes": 16}, "train": {"epochs": 4, "lr": 0.001}}))
    model, train = _load_config(str(path), {"train.epochs": 3, "train.seed": None}, ["train.lr=0.01"])
    assert model == {"n_modes": 16} and train == {"epochs": 3, "lr": 0.01}
    assert _load_config(None, {}, []) == ({}, {})
    with pytest.raises(ConfigError, match=r"--set train\.epoch=2: unknown key\(s\) \['train\.epoch'\]"):
        _load_config(None, {}, ["train.epoch=2"])
    path.write_text(yaml.safe_dump({"modle": {}}))
    with pytest.raises(ConfigError, match=r"c\.yaml: unknown key\(s\) \['modle'\]; known: \['model', 'train'\]"):
        _load_config(str(path), {}, [])
