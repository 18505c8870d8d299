"""The decisive preset (issue 26): its plan passes the check with the real trainer configs (every pipeline of the
registry x ReSkill and TD3 x 4 seeds, the split sizes, every generator setting with K = 5, a real-data setting),
and a toy variant of it runs end to end through `seal run` (injected step / job functions, the real report): run
folders per algorithm, ReSkill runs on the fitted skills, and a report that keeps the algorithms apart."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import scenario_factory as sf
import yaml
from results_builders import episode
from run_builders import FakeTasks, fake_train

from seal.adversaries.base import pipeline_names
from seal.cli import main
from seal.core.dataset import write_dataset
from seal.experiments.backends import InlineBackend
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.pipeline.references import fits_needed, planned_runs
from seal.experiments.pipeline.run import check_run, load_run_config, run_pipeline, train_config

PRESET = Path(__file__).resolve().parents[2] / "experiments" / "configs" / "decisive.yaml"


@pytest.fixture()
def real_dataset(tmp_path: Path) -> str:
    """An imported-recordings stand-in: the preset's ``real:`` setting pointed at it."""
    root = tmp_path / "ngsim"
    write_dataset(root, [sf.highway_scenario(i) for i in range(2)])
    return str(root)


def _settings_with(real: str, settings: list[str]) -> str:
    return "eval.settings=" + json.dumps([*settings, f"real:{real}"])


def test_decisive_plan_is_every_pipeline_times_two_algorithms_times_four_seeds(tmp_path: Path, real_dataset: str
                                                                               ) -> None:
    config = load_run_config(PRESET)
    assert config["pipelines"] == list(pipeline_names()) and config["algos"] == ["reskill", "td3"]
    assert config["seeds"] == [0, 1, 2, 3]
    split = config["data"]["split"]
    assert (split["n_train"], split["n_eval"], split["n_hard"], split["hard_by"]) == (1000, 300, 300, "pair")
    ev = config["eval"]
    assert ev["k"] == 5 and ev["limit"] is None
    assert set(pipeline_names()) - {"noadv"} <= set(ev["settings"])
    assert {"normal", "hard", "normal-reactive"} <= set(ev["settings"])
    assert any(s.startswith("real:") for s in ev["settings"])
    assert set(fits_needed(config)) == {"prior", "goose", "skills", "ego_skills", "objective", "behavior", "probes"}
    # the ReSkill ego needs its own skills, fitted on the SEAL skills' demonstrations (so those come first)
    assert fits_needed({**config, "pipelines": ["noadv"], "eval": {}}) == ["skills", "ego_skills"]
    assert {k: v for k, v in config["fit"]["ego_skills"].items() if k != "set"} == {
        "model": "skills", "preset": "ego", "demos": "${fit.skills}", "no_progress": True}
    settings = [s for s in ev["settings"] if not s.startswith("real:")]
    plan = check_run(PRESET, tmp_path / "out", [_settings_with(real_dataset, settings)])
    assert len(plan["runs"]) == 56 and "seal-rcg-reskill-s3" in plan["runs"] and "noadv-td3-s0" in plan["runs"]
    # the precision pool: 600 Normal + 600 Hard scenarios of other traffic runs, built into OUT/heldout/seed1
    assert plan["eval_heldout"] == [str((tmp_path / "out" / "heldout" / "seed1").resolve())]
    (pool,) = ev["heldout"]
    assert pool["generate"]["seed"] != config["data"]["generate"]["seed"]
    assert (pool["split"]["n_train"], pool["split"]["n_eval"], pool["split"]["n_hard"]) == (0, 600, 600)
    assert not (tmp_path / "out").exists()



