"""`seal eval runs`: the protocol on tiny scenarios into the results store, incremental re-runs, settings,
trained-run egos, real:DIR, the CLI."""

from __future__ import annotations

from pathlib import Path

import pytest
import scenario_factory as sf

from seal.cli import main
from seal.core.dataset import Dataset
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.episodes import run_episode
from seal.experiments.evaluation.evaluate import parse_settings, read_run, resolve_eval_config
from seal.experiments.evaluation.parallel import evaluate_runs
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.training.egos import HeuristicEgo


def test_parse_settings(dataset: Path, tmp_path: Path) -> None:
    normal, hard, cat = parse_settings("normal, hard,cat", dataset)
    assert (normal.split, hard.split, cat.split, cat.generator, normal.kind) == ("eval", "hard", "eval", "cat",
                                                                                 "replay")
    assert normal.dataset == str(dataset.resolve())
    (real,) = parse_settings([f"real:{dataset}"], None)
    assert real.name == f"real:{dataset.resolve()}" and real.split == "eval" and real.generator is None
    with pytest.raises(ValueError, match="unknown setting 'bogus'.*real:DIR"):
        parse_settings("normal,bogus", dataset)
    with pytest.raises(ValueError, match="needs a dataset"):
        parse_settings("normal", None)
    with pytest.raises(Exception, match="not a seal dataset"):
        parse_settings(f"real:{tmp_path}", None)


def test_heuristic_ego_normal_and_cat_into_the_store(dataset: Path, tmp_path: Path) -> None:
    store_path = tmp_path / "r.sqlite"
    config = resolve_eval_config(candidates="lanes", k=2)
    results = evaluate_runs(["heuristic"], "normal,hard,cat", store_path, dataset=dataset, config=config,
                            progress=False)
    assert [r["run"] for r in results] == ["heuristic", "replay"]  # the Replay ego comes by default
    assert results[0]["written"] == {"normal": 2, "hard": 1, "cat": 2}
    with ResultsStore(store_path) as store:
        rows = store.episodes(run="heuristic")
        assert len(rows) == 5 and store.count() == 10
        cat = [r for r in rows if r["setting"] == "cat"]
        assert all(r["k"] == 2 and r["generations"] == 2 and r["generation_ms_mean"] > 0 for r in cat)
        assert all(r["success"] + r["crash"] + r["out_of_road"] + r["timeout"] == 1 for r in rows)
        (setting,) = [s for s in store.settings() if s["setting"] == "cat"]
        assert setting["kwargs"] == {"candidates": "lanes"} and setting["k"] == 2
        # the normal row is the episode a direct roll-out of the same ego gives
        scenario = Dataset.open(dataset).load(split="eval")[0]
        direct = run_episode(ScenarioEnv([scenario]), scenario, HeuristicEgo(), seed=0)
        (normal,) = [r for r in rows if r["setting"] == "normal" and r["scenario_id"] == scenario.scenario_id]
        assert normal["outcome"] == direct.outcome
        assert normal["route_completion"] == pytest.approx(direct.route_completion)
        before = {(r["setting"], r["scenario_id"]): r["created_at"] for r in store.episodes()}
    # re-run: everything is in the store already, nothing is played or rewritten
    again = evaluate_runs(["heuristic"], "normal,hard,cat", store_path, dataset=dataset, config=config,
                          progress=False)
    assert all(n == 0 for r in again for n in r["written"].values())
    with ResultsStore(store_path) as store:
        assert store.count() == 10
        assert {(r["setting"], r["scenario_id"]): r["created_at"] for r in store.episodes()} == before
    # another ego met by other adversaries under the same setting name: refused before anything is written
    with pytest.raises(ValueError, match=r"setting 'cat' holds episodes played with other settings \(differs in k"):
        evaluate_runs(["heuristic"], "normal,cat", store_path, dataset=dataset, replay_ego=False,
                      config=resolve_eval_config(candidates="lanes", k=3), progress=False)
    with ResultsStore(store_path) as store:
        assert store.count() == 10 and [s["k"] for s in store.settings() if s["setting"] == "cat"] == [2]


def test_incremental_limit_then_all(dataset: Path, tmp_path: Path) -> None:
    store_path = tmp_path / "r.sqlite"
    first = evaluate_runs([], "normal", store_path, dataset=dataset,
                          config=resolve_eval_config(limit=1), progress=False)
    assert first == [{"run": "replay", "written": {"normal": 1}}]
    rest = evaluate_runs([], "normal", store_path, dataset=dataset, config=resolve_eval_config(), progress=False)
    assert rest[0]["written"] == {"normal": 1}  # only the scenario not scored yet


