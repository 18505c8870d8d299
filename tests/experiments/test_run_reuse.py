"""`reuse: OTHER_OUT` in a `seal run` preset: the data and fits of another run folder are taken only where they were
made with the same options (and the same models below them); the rest is made in the new folder."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from run_builders import FakeTasks, fake_train_config, run, write_preset

from seal.experiments.pipeline.reuse import reuse_plan
from seal.experiments.pipeline.run import check_run, load_run_config

FIT = {"prior": {"epochs": 1}, "objective": {"prior": "${fit.prior}"}}
SEAL = {"seal": {"objective": "${fit.objective}/objective.pt"}}


def _first(tmp_path: Path) -> Path:
    first = tmp_path / "first"
    run(write_preset(tmp_path, fit=FIT, pipelines=["seal"], generators=SEAL), first, FakeTasks())
    return first


def test_a_second_comparison_takes_the_data_and_fits_it_asks_for(tmp_path: Path) -> None:
    first = _first(tmp_path)
    commands = FakeTasks()
    preset = write_preset(tmp_path, fit=FIT, pipelines=["seal", "noadv"], generators=SEAL, seeds=(5,),
                          reuse=str(first))
    summary = run(preset, tmp_path / "second", commands)
    assert commands.calls == []  # nothing generated, scored, split or fitted again
    assert summary["dataset"] == str(first / "data")
    # the objective comes as a model path, so the prior it was fitted with is no longer needed here
    assert summary["models"] == {"objective": str(first / "models" / "objective")}
    cfg = yaml.safe_load((tmp_path / "second" / "runs" / "seal-s5" / "config.yaml").read_text())
    assert cfg["generator"]["kwargs"] == {"objective": str(first / "models" / "objective" / "objective.pt")}
    recorded = yaml.safe_load((tmp_path / "second" / "config.yaml").read_text())
    assert recorded["fit"]["objective"] == {"path": str(first / "models" / "objective")}  # it says where from


def test_a_fit_with_other_options_is_made_again_with_what_depends_on_it(tmp_path: Path) -> None:
    first = _first(tmp_path)
    commands = FakeTasks()
    fit = {"prior": {"epochs": 2}, "objective": {"prior": "${fit.prior}"}}
    second = tmp_path / "second"
    preset = write_preset(tmp_path, fit=fit, pipelines=["seal"], generators=SEAL, reuse=str(first))
    plan = check_run(preset, second, train_config_fn=fake_train_config)
    assert plan["reuse"] == f"reusing from {first.resolve()}: data; fitted here: prior, objective"
    run(preset, second, commands)
    # the data is the first run's; the prior has other options, and the objective was fitted on the first's prior
    assert [(c[0], c[1], c[2]) for c in commands.calls] == [
        ("prior", str(first / "data"), str(second / "models" / "prior.pt")),
        ("objective", str(first / "data"), str(second / "models" / "objective"))]


def test_other_data_options_reuse_nothing(tmp_path: Path) -> None:
    first = _first(tmp_path)
    preset = write_preset(tmp_path, fit=FIT, pipelines=["seal"], generators=SEAL,
                          data={"generate": {"n": 4, "seed": 0}}, reuse=str(first))
    config = load_run_config(preset)
    plan = reuse_plan({**config, "fit": FIT}, first)
    assert plan.dataset is None and plan.models == {} and plan.refit == ["prior", "objective"]
    commands, second = FakeTasks(), tmp_path / "second"
    run(preset, second, commands)
    made = [c[0] for c in commands.calls if c[1] == str(second / "data")]
    assert made == ["generate", "score", "split", "prior", "objective"] and len(commands.calls) == 5


def test_a_missing_model_is_fitted_again_and_a_non_run_folder_is_refused(tmp_path: Path) -> None:
    first = _first(tmp_path)
    (first / "models" / "objective").unlink()
    config = load_run_config(write_preset(tmp_path, fit=FIT, pipelines=["seal"], generators=SEAL, reuse=str(first)))
    assert config["fit"]["prior"] == {"path": str(first / "models" / "prior.pt")}
    assert config["fit"]["objective"] == FIT["objective"]
    with pytest.raises(ValueError, match="reuse: .* is not a seal run folder"):
        load_run_config(write_preset(tmp_path, reuse=str(tmp_path)))


def test_a_heldout_pool_built_with_the_same_options_is_taken_one_with_others_is_built(tmp_path: Path) -> None:
    pool = {"name": "seed7", "generate": {"n": 3, "seed": 7}, "split": {"n_train": 0, "n_eval": 2, "n_hard": 1}}
    first = tmp_path / "first"
    run(write_preset(tmp_path, eval={"settings": ["normal"], "heldout": [pool]}), first, FakeTasks())
    other = {**pool, "name": "seed8", "generate": {"n": 3, "seed": 8}}
    commands, second = FakeTasks(), tmp_path / "second"
    preset = write_preset(tmp_path, eval={"settings": ["normal"], "heldout": [pool, other]}, reuse=str(first))
    plan = check_run(preset, second, train_config_fn=fake_train_config)
    assert plan["reuse"] == f"reusing from {first.resolve()}: data, prior, heldout/seed7"
    assert plan["eval_heldout"] == [str(first / "heldout" / "seed7"), str(second / "heldout" / "seed8")]
    run(preset, second, commands)
    assert {c[1] for c in commands.calls if c[0] in ("generate", "score", "split")} == {
        str(second / "heldout" / "seed8")}