def test_no_decisive_fit_stops_on_a_wall_clock_budget(tmp_path: Path, real_dataset: str) -> None:
    """A budget that binds makes a model depend on the machine's speed and load: every fit of the preset stops on
    its epochs / steps and patience alone, resolved as the fit itself resolves its options."""
    from dataclasses import asdict

    from seal.experiments.pipeline.tasks import FIT_CONFIGS

    fits = load_run_config(PRESET)["fit"]
    assert fits["prior"].get("no_time_budget") is True and "max_minutes" not in fits["prior"]
    budgets = {}
    for name in ("goose", "skills", "ego_skills", "objective", "behavior"):
        options = {k: v for k, v in fits[name].items() if k != "model"}
        config = asdict(FIT_CONFIGS[fits[name].get("model", name)](options))
        budgets[name] = {section: values["max_minutes"] for section, values in config.items()
                         if isinstance(values, dict) and "max_minutes" in values}
    assert budgets == {"goose": {}, "skills": {"vae_train": None, "prior_train": None},
                       "ego_skills": {"vae_train": None, "prior_train": None},
                       "objective": {"train": None}, "behavior": {"train": None}}
    # a bad override fails the plan check, naming the fit and the key, before anything is written
    sets = [_settings_with(real_dataset, ["normal"]), "fit.behavior.set=[train.max_minute=null]"]
    with pytest.raises(ValueError, match=r"fit.behavior: .*train.max_minute"):
        check_run(PRESET, tmp_path / "out", sets)
    assert not (tmp_path / "out").exists()


def test_seal_run_check_prints_the_plan_and_writes_nothing(tmp_path: Path, real_dataset: str, capsys) -> None:
    out = tmp_path / "o"
    sets = ["--set", _settings_with(real_dataset, ["normal", "hard", "seal"])]
    assert main(["run", str(PRESET), "--out", str(out), "--check", "--json", *sets]) == 0
    plan = json.loads(capsys.readouterr().out)
    assert len(plan["runs"]) == 56 and plan["eval_k"] == 5 and plan["eval_settings"][:3] == ["normal", "hard", "seal"]
    assert main(["run", str(PRESET), "--out", str(out), "--check", *sets, "--set", "algos=[reskill, dqn]"]) == 2
    assert "algos: expected a list of distinct ego algorithms" in capsys.readouterr().err
    assert not out.exists()


def test_each_run_gets_its_algorithm_and_the_reskill_runs_the_fitted_skills(real_dataset: str) -> None:
    config = load_run_config(PRESET, [_settings_with(real_dataset, ["normal"])])
    runs = planned_runs(config)
    assert runs["cat-td3-s2"] == ("cat", 2, "td3") and runs["seal-reskill-s0"] == ("seal", 0, "reskill")
    from seal.experiments.pipeline.references import with_algo, with_models

    resolved = with_models(config, {"skills": "/m/skills", "ego_skills": "/m/ego_skills"})
    gens = {"seal": {"prior": "/m/prior.pt", "objective": "/m/objective/objective.pt", "skills": "/m/skills"}}
    reskill = train_config(with_algo(resolved, "reskill"), PRESET, "seal", 0, "/d", gens)
    td3 = train_config(with_algo(resolved, "td3"), PRESET, "seal", 0, "/d", gens)
    assert reskill["algo"] == "reskill" and reskill["hyperparams"]["skills"] == "/m/ego_skills"
    assert td3["algo"] == "td3" and td3["hyperparams"]["train_freq"] == 2
    assert reskill["generator"] == td3["generator"] == {"name": "seal", "kwargs": gens["seal"]}
    # The ReSkill ego is time-aware, TD3 is not (`algo_train`; the preset's comments give the measurements).
    assert reskill["deadline_obs"] is True and td3["deadline_obs"] is False


def _eval(job) -> dict:
    """Four scenarios per setting: SEAL's ReSkill egos solve all four, every other ego the first two."""
    builtin = job["run"] in ("replay", "heuristic")  # the preset's reference egos
    cfg = yaml.safe_load((Path(job["run"]) / "config.yaml").read_text()) if not builtin else {}
    pipeline, seed = cfg.get("pipeline", job["run"]), cfg.get("seed", 0)
    wins = 4 if (pipeline, cfg.get("algo")) == ("seal", "reskill") else 2
    with ResultsStore(job["store"]) as store:
        store.upsert_episodes([episode(run=job["run"], setting=s["name"], pipeline=pipeline, seed=seed,
                                       scenario_id=f"s{i}", outcome="success" if i < wins else "crash")
                               for s in job["settings"] for i in range(4)])
        store.upsert_run(job["run"], pipeline, seed, job["run"], None if builtin else job["run"], cfg)
    return {"run": job["run"]}


