"""`seal run` orchestration with injected step and job functions: the step order, what each step gets,
skip-on-rerun, changed parameters, failing jobs; the step tasks' options; and the shipped presets."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import scenario_factory as sf
import yaml
from run_builders import FakeTasks, fake_eval, fake_train, fake_train_config, run, write_preset

from seal.core.dataset import Dataset, write_dataset
from seal.experiments.backends import InlineBackend
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.pipeline.references import fits_needed, substitute
from seal.experiments.pipeline.run import load_run_config, run_pipeline
from seal.experiments.pipeline.tasks import run_task

CONFIGS = Path(__file__).resolve().parents[2] / "experiments" / "configs"


def test_steps_then_skip_on_rerun(tmp_path: Path) -> None:
    preset, out = write_preset(tmp_path), tmp_path / "out"
    commands = FakeTasks()
    summary = run(preset, out, commands)
    data = str(out / "data")
    prior = str(out / "models" / "prior.pt")
    assert commands.calls == [
        ("generate", data, None, {"n": 3, "seed": 0}),
        ("score", data, None, {}),
        ("split", data, None, {"n_train": 1, "n_eval": 2, "n_hard": 1}),
        # only the prior: goose and skills are not referenced by the generators in use (cat)
        ("prior", data, prior, {"epochs": 1, "no_progress": True}),
    ]
    assert summary["steps_ran"] == ["data", "score", "split", "fit-prior", "eval", "report"]
    assert summary["train_jobs"] == 4 and len(summary["runs"]) == 4 and summary["models"] == {"prior": prior}
    cat_cfg = yaml.safe_load((out / "runs" / "cat-s1" / "config.yaml").read_text())
    assert cat_cfg["generator"] == {"name": "cat", "kwargs": {"prior": prior, "follow": "replay"}}
    with ResultsStore(out / "results.sqlite") as store:
        assert store.count() == 5 * 3  # 4 trained egos + the Replay ego, 3 settings
        assert {r["pipeline"] for r in store.runs()} == set()  # fake_eval records episodes only
    assert (out / "report" / "report.md").is_file() and (out / "report" / "table_6_1.csv").is_file()
    assert json.loads((out / "summary.json").read_text())["errors"] == []

    # second run: every step done, nothing runs
    def must_not_train(job):
        raise AssertionError(f"trained {job['out']} again")

    again = run(preset, out, commands, train=must_not_train)
    assert len(commands.calls) == 4 and again["steps_ran"] == [] and again["train_jobs"] == 0
    assert again["steps_skipped"] == ["data", "score", "split", "fit-prior", "eval", "report"]


def test_changed_parameters_rerun_only_what_changed(tmp_path: Path) -> None:
    out, commands = tmp_path / "out", FakeTasks()
    run(write_preset(tmp_path), out, commands)
    trained = []

    def train(job):
        trained.append(Path(job["out"]).name)
        return fake_train(job)

    summary = run(write_preset(tmp_path, seeds=(0, 1, 2)), out, commands, train=train)
    assert sorted(trained) == ["cat-s2", "noadv-s2"]
    assert summary["steps_ran"] == ["eval", "report"]  # new egos: evaluate (incrementally) and report again
    with ResultsStore(out / "results.sqlite") as store:
        assert store.count() == 7 * 3


def test_reference_egos_are_evaluated_beside_the_trained_ones(tmp_path: Path) -> None:
    out, commands = tmp_path / "out", FakeTasks()
    run(write_preset(tmp_path), out, commands)
    evaluated = []

    def evaluate(job):
        evaluated.append(job["run"])
        return fake_eval(job)

    # eval.egos added after a finished run: nothing is trained again, the eval step runs for the new ego list
    preset = write_preset(tmp_path, eval={"settings": ["normal", "hard", "cat"], "k": 2, "limit": 2,
                                          "egos": ["heuristic"]})
    summary = run(preset, out, commands, train=lambda job: pytest.fail(f"trained {job['out']}"), evaluate=evaluate)
    assert summary["steps_ran"] == ["eval", "report"]
    assert evaluated[-2:] == ["heuristic", "replay"] and len(evaluated) == 6
    with ResultsStore(out / "results.sqlite") as store:
        assert store.count() == 6 * 3 and store.count(run="heuristic") == 3


def test_heldout_pools_are_evaluated_beside_the_runs_own(tmp_path: Path) -> None:
    """``eval.heldout``: every setting but ``real:`` also on another pool's eval / hard splits, into the same store
    (rows keyed by dataset); a pool that is the run's own, lacks a split or is not a list fails the plan check."""
    pool = tmp_path / "heldout"
    FakeTasks()({"task": "generate", "dataset": str(pool), "options": {}})
    FakeTasks()({"task": "split", "dataset": str(pool), "options": {}})
    out, commands, seen = tmp_path / "out", FakeTasks(), []

    def evaluate(job):
        seen.append(sorted((s["name"], Path(s["dataset"]).name) for s in job["settings"]))
        return fake_eval(job)

    settings = ["normal", "hard", "cat", f"real:{pool}"]
    run(write_preset(tmp_path, eval={"settings": settings, "k": 2, "limit": 2, "heldout": [str(pool)]}), out,
        commands, evaluate=evaluate)
    assert seen[0] == sorted([("normal", "data"), ("hard", "data"), ("cat", "data"), (f"real:{pool.resolve()}",
                                                                                     "heldout"),
                              ("normal", "heldout"), ("hard", "heldout"), ("cat", "heldout")])
    with ResultsStore(out / "results.sqlite") as store:
        assert store.count() == 5 * 7  # 4 trained egos + Replay, 3 settings on each pool + the real one
    assert "normal@heldout" in (out / "report" / "report.md").read_text()
    for heldout, message in (([str(out / "data")], "is the run's own dataset"), ("x", "must be a list"),
                             ([str(tmp_path / "none")], "eval.heldout: .*none")):
        with pytest.raises(ValueError, match=message):
            run(write_preset(tmp_path, eval={"settings": settings, "heldout": heldout}), out, commands)
    Dataset.open(pool).update_manifest(splits={"train": [], "eval": Dataset.open(pool).splits["eval"], "hard": []})
    with pytest.raises(ValueError, match="has no hard split"):
        run(write_preset(tmp_path, eval={"settings": settings, "heldout": [str(pool)]}), out, commands)
    # a given dataset (data.path) generated with the pool's seed: the same traffic runs
    for root in (out / "data", pool):
        Dataset.open(root).update_manifest(provenance={"source": "highway-env", "seed": 5})
    with pytest.raises(ValueError, match="generated with seed 5, as the run's pool"):
        run(write_preset(tmp_path, data={"path": str(out / "data")},
                         eval={"settings": ["normal"], "heldout": [str(pool)]}), tmp_path / "out2", commands)


