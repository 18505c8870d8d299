"""End to end at toy scale (issue 24: these commands had no test beyond `--help`): `seal fit skills`,
`seal fit objective` / `seal eval objective`, `seal demo`, `seal bench training` and `seal bench data`, each run
through the CLI on a tiny generated dataset with tiny training budgets, checking what they write and print."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
from train_fixtures import tiny_dataset

from seal.cli import main
from seal.core.dataset import Dataset


def _run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict:
    """``seal ARGV --json``: exit code 0 and the printed JSON."""
    capsys.readouterr()
    code = main([*argv, "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err[-2000:]
    return json.loads(captured.out)


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """12 base scenarios of highway-env traffic (highway, merge, intersection), 8 in train and 4 in eval."""
    root = tmp_path_factory.mktemp("e2e") / "data"
    assert main(["data", "generate", "--n", "12", "--seed", "0", "--workers", "1", "--no-progress",
                 "--out", str(root)]) == 0
    ds = Dataset.open(root)
    ids = [s.scenario_id for s in ds.load()]
    ds.update_manifest(splits={"train": ids[:8], "eval": ids[8:]})
    return root


def test_bench_data_loads_the_first_n(generated: Path, capsys: pytest.CaptureFixture[str]) -> None:
    result = _run(["bench", "data", str(generated), "--n", "5"], capsys)
    assert result["scenarios_loaded"] == 5
    assert result["scenarios_per_s"] == pytest.approx(5 / result["seconds"], rel=0.05, abs=0.5)
    assert result["meets_target"] == (result["seconds"] < 2.0)


def test_fit_skills_writes_loadable_models_and_metrics(
    generated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    from seal.models.skills.io import load_skill_models

    out = tmp_path / "skills"
    result = _run(["fit", "skills", str(generated), "--split", "all", "--out", str(out), "--preset", "quick",
                   "--limit", "12", "--workers", "1", "--no-progress", "--set", "val_fraction=0.3",
                   "--set", "max_benign_windows=1500", "--set", "max_val_windows=600", "--set", "plot_states=5",
                   "--set", "vae_train={max_epochs: 1, patience: 1, max_minutes: 0.2}",
                   "--set", "prior_train={max_epochs: 1, patience: 1, max_minutes: 0.1}"], capsys)
    demos = result["demonstrations"]
    assert demos["scenarios"] == 12 and demos["agents"] == sum(demos["agents_per_source"].values())
    used = result["windows_used"]
    assert used["train_benign"] == 1500  # the cap
    assert used["train_adversarial"] > 0 and used["val_adversarial"] > 0
    assert used["train_adversarial"] + used["val_adversarial"] <= demos["windows_adversarial"]
    for name in ("vae.pt", "prior_benign.pt", "prior_adversarial.pt", "metrics.json", "config.yaml",
                 "embedding.png", "demos_log.npz", "demos_heuristic.npz"):
        assert (out / name).is_file(), name
    assert json.loads((out / "metrics.json").read_text())["windows_used"] == used
    models = load_skill_models(out)
    assert models.vae is not None and set(models.priors) == {"benign", "adversarial"}
    reach = result["reach"]["benign"]  # each prior's reach over the plot's 5 held-out states
    assert set(result["reach"]) == {"benign", "adversarial"} and reach["states"] == 5
    for bound in ("1", "2", "3"):
        cell = reach[f"noise_bound_{bound}"]
        assert -1 <= cell["hardest_braking"]["p10"] <= cell["hardest_braking"]["p90"] <= 1
        assert cell["hardest_braking"]["p50"] <= cell["strongest_throttle"]["p50"]
    braking = result["braking_probe"]  # closed loop behind a braking car, both priors and the heuristic reference
    assert set(braking) == {"probe", "noise_scale", "heuristic_driver", "benign_prior", "adversarial_prior"}
    assert braking["heuristic_driver"]["contact_share"] == 0.0
    assert 0.0 <= braking["adversarial_prior"]["contact_share"] <= 1.0


def test_fit_then_eval_objective_give_the_same_held_out_report(
    generated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str],
) -> None:
    """`seal eval objective` on the fitted model and its held-out labels repeats the fit's report exactly."""
    out = tmp_path / "objective"
    common = ["--candidates", "lanes", "--preset", "quick", "--eval-limit", "3", "--workers", "1",
              "--set", "n_candidates=8", "--no-progress"]
    fit = _run(["fit", "objective", str(generated), "--out", str(out), "--limit", "4", *common,
                "--set", "train={max_epochs: 1, pairs_per_epoch: 200, batch_size: 64, patience: 1, max_minutes: 0.2}"],
               capsys)
    assert (fit["train_split"], fit["eval_split"]) == ("train", "eval")
    assert fit["train_labels"]["scenarios"] == 4 and fit["train_labels"]["candidates"] == 8
    assert fit["fit"]["epochs"] == 1
    for name in ("objective.pt", "objective.json", "report.json", "report.md", "train_log.csv", "config.yaml"):
        assert (out / name).is_file(), name
    assert json.loads((out / "report.json").read_text())["mse"] == fit["mse"]
    evaluated = _run(["eval", "objective", str(out / "objective.pt"), str(generated), *common], capsys)
    assert evaluated["mse"] == fit["mse"]
    assert evaluated["ranking_logged_prev"] == fit["ranking_logged_prev"]
    assert evaluated["ranking_logged_prev"]["pi_score"]["scenarios"] == 3


def test_demo_writes_its_dataset_roll_outs_and_video(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "demo"
    capsys.readouterr()
    assert main(["demo", "--out", str(out), "--n", "4", "--rollouts", "2", "--seed", "0"]) == 0
    printed = capsys.readouterr().out
    assert len(Dataset.open(out / "data").load()) == 4
    rows = list(csv.DictReader((out / "rollouts.csv").open()))
    assert len(rows) == 2 and all(r["outcome"] for r in rows)
    summary = (out / "summary.md").read_text()
    assert "| all | 2 |" in summary and "| all | 2 |" in printed
    assert [p.suffix for p in (out / "videos").iterdir()] and all(p.stat().st_size > 0
                                                                   for p in (out / "videos").iterdir())
    # A second run reuses the dataset and rolls the same episodes out again.
    first = (out / "rollouts.csv").read_text()
    assert main(["demo", "--out", str(out), "--n", "4", "--rollouts", "2", "--seed", "0"]) == 0
    assert (out / "rollouts.csv").read_text() == first


def test_bench_training_reports_consistent_numbers(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = tiny_dataset(tmp_path)
    result = _run(["bench", "training", "--config", "quick", "--pipeline", "cat", "--dataset", str(data),
                   "--steps", "200", "--n-envs", "1", "--set", "pipelines.cat={name: rule, kwargs: {}}",
                   "--set", "hyperparams.td3={learning_starts: 30, batch_size: 16, net_arch: [16, 16], "
                   "buffer_size: 400}"], capsys)
    assert (result["measured_steps"], result["n_envs"], result["generator"], result["algo"]) == (200, 1, "rule", "td3")
    ratio = result["training_steps_per_s"] / result["env_only_steps_per_s"]
    assert result["ratio_training_vs_env_only"] == pytest.approx(ratio, abs=2e-3)
    hours = 1e6 / result["training_steps_per_s"] / 3600
    assert result["estimated_1M_steps_h"] == pytest.approx(hours, rel=0.01, abs=0.01)
    assert result["meets_target"] == (hours < 2.0)
    assert 0.0 <= result["generation_share_of_env_worker_time"] <= 1.0