def test_toy_decisive_runs_end_to_end_and_reports_the_algorithms_apart(tmp_path: Path, real_dataset: str) -> None:
    sets = ["seeds=[0,1]", _settings_with(real_dataset, ["normal", "cat"]), "report.plots=false",
            "report.videos=0", "report.reps=100", "report.poi_reps=50"]
    out = tmp_path / "toy"
    tasks = FakeTasks()
    summary = run_pipeline(PRESET, out, backend=InlineBackend(), task_fn=tasks, train_fn=fake_train, eval_fn=_eval,
                           progress=False, sets=sets)
    fits = {Path(c[2]).name: c for c in tasks.calls if c[0] not in ("generate", "score", "split")}
    fitted = [c[0] for c in fits.values()]
    assert fitted.index("prior") < fitted.index("probes") and sorted(fitted) == sorted([
        "prior", "goose", "skills", "skills", "objective", "behavior", "probes"])
    # the named fit: the skills command, into models/ego_skills, on the demonstrations of models/skills
    kind, _, ego_out, options = fits["ego_skills"]
    assert kind == "skills" and options == {"preset": "ego", "demos": str(out / "models" / "skills"),
                                            "set": ["vae_train.max_minutes=null", "prior_train.max_minutes=null"],
                                            "no_progress": True}
    assert list(fits).index("skills") < list(fits).index("ego_skills")
    assert len(summary["runs"]) == 7 * 2 * 2 and not summary["errors"]
    reskill = yaml.safe_load((out / "runs" / "noadv-reskill-s1" / "config.yaml").read_text())
    assert reskill["algo"] == "reskill" and reskill["hyperparams"]["skills"] == str(out / "models" / "ego_skills")
    models = out / "models"
    assert yaml.safe_load((out / "runs" / "steered-td3-s0" / "config.yaml").read_text())["generator"] == {
        "name": "steered", "kwargs": {"prior": str(models / "prior.pt"), "steer": str(models / "probes")}}
    report = out / "report"
    md = (report / "report.md").read_text()
    assert "### Ego algorithm: reskill" in md and "### Ego algorithm: td3" in md
    assert "| normal | seal (reskill) | 100.0 % [" in md and "| cat | seal (reskill) |" in md
    assert "| heuristic | 1 | 50.0 [50.0-50.0] (4) |" in md  # eval.egos: the heuristic driver as a reference row
    assert md.count("| P(row > column) |") == 2 and "**normal** (td3 egos) (4 scenarios)" in md  # a matrix per algo
    with open(report / "improvement.csv") as f:
        poi = list(csv.DictReader(f))
    assert all(r["pipeline"][r["pipeline"].index("("):] == r["reference"][r["reference"].index("("):] for r in poi)
    assert len(poi) == 2 * 7 * 6  # every ordered pair within each algorithm
    best = next(r for r in poi if (r["pipeline"], r["reference"]) == ("seal (reskill)", "cat (reskill)"))
    assert float(best["p_improvement"]) == 1.0 and int(best["settings"]) == 3


def test_algo_train_sets_one_algorithm_apart(real_dataset: str) -> None:
    """``algo_train: {td3: {...}}`` applies to that algorithm's runs only, after ``train``; an unknown algorithm is
    an error before anything runs, one the plan does not train is ignored."""
    from seal.experiments.pipeline.references import with_algo, with_models

    sets = [_settings_with(real_dataset, ["normal"]), "algo_train={td3: {deadline_obs: false, hyperparams: "
            "{td3: {train_freq: 4}}}}"]
    config = with_models(load_run_config(PRESET, sets), {"skills": "/m/skills", "ego_skills": "/m/ego_skills"})
    reskill = train_config(with_algo(config, "reskill"), PRESET, "noadv", 0, "/d", {})
    td3 = train_config(with_algo(config, "td3"), PRESET, "noadv", 0, "/d", {})
    assert reskill["deadline_obs"] is True and td3["deadline_obs"] is False
    assert td3["hyperparams"]["train_freq"] == 4 and td3["hyperparams"]["learning_starts"] == 5000  # nested keys
    with pytest.raises(ValueError, match=r"'algo_train' names unknown ego algorithm\(s\) \['dqn'\]"):
        load_run_config(PRESET, [*sets[:1], "algo_train={dqn: {deadline_obs: false}}"])
    load_run_config(PRESET, [*sets[:1], "algos=[reskill]"])  # an algorithm the plan does not train is ignored
    with pytest.raises(ValueError, match="'algo_train' must be a mapping"):
        load_run_config(PRESET, [*sets[:1], "algo_train={td3: 3}"])