def test_a_heldout_pool_the_run_builds_is_made_after_the_data_and_skipped_after(tmp_path: Path) -> None:
    """``eval.heldout: [{name, generate, score, split}]``: generate / score / split into OUT/heldout/<name> (right
    after the run's own data, so a pool that cannot be split fails before the training), evaluated like a given
    pool, skipped on a re-run; a bad entry fails the plan."""
    out, commands, seen = tmp_path / "out", FakeTasks(), []

    def evaluate(job):
        seen.append(sorted({Path(s["dataset"]).name for s in job["settings"]}))
        return fake_eval(job)

    pool = {"name": "seed7", "generate": {"n": 3, "seed": 7}, "split": {"n_train": 0, "n_eval": 2, "n_hard": 1}}
    preset = write_preset(tmp_path, eval={"settings": ["normal", "hard"], "k": 2, "limit": 2, "heldout": [pool]})
    summary = run(preset, out, commands, evaluate=evaluate)
    built = str(out / "heldout" / "seed7")
    assert [(c[0], c[3]) for c in commands.calls if c[1] == built] == [
        ("generate", pool["generate"]), ("score", {}), ("split", pool["split"])]
    assert summary["steps_ran"][:6] == ["data", "score", "split", "heldout-seed7-data", "heldout-seed7-score",
                                        "heldout-seed7-split"]
    assert seen[0] == ["data", "seed7"] and Dataset.open(built).splits["hard"]
    assert "normal@seed7" in (out / "report" / "report.md").read_text()
    from seal.experiments.pipeline.status import run_status

    states = {s["name"]: s["state"] for s in run_status(preset, out)["steps"]}
    assert states["heldout-seed7-split"] == "done"
    assert run(preset, out, commands, evaluate=evaluate)["steps_ran"] == []  # all done: nothing again
    for entry, message in (({**pool, "generate": {"n": 3, "seed": 0}}, r"seed7\]\.generate\.seed: 0 is the run's"),
                           ({**pool, "name": "../x"}, "needs a folder name"),
                           ({**pool, "splits": {}}, r"unknown key\(s\) \['splits'\]"),
                           ({**pool, "split": {"n_eval": "many"}}, r"eval.heldout\[seed7\].split.n_eval must be"),
                           ({"name": "a", "generate": {"seed": 2}}, r"eval.heldout\[a\].generate.n: missing")):
        with pytest.raises(ValueError, match=message):
            run(write_preset(tmp_path, eval={"settings": ["normal"], "heldout": [entry]}), tmp_path / "o2", commands)
    with pytest.raises(ValueError, match="share a name"):
        run(write_preset(tmp_path, eval={"settings": ["normal"], "heldout": [pool, pool]}), tmp_path / "o2", commands)
    assert not (tmp_path / "o2").exists()