def test_trained_run_real_dataset_and_cli(dataset: Path, tmp_path: Path, capsys) -> None:
    import stable_baselines3 as sb3

    run = tmp_path / "runs" / "cat-s3"
    run.mkdir(parents=True)
    model = sb3.TD3("MlpPolicy", ScenarioEnv(sf.curve_scenario()), seed=0, device="cpu", buffer_size=100)
    model.save(run / "final_model.zip")
    (run / "config.yaml").write_text(
        f"algo: td3\npipeline: cat\nseed: 3\ndataset: {dataset}\n"
        "generator: {name: cat, kwargs: {candidates: lanes}}\n"
    )
    ego = read_run(run)
    assert (ego.pipeline, ego.seed, ego.run) == ("cat", 3, str(run.resolve()))
    store_path = tmp_path / "r.sqlite"
    # the dataset and the cat kwargs come from the run's config.yaml
    code = main(["eval", "runs", str(run), "--settings", f"normal,cat,real:{dataset}", "--store", str(store_path),
                 "--k", "1", "--no-replay-ego", "--no-progress"])
    assert code == 0
    assert "normal: 2, cat: 2" in capsys.readouterr().out
    with ResultsStore(store_path) as store:
        rows = store.episodes()
        assert {(r["pipeline"], r["seed"]) for r in rows} == {("cat", 3)}
        assert sorted({r["setting"] for r in rows}) == ["cat", "normal", f"real:{dataset.resolve()}"]
        assert store.runs()[0]["config"]["algo"] == "td3"
    # the short form `seal eval RUN...`; everything is stored already, so nothing new is written
    assert main(["eval", str(run), "--settings", "normal", "--store", str(store_path), "--k", "1", "--no-replay-ego",
                 "--no-progress"]) == 0
    assert "normal: 0" in capsys.readouterr().out
    code = main(["eval", "runs", "--settings", "normal,goose", "--store", str(store_path), "--dataset",
                 str(dataset), "--no-progress"])
    assert code == 2
    assert "cannot build generator 'goose'" in capsys.readouterr().err
    assert main(["eval", "runs", str(tmp_path / "nope"), "--store", str(store_path)]) == 2


def test_videos_replay_the_scored_pass(dataset: Path, tmp_path: Path) -> None:
    """The report's videos re-simulate the stored episode: same seeds and generator settings, same outcome."""
    from seal.experiments.evaluation.protocol import build_generator, episode_seed_of, scored_pass
    from seal.experiments.report.compare_plots import render_generator_videos

    store_path = tmp_path / "r.sqlite"
    evaluate_runs(["heuristic"], "cat", store_path, dataset=dataset, replay_ego=False,
                  config=resolve_eval_config(candidates="lanes", k=3, seed=7), progress=False)
    with ResultsStore(store_path) as store:
        rows, runs, settings = store.episodes(decode_hists=True), store.runs(), store.settings()
    scenarios = Dataset.open(dataset).load(split="eval")
    env, ego = ScenarioEnv(scenarios), HeuristicEgo()
    generator = build_generator("cat", settings[0]["kwargs"], {})
    for i, sc in enumerate(scenarios):
        normal = run_episode(env, sc, ego, seed=episode_seed_of(7, i))
        rollout, times = scored_pass(env, sc, i, ego, generator, 3, 7, normal)
        (row,) = [r for r in rows if r["scenario_id"] == sc.scenario_id]
        assert (rollout.outcome, len(times)) == (row["outcome"], row["generations"])
        assert rollout.route_completion == pytest.approx(row["route_completion"])
    paths = render_generator_videos(rows, runs, settings, tmp_path / "videos", per_generator=1, fmt="gif",
                                    progress=False)
    assert len(paths) == 1 and paths[0].suffix == ".gif" and paths[0].stat().st_size > 1000


def test_eval_without_subcommand_means_eval_runs() -> None:
    from seal.cli import build_tree

    parser, tree = build_tree()
    assert tree.expand_default(["eval", "runs/cat-s0", "--settings", "normal"]) == [
        "eval", "runs", "runs/cat-s0", "--settings", "normal"]
    for argv in (["eval", "generators", "DS"], ["eval", "runs", "R"], ["eval", "--help"], ["train", "--resume", "R"]):
        assert tree.expand_default(argv) == argv
    args = parser.parse_args(tree.expand_default(["eval", "a", "b", "--settings", "hard"]))
    assert (args.eval_command, args.runs, args.settings) == ("runs", ["a", "b"], "hard")


def test_eval_config_set_and_types() -> None:
    config = resolve_eval_config(k=2, sets=["k=4", "generators.cat.stride=10"])
    assert config["k"] == 4 and config["generators"] == {"cat": {"stride": 10}}
    with pytest.raises(ValueError, match="--set: unknown key.*'kk'"):
        resolve_eval_config(sets=["kk=4"])
    with pytest.raises(ValueError, match="k must be int"):
        resolve_eval_config(sets=["k=many"])
    with pytest.raises(ValueError, match="k must be >= 1"):
        resolve_eval_config(k=0)
