"""Generator evaluation: the X-Gen protocol, the summary numbers, the output files, the CLI, and the egos."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf
import yaml

from seal.adversaries.base import make_generator
from seal.cli import main
from seal.core.dataset import write_dataset
from seal.core.scenario import CURRENT_STEP, X, Y
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.episodes import run_episode
from seal.experiments.evaluation.generator_metrics import EpisodeRecord, LoggedAdversary, markdown_table, summarize
from seal.experiments.evaluation.generators import evaluate_generators, parse_generators, resolve_config
from seal.experiments.training.egos import ReplayEgo, load_sb3_model, make_ego


@pytest.fixture(scope="module")
def scenarios() -> list:
    return [sf.highway_scenario(1), sf.highway_scenario(2)]


def test_parse_generators_checks_names() -> None:
    assert parse_generators("replay, rule") == {"replay": {}, "rule": {}}
    assert parse_generators({"cat": {"candidates": "lanes"}}) == {"cat": {"candidates": "lanes"}}
    with pytest.raises(ValueError, match=r"unknown generator\(s\) bogus; available: .*cat.*replay.*rule"):
        parse_generators(["replay", "bogus"])


def test_resolve_config_layers(tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("generators: {cat: {follow: track}}\nego: heuristic\nk: 3\n")
    config = resolve_config(cfg, k=4, ego=None, candidates="lanes")
    assert config["generators"] == {"cat": {"follow": "track"}} and config["ego"] == "heuristic"
    assert config["k"] == 4 and config["candidates"] == "lanes" and config["split"] == "eval"
    config = resolve_config(cfg, gen_opts=["cat.stride=10", "cat.follow=replay"])
    assert config["generators"] == {"cat": {"follow": "replay", "stride": 10}}
    with pytest.raises(ValueError, match="not among"):
        resolve_config(cfg, gen_opts=["rule.max_accel_mps2=2"])
    with pytest.raises(ValueError, match="NAME.KEY=VALUE"):
        resolve_config(cfg, gen_opts=["cat=3"])
    cfg.write_text("gens: [replay]\n")
    with pytest.raises(ValueError, match="unknown key.*gens"):
        resolve_config(cfg)


def test_generators_option_picks_labelled_entries_of_the_config_file(tmp_path: Path) -> None:
    cfg = tmp_path / "ablations.yaml"
    cfg.write_text("generators: {cat: {follow: track}, seal_traj: {generator: seal, switch: none}, rule: {}}\n")
    picked = resolve_config(cfg, generators="seal_traj, replay")
    assert picked["generators"] == {"seal_traj": {"generator": "seal", "switch": "none"}, "replay": {}}
    assert resolve_config(cfg, generators=["cat"])["generators"] == {"cat": {"follow": "track"}}
    assert list(resolve_config(cfg)["generators"]) == ["cat", "seal_traj", "rule"]  # no --generators: all entries
    with pytest.raises(ValueError, match="unknown generator.*seal_trajectory"):
        resolve_config(cfg, generators="seal_trajectory")


def test_shipped_preset_resolves() -> None:
    preset = Path(__file__).resolve().parents[2] / "experiments" / "configs" / "eval_generators.yaml"
    config = resolve_config(preset, candidates="lanes")
    assert list(config["generators"]) == ["replay", "rule", "cat"] and config["k"] == 5


def test_protocol_replay_vs_rule(scenarios: list) -> None:
    generators = {"replay": make_generator("replay"), "rule": make_generator("rule")}
    rows, records = evaluate_generators(scenarios, generators, "replay", k=2, progress=False)
    by = {row["generator"]: row for row in rows}
    assert [r.generator for r in records] == ["replay", "replay", "rule", "rule"]
    for row in rows:
        assert row["scenarios"] == 2 and row["generations"] == 4  # K passes per scenario
        assert sum(row[f"{k}_rate"] for k in ("success", "crash", "out_of_road", "timeout")) == pytest.approx(1)
    # The replayed log: no contact, the original adversary's own motion (realism distances ~0).
    assert by["replay"]["adv_collision_rate"] == 0.0 and by["replay"]["success_rate"] == 1.0
    assert by["replay"]["realism"] < 0.02
    # The rule adversary aims at the logged ego, which the replayed ego follows: both scenarios end in contact.
    assert by["rule"]["adv_collision_rate"] == 1.0 and by["rule"]["crash_rate"] == 1.0
    assert by["rule"]["collision_speed_mps"] > 0
    rule = [r for r in records if r.generator == "rule"]
    assert all(r.first_crash_step <= r.predicted_step for r in rule)


def _record(scenario, outcome: str, adv_hit: bool, times: list[float]) -> EpisodeRecord:
    tracks = scenario.tracks.copy()
    crashes = [(40, scenario.adv_id)] if adv_hit else []
    rollout = Rollout(scenario.scenario_id, tracks, scenario.agent_ids, scenario.ego_id, scenario.adv_id,
                      last_step=90, outcome=outcome, ego_crashes=crashes)
    return EpisodeRecord.from_rollout(scenario, "g", rollout, times)


def test_summary_numbers(scenarios: list) -> None:
    records = [_record(scenarios[0], "crash", True, [0.001, 0.003]), _record(scenarios[1], "success", False,
                                                                           [0.002, 0.010])]
    logged = [LoggedAdversary.of(s) for s in scenarios]
    row = summarize(records, logged)
    assert row["crash_rate"] == 0.5 and row["success_rate"] == 0.5 and row["adv_collision_rate"] == 0.5
    assert row["generation_ms_mean"] == pytest.approx(4.0)
    assert row["generation_ms_p95"] == pytest.approx(np.percentile([1, 3, 2, 10], 95))
    # Executed adversary = logged adversary: every realism distance is 0.
    assert row["yaw_wd"] == pytest.approx(0.0) and row["acc_wd"] == pytest.approx(0.0) and row["road_wd"] == 0.0
    table = markdown_table([row])
    assert "| g | 2 | 50.0% | 50.0% | 0.0% | 50.0% |" in table


def test_cli_eval_and_bench(tmp_path: Path, scenarios: list, capsys: pytest.CaptureFixture) -> None:
    data = tmp_path / "data"
    write_dataset(data, scenarios)
    out = tmp_path / "out"
    code = main(["eval", "generators", str(data), "--generators", "replay,rule,cat", "--candidates", "lanes",
                 "--gen-opt", "rule.max_accel_mps2=3.5", "--all-scenarios", "--k", "2", "--ego", "replay",
                 "--out", str(out), "--no-progress"])
    assert code == 0
    rows = list(csv.DictReader((out / "generators.csv").open()))
    assert [r["generator"] for r in rows] == ["replay", "rule", "cat"]
    episodes = list(csv.DictReader((out / "episodes.csv").open()))
    assert len(episodes) == 6 and {"extra_collision_predicted", "extra_target_step"} <= set(episodes[0])
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["generators"] == {"replay": {}, "rule": {"max_accel_mps2": 3.5}, "cat": {}}
    assert config["candidates"] == "lanes"
    assert config["k"] == 2 and config["scenarios"] == 2 and config["split"] is None
    assert json.loads((out / "generators.json").read_text())["rows"][2]["generator"] == "cat"
    assert "| cat |" in (out / "generators.md").read_text()
    capsys.readouterr()
    assert main(["bench", "generators", str(data), "--all-scenarios", "--generators", "replay,cat",
                 "--candidates", "lanes", "--json"]) == 0
    bench = json.loads(capsys.readouterr().out)
    assert bench["scenarios"] == 2 and bench["cat"]["ms_mean"] > 0 and "candidate_ms_mean" in bench["cat"]
    # x_replay is each generator's mean time over the replayed adversary's, measured in the same run (1 decimal).
    ratio = bench["cat"]["ms_mean"] / bench["replay"]["ms_mean"]
    assert bench["cat"]["x_replay"] == pytest.approx(ratio, abs=0.051) and bench["replay"]["x_replay"] == 1.0


def test_cli_names_unknown_generators_and_missing_splits(tmp_path: Path, scenarios: list,
                                                         capsys: pytest.CaptureFixture) -> None:
    data = tmp_path / "data"
    write_dataset(data, scenarios[:1])
    capsys.readouterr()
    assert main(["eval", "generators", str(data), "--generators", "replay,nope", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "unknown generator(s) nope" in err
    assert all(name in err.split("available:")[1] for name in ("cat", "replay", "rule"))
    assert main(["eval", "generators", str(data), "--generators", "replay", "--out", str(tmp_path / "o")]) == 2
    assert "no split 'eval'" in capsys.readouterr().err


def test_replay_ego_follows_the_log() -> None:
    scenario = sf.lane_change_scenario()
    rollout = run_episode(ScenarioEnv(scenario), scenario, ReplayEgo())
    ego, log = rollout.ego_track, scenario.track(scenario.ego_id)
    n = rollout.last_step + 1
    gap = np.hypot(*(ego[CURRENT_STEP:n, [X, Y]] - log[CURRENT_STEP:n, [X, Y]]).T)
    assert rollout.outcome == "success" and gap.max() < 0.3


@pytest.mark.parametrize("algo", ["ppo", "td3"])
def test_run_ego_loads_sb3_models_without_pickle(tmp_path: Path, algo: str) -> None:
    import stable_baselines3 as sb3

    env = ScenarioEnv(sf.curve_scenario())
    kwargs = {"n_steps": 16, "batch_size": 16} if algo == "ppo" else {"buffer_size": 100}
    model = getattr(sb3, algo.upper())("MlpPolicy", env, seed=0, device="cpu", **kwargs)
    model.save(tmp_path / "model.zip")  # a plain save: the algorithm is read from the file itself
    loaded = load_sb3_model(tmp_path)
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    ego = make_ego(str(tmp_path / "model.zip"))
    assert ego.act(obs, CURRENT_STEP).shape == (2,)
    with pytest.raises(ValueError, match="not 'heuristic', 'replay'"):
        make_ego(str(tmp_path / "missing"))


def test_cli_offset_plays_a_slice_with_the_episodes_of_the_whole_run(tmp_path: Path,
                                                                       capsys: pytest.CaptureFixture) -> None:
    """``--offset`` keeps each scenario's split index, so a held-out slice replays exactly its rows of a run over
    the whole split (episode seeds and generator streams follow the index); past the end is a one-line error."""
    data = tmp_path / "data"
    write_dataset(data, [sf.highway_scenario(1), sf.highway_scenario(2), sf.highway_scenario(3)])
    common = ["eval", "generators", str(data), "--generators", "rule", "--all-scenarios", "--k", "2", "--ego",
              "heuristic", "--no-progress"]
    assert main([*common, "--out", str(tmp_path / "all")]) == 0
    assert main([*common, "--offset", "1", "--limit", "1", "--out", str(tmp_path / "slice")]) == 0
    whole = list(csv.DictReader((tmp_path / "all" / "episodes.csv").open()))
    part = list(csv.DictReader((tmp_path / "slice" / "episodes.csv").open()))
    assert len(whole) == 3 and len(part) == 1
    timing = "generation_ms_mean"  # wall time, the only column that may differ
    assert {k: v for k, v in part[0].items() if k != timing} == {k: v for k, v in whole[1].items() if k != timing}
    assert yaml.safe_load((tmp_path / "slice" / "config.yaml").read_text())["offset"] == 1
    capsys.readouterr()
    assert main([*common, "--offset", "3", "--out", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "--offset 3" in err and "no scenario after the first 3" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as exc:  # argparse's own usage error
        main([*common, "--offset", "-1", "--out", str(tmp_path / "neg")])
    assert exc.value.code == 2 and "--offset must be >= 0" in capsys.readouterr().err