def test_failed_job_is_reported_and_retried(tmp_path: Path) -> None:
    out, commands = tmp_path / "out", FakeTasks()
    with pytest.raises(RuntimeError, match=r"(?s)1 job\(s\) failed.*cat-s13: RuntimeError: diverged"):
        run(write_preset(tmp_path, seeds=(0, 13), pipelines=["cat"]), out, commands)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == [str(out / "runs" / "cat-s0")] and len(summary["errors"]) == 1
    with ResultsStore(out / "results.sqlite") as store:  # what trained was still evaluated and reported
        assert {r["run"] for r in store.episodes()} == {str(out / "runs" / "cat-s0"), "replay"}
    tried = []

    def train(job):
        tried.append(Path(job["out"]).name)
        return fake_train({**job, "config": {**job["config"], "seed": 99}})

    run(write_preset(tmp_path, seeds=(0, 13), pipelines=["cat"]), out, commands, train=train)
    assert tried == ["cat-s13"]  # only the failed run is tried again


def test_existing_dataset_and_model_paths(tmp_path: Path) -> None:
    data = tmp_path / "data"
    FakeTasks()({"task": "generate", "dataset": str(data), "options": {}})
    FakeTasks()({"task": "split", "dataset": str(data), "options": {}})
    model = tmp_path / "models" / "goose.zip"
    model.parent.mkdir()
    model.write_bytes(b"")  # the fake trainer never opens it; the plan check only needs it to exist
    preset = write_preset(tmp_path, data={"path": str(data)}, pipelines=["goose"],
                          generators={"goose": {"model": "${fit.goose}"}}, eval={"settings": ["normal"], "limit": 1},
                          fit={"goose": {"path": str(model)}})
    commands = FakeTasks()
    summary = run(preset, tmp_path / "out", commands)
    assert commands.calls == []  # nothing generated, nothing fitted: goose's model is given as a path
    assert summary["dataset"] == str(data.resolve()) and summary["models"] == {"goose": str(model.resolve())}


def test_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown key.*'bogus'"):
        load_run_config(write_preset(tmp_path, bogus=1))
    with pytest.raises(ValueError, match="'seeds' must be a non-empty list"):
        load_run_config(write_preset(tmp_path, seeds=()))
    config = load_run_config(write_preset(tmp_path, generators={"cat": {"prior": "${fit.nothing}"}}))
    with pytest.raises(ValueError, match="no fit.nothing entry"):
        fits_needed(config)


def test_set_overrides_the_preset(tmp_path: Path) -> None:
    path = write_preset(tmp_path)
    config = load_run_config(path, ["eval.limit=3", "seeds=[5]"])
    assert config["eval"]["limit"] == 3 and config["seeds"] == [5]
    assert load_run_config(path)["seeds"] != [5]  # the file is left alone
    with pytest.raises(ValueError, match="--set: unknown key.*'evals'"):
        load_run_config(path, ["evals.limit=3"])


def test_set_reaches_the_steps_and_the_trainer_config(tmp_path: Path) -> None:
    from seal.experiments.pipeline.run import train_config

    preset, commands = write_preset(tmp_path), FakeTasks()
    run_pipeline(preset, tmp_path / "out", backend=InlineBackend(), task_fn=commands, train_fn=fake_train,
                 eval_fn=fake_eval, train_config_fn=fake_train_config, progress=False,
                 sets=["fit.prior.epochs=7", "seeds=[4]"])
    assert ("prior", str(tmp_path / "out" / "data"), str(tmp_path / "out" / "models" / "prior.pt"),
            {"epochs": 7, "no_progress": True}) in commands.calls
    assert sorted(p.name for p in (tmp_path / "out" / "runs").iterdir()) == ["cat-s4", "noadv-s4"]
    # The trainer config follows the run config's train section (a --set there too), not only the file's.
    config = load_run_config(CONFIGS / "quick.yaml", ["train.total_timesteps=1234"])
    assert train_config(config, CONFIGS / "quick.yaml", "noadv", 0, "/d", {})["total_timesteps"] == 1234


def test_fit_dependencies_come_first(tmp_path: Path) -> None:
    fit = {"objective": {"prior": "${fit.prior}"}, "prior": {"epochs": 1}, "skills": {}}
    config = load_run_config(write_preset(tmp_path, fit=fit, pipelines=["seal"],
                                          generators={"seal": {"objective": "${fit.objective}/objective.pt"}}))
    assert fits_needed(config) == ["prior", "objective"]
    commands = FakeTasks()
    out = tmp_path / "out"
    commands.calls.clear()
    run_pipeline(config_path=tmp_path / "preset.yaml", out=out, backend=InlineBackend(), task_fn=commands,
                 train_fn=fake_train, eval_fn=fake_eval, train_config_fn=fake_train_config, progress=False)
    fits = [c for c in commands.calls if c[0] in ("prior", "objective")]
    assert [c[0] for c in fits] == ["prior", "objective"]
    assert fits[1][3] == {"prior": str(out / "models" / "prior.pt")}
    seal_cfg = yaml.safe_load((out / "runs" / "seal-s0" / "config.yaml").read_text())
    assert seal_cfg["generator"]["kwargs"] == {"objective": str(out / "models" / "objective" / "objective.pt")}
    fit["prior"]["prior"] = "${fit.objective}"
    with pytest.raises(ValueError, match="circular"):
        fits_needed(load_run_config(write_preset(tmp_path, fit=fit, pipelines=["seal"],
                                                 generators={"seal": {"objective": "${fit.objective}"}})))


def test_failed_step_stops_the_pipeline(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    def failing(job) -> None:
        raise OSError("disk full")

    def go() -> None:
        run_pipeline(write_preset(tmp_path), tmp_path / "out", backend=InlineBackend(), task_fn=failing,
                     train_fn=fake_train, eval_fn=fake_eval, train_config_fn=fake_train_config, progress=False)

    with pytest.raises(RuntimeError) as error:
        go()
    assert str(error.value) == "step data failed: OSError: disk full"  # one line: what and why, no traceback
    assert not (tmp_path / "out" / "steps" / "data.json").exists()  # not marked done: runs again next time
    monkeypatch.setenv("SEAL_DEBUG", "1")
    with pytest.raises(RuntimeError, match=r"(?s)step data failed: OSError: disk full\n.*raise OSError"):
        go()


def test_tasks_check_their_options(tmp_path: Path) -> None:
    """The step tasks take the matching command's options (without dashes) and name unknown ones."""
    with pytest.raises(ValueError, match=r"split: unknown option\(s\) \['n_trian'\]; known: \['hard_quantile'"):
        run_task({"task": "split", "dataset": str(tmp_path), "options": {"n_trian": 80}})
    with pytest.raises(ValueError, match=r"prior: unknown option\(s\) \['epoch'\]"):
        run_task({"task": "fit", "model": "prior", "dataset": str(tmp_path), "out": "p.pt", "options": {"epoch": 1}})
    with pytest.raises(ValueError, match="fit: unknown model 'bogus'"):
        run_task({"task": "fit", "model": "bogus", "dataset": str(tmp_path), "out": "x", "options": {}})
    with pytest.raises(ValueError, match="unknown task 'clean'"):
        run_task({"task": "clean", "dataset": str(tmp_path), "options": {}})


def test_split_task_is_the_split_command(tmp_path: Path) -> None:
    """A real task in process: `split` writes the splits `seal data split` writes for the same options."""
    from seal.cli import main

    for name in ("a", "b"):
        write_dataset(tmp_path / name, [sf.highway_scenario(i).with_metadata(group=f"run{i}") for i in range(6)])
        assert main(["data", "score", str(tmp_path / name), "--workers", "1", "--no-progress"]) == 0
    run_task({"task": "split", "dataset": str(tmp_path / "a"),
              "options": {"n_train": 2, "n_eval": 2, "n_hard": 1, "seed": 3, "hard_by": "scene"}})
    assert main(["data", "split", str(tmp_path / "b"), "--n-train", "2", "--n-eval", "2", "--n-hard", "1",
                 "--seed", "3", "--hard-by", "scene"]) == 0
    assert Dataset.open(tmp_path / "a").splits == Dataset.open(tmp_path / "b").splits


def test_helpers() -> None:
    assert substitute({"a": ["${fit.prior}", "x"], "b": "${fit.skills}/adv.pt"}, {"prior": "/p", "skills": "/s"}) \
        == {"a": ["/p", "x"], "b": "/s/adv.pt"}


@pytest.mark.parametrize("name", ["quick", "standard", "paper"])
def test_shipped_presets(name: str) -> None:
    config = load_run_config(CONFIGS / f"{name}.yaml")
    assert set(config["pipelines"]) == {"noadv", "goose", "cat", "seal"}
    assert set(fits_needed(config)) == {"prior", "goose", "skills", "objective"}
    assert {"normal", "hard", "cat", "goose", "seal"} <= set(config["eval"]["settings"])
    assert "train" in config and config["data"]["split"]["n_eval"] >= 16


def test_ablation_preset_trains_each_fig_6_5_variant_as_a_pipeline() -> None:
    from seal.experiments.pipeline.references import generator_of, generators_in_use, variant_of
    from seal.experiments.pipeline.run import train_config

    path = CONFIGS / "quick_ablations.yaml"
    config = load_run_config(path)
    assert set(fits_needed(config)) == {"prior", "skills", "objective"}
    assert generators_in_use(config) == ["cat", "seal"]
    gens = {"cat": {"prior": "/m/prior.pt"},
            "seal": {"prior": "/m/prior.pt", "objective": "/m/objective.pt", "skills": "/m/skills"}}
    resolved = {p: train_config(config, path, p, 0, "/d", gens) for p in config["pipelines"]}
    assert {p: generator_of(p, config) for p in config["pipelines"]} == {
        "cat": "cat", "seal": "seal", "seal_heuristic_obj": "seal", "seal_benign_prior": "seal",
        "seal_traj_only": "seal", "seal_no_curriculum": "seal", "seal_no_nonreactive_start": "seal"}
    kwargs = {p: r["generator"]["kwargs"] for p, r in resolved.items()}
    assert kwargs["seal"]["objective"] == "/m/objective.pt" and kwargs["seal"].get("switch") is None
    assert kwargs["seal_heuristic_obj"]["objective"] == "cat"
    assert kwargs["seal_benign_prior"]["switch"] == "benign" and kwargs["seal_traj_only"]["switch"] == "none"
    assert all(k["skills"] == "/m/skills" for k in kwargs.values() if "skills" in k)
    curriculum = {p: r["curriculum"] for p, r in resolved.items()}
    assert curriculum["seal"] == {"slope": 1.8, "cap": 0.9, "warmup": 0.1}
    assert curriculum["seal_no_curriculum"] == {"slope": 1000.0, "cap": 0.9, "warmup": 0.1}
    assert curriculum["seal_no_nonreactive_start"] == {"slope": 1.8, "cap": 0.9, "warmup": 0.0}
    assert all(r["pipeline"] == p for p, r in resolved.items())
    with pytest.raises(ValueError, match=r"variants\.x: unknown key\(s\) \['kwarg'\]"):
        variant_of({"variants": {"x": {"generator": "seal", "kwarg": {}}}}, "x")
    with pytest.raises(ValueError, match=r"variants\.seal_traj_only: unknown key"):  # at load, before any step
        load_run_config(path, ["variants.seal_traj_only.kwarg={}"])


def test_time_aware_variants_of_a_generator_and_of_noadv() -> None:
    """``variants`` with ``train: {deadline_obs: true}``: the time-aware ablation of a pipeline, noadv included
    (``generator: noadv`` trains without an adversary under the variant's own name)."""
    from seal.experiments.pipeline.references import generator_of
    from seal.experiments.pipeline.run import train_config

    path = CONFIGS / "quick.yaml"
    config = load_run_config(path, [
        "pipelines=[noadv, noadv-dl, goose, goose-dl]",
        "variants={noadv-dl: {generator: noadv, train: {deadline_obs: true}}, "
        "goose-dl: {generator: goose, train: {deadline_obs: true}}}"])
    gens = {"goose": {"model": "/m/goose.zip"}}
    resolved = {p: train_config(config, path, p, 0, "/d", gens) for p in config["pipelines"]}
    assert {p: generator_of(p, config) for p in config["pipelines"]} == {
        "noadv": None, "noadv-dl": None, "goose": "goose", "goose-dl": "goose"}
    assert {p: r["generator"]["name"] for p, r in resolved.items()} == {
        "noadv": None, "noadv-dl": None, "goose": "goose", "goose-dl": "goose"}
    assert {p: r["deadline_obs"] for p, r in resolved.items()} == {
        "noadv": False, "noadv-dl": True, "goose": False, "goose-dl": True}
    assert resolved["goose-dl"]["generator"]["kwargs"]["model"] == "/m/goose.zip"
    assert all(r["pipeline"] == p for p, r in resolved.items())


def test_non_reactive_start_keeps_p_at_zero_then_ramps() -> None:
    from seal.experiments.bench.training import mean_perturb_probability
    from seal.experiments.training.curriculum import perturb_probability

    assert perturb_probability(99, 1000, warmup=0.1) == 0.0
    assert perturb_probability(100, 1000, warmup=0.1) == 0.0
    assert perturb_probability(200, 1000, warmup=0.1) == pytest.approx(0.18)
    assert perturb_probability(900, 1000, warmup=0.1) == 0.9
    assert perturb_probability(101, 1000, slope=1000.0, warmup=0.1) == 0.9  # no curriculum: cap at once
    # Mean of p over the run, against a fine numerical average.
    for slope, cap, warmup in ((1.8, 0.9, 0.0), (1.8, 0.9, 0.1), (1000.0, 0.9, 0.1)):
        numeric = sum(perturb_probability(t, 100_000, slope, cap, warmup) for t in range(100_000)) / 100_000
        assert mean_perturb_probability(slope, cap, warmup) == pytest.approx(numeric, abs=1e-3)
