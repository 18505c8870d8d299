"""`seal eval background` / `seal bench background` / `normal-reactive` (issue 22) on hand-built scenarios."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf
import torch

from seal.cli import main
from seal.core.scenario import CURRENT_STEP, DT_S, VX, VY
from seal.envs.background import ConstantVelocityBackground, IDMBackground, SimulatedBackground, roll_background
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.bench.background import tiled_scenario
from seal.experiments.evaluation.background import FAR_M, alone, intent_metrics, open_loop_metrics, r2, rollout_errors
from seal.experiments.evaluation.evaluate import parse_settings, resolve_eval_config
from seal.experiments.evaluation.parallel import evaluate_runs
from seal.experiments.evaluation.results_store import ResultsStore
from seal.models.rapid import RapidBackground
from seal.models.rapid.network import RapidNet
from seal.models.rapid.train import RapidTrainConfig, save_rapid


def follower_scenario():
    road = sf.straight_road(2)
    ego = sf.simulate_track(road.lanes[0].centerline, 80.0, 20.0)
    adv = sf.simulate_track(road.lanes[1].centerline, 80.0, 20.0)
    follower = sf.simulate_track(road.lanes[0].centerline, 50.0, 20.0)
    return sf.make_scenario(road, [ego, adv, follower], "follower")


def test_r2_matches_its_definition() -> None:
    t = np.array([1.0, 2.0, 3.0, 4.0])
    assert r2(t, t) == 1.0
    assert r2(t, np.full(4, t.mean())) == 0.0
    assert r2(t, t + 1.0) == pytest.approx(1 - 4 / 5)
    assert math.isnan(r2(np.ones(3), np.ones(3)))


def test_rear_end_rule_counts_the_background_car_from_behind_only() -> None:
    sc = follower_scenario()
    outcomes = {}
    for kind in ("replay", "idm"):
        env = ScenarioEnv([sc], config={"background": kind})
        env.reset(seed=0)
        done = False
        while not done:
            *_, term, trunc, info = env.step(np.array([0.0, -0.5]))
            done = term or trunc
        outcomes[kind] = info["rollout"]
    assert outcomes["replay"].crashed and outcomes["replay"].rear_end_by_background()
    assert not outcomes["idm"].crashed and not outcomes["idm"].rear_end_by_background()
    # the same contact with the ego behind the other car is not a rear-end hit *by* background traffic
    swapped = outcomes["replay"]
    swapped.tracks[2, :, 0] += 200.0  # move the follower far ahead of the ego: its contact is no longer behind
    assert not swapped.rear_end_by_background()


def test_open_loop_metrics_constant_velocity_on_straight_lanes_is_exact() -> None:
    sc = sf.highway_scenario(0)
    out = open_loop_metrics([sc], {"constant_velocity": ConstantVelocityBackground(), "idm": IDMBackground()}, 0)
    assert set(out) == {"constant_velocity", "idm", "log"}
    assert out["log"]["collision_rate"] == 0.0
    assert out["constant_velocity"]["agents"] == out["idm"]["agents"] > 0
    tracks = roll_background(sc, ConstantVelocityBackground(), np.random.default_rng(0))
    ade, fde, hit = rollout_errors(sc, tracks)
    assert out["constant_velocity"]["ade_8s_m"] == pytest.approx(np.mean(ade))
    assert all(f >= 0 for f in fde) and len(hit) == len(ade)


class _Obedient(SimulatedBackground):
    """Reaches its desired speed in one step along its velocity, ignoring everything else."""

    def accelerations(self, t: int, cur: np.ndarray, rows: np.ndarray) -> np.ndarray:
        v = cur[rows][:, [VX, VY]]
        speed = np.hypot(v[:, 0], v[:, 1])
        want = np.nan_to_num(self.intent.desired_speed_mps[rows], nan=speed)
        return v / speed[:, None] * ((want - speed) / DT_S)[:, None]


def test_intent_metrics_give_r2_one_to_an_obedient_controller() -> None:
    out = intent_metrics([sf.highway_scenario(1)], _Obedient(), 0)
    assert out["agents"] > 3
    assert out["speed_r2"] == pytest.approx(1.0) and out["speed_mae_mps"] == pytest.approx(0.0, abs=1e-9)
    assert out["speed_r2_if_ignored"] < 0.9
    assert out["heading_r2_24"] == pytest.approx(out["heading_r2_if_ignored_24"])  # it ignores destinations
    assert out["speed_r2_free_road"] == pytest.approx(1.0)


def test_alone_keeps_one_background_agent_on_an_empty_road() -> None:
    sc = sf.highway_scenario(1)
    row = next(i for i in range(sc.n_agents) if i not in (sc.ego_index, sc.adv_index))
    solo = alone(sc, row)
    assert solo.n_agents == 3 and (solo.ego_index, solo.adv_index) == (0, 1)
    np.testing.assert_array_equal(solo.tracks[2], sc.tracks[row])
    assert solo.agent_ids[2] == sc.agent_ids[row] and solo.road is sc.road
    np.testing.assert_allclose(solo.tracks[0, :, 0], sc.tracks[sc.ego_index, :, 0] + FAR_M)


def test_free_road_speed_r2_separates_yielding_from_not_following() -> None:
    # a follower 30 m behind the (replayed, 20 m/s) ego: commanded above 20 m/s, IDM yields to the ego; alone on
    # the road it reaches every command
    scenes = [follower_scenario() for _ in range(8)]
    out = intent_metrics(scenes, IDMBackground(), 0, heading=False)
    assert out["agents"] == 8 and "heading_r2_24" not in out
    assert out["speed_r2_free_road"] > 0.97
    assert out["speed_r2"] < out["speed_r2_free_road"] - 0.2


def test_idm_background_takes_a_commanded_speed_but_no_destination() -> None:
    sc = follower_scenario()
    ctrl = IDMBackground()
    ctrl.reset(sc, np.random.default_rng(0), np.array([False, False, True]))
    ctrl.set_intent(2, desired_speed_mps=7.0)
    assert ctrl.intent.desired_at(CURRENT_STEP, np.array([2]))[0] == 7.0
    with pytest.raises(ValueError, match="destination"):
        ctrl.set_intent(2, destination_xy=(0.0, 0.0))


def test_tiled_scenario_has_exactly_n_background_agents() -> None:
    base = sf.highway_scenario(2)
    for n in (5, 30):
        scene = tiled_scenario(base, n)
        assert scene.n_agents == n + 2 and scene.ego_index == 0 and scene.adv_index == 1
        assert len(set(scene.agent_ids.tolist())) == n + 2


@pytest.fixture(scope="module")
def model_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("rapid") / "model.pt"
    save_rapid(path, RapidNet(16).eval(), RapidTrainConfig(dim=16), {})
    return path


def test_normal_reactive_setting_plays_with_reactive_background(dataset: Path, tmp_path: Path, model_file: Path
                                                                 ) -> None:
    (setting,) = parse_settings("normal-reactive", dataset)
    assert setting.split == "eval" and setting.reactive and setting.kind == "replay"
    with pytest.raises(Exception, match="background_model"):
        resolve_eval_config(sets=["background=rapid"])
    store_path = tmp_path / "r.sqlite"
    config = resolve_eval_config(sets=["background=rapid", f"background_model={model_file}"])
    results = evaluate_runs(["heuristic"], "normal,normal-reactive", store_path, dataset=dataset, config=config,
                            progress=False, replay_ego=False)
    assert results[0]["written"] == {"normal": 2, "normal-reactive": 2}
    with ResultsStore(store_path) as store:
        (s,) = [s for s in store.settings() if s["setting"] == "normal-reactive"]
        assert s["kwargs"]["background"] == "rapid"


def test_eval_and_bench_background_cli(dataset: Path, tmp_path: Path, model_file: Path, capsys) -> None:
    import json

    out = tmp_path / "ev"
    assert main(["eval", "background", str(dataset), "--model", str(model_file), "--parts", "open,closed",
                 "--out", str(out), "--no-progress", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert set(report["open_loop"]) == {"constant_velocity", "idm", "idm_unscheduled", "rapid", "rapid_unguided", "log"}
    assert set(report["closed_loop"]["heuristic"]) == {"replay", "idm", "rapid"}
    assert (out / "background_eval.json").is_file() and (out / "background_eval.png").is_file()
    assert main(["eval", "background", str(dataset), "--parts", "open,bogus"]) == 2
    assert "unknown part" in capsys.readouterr().err
    assert main(["bench", "background", "--dataset", str(dataset), "--model", str(model_file), "--counts", "5,20",
                 "--steps", "3", "--json"]) == 0
    bench = json.loads(capsys.readouterr().out)
    assert set(bench["per_step"]["rapid"]) == {"5", "20"} and bench["per_step"]["rapid"]["20"]["agents"] == 20
    idm = bench["per_step"]["idm"]
    assert bench["idm_ratio_20_over_5"] == pytest.approx(idm["20"]["median_ms"] / idm["5"]["median_ms"])


def test_rapid_background_in_the_env_moves_agents_off_their_log(model_file: Path) -> None:
    from seal.models.rapid import load_rapid

    sc = sf.highway_scenario(0)
    rapid = load_rapid(model_file)
    assert isinstance(rapid, RapidBackground)
    env = ScenarioEnv([sc], config={"background": "rapid"}, background_model=rapid)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros(2))
    row = [i for i in range(sc.n_agents) if i not in (sc.ego_index, sc.adv_index) and sc.valid[i, CURRENT_STEP + 5]][0]
    assert not np.array_equal(env._cur[row], sc.tracks[row, CURRENT_STEP + 5].astype(np.float64))


def test_table_6_2_keeps_normal_reactive_beside_normal() -> None:
    from results_builders import episode

    from seal.experiments.report.compare import generator_table

    rows = [episode(setting=s, scenario_id=f"s{i}", outcome="crash" if (s == "normal" and i < 2) else "success")
            for s in ("normal", "normal-reactive", "hard") for i in range(4)]
    for r in rows:
        r.update({k: list(r[k]) for k in ("adv_yaw_hist", "adv_acc_hist", "log_yaw_hist", "log_acc_hist")})
    settings = [{"setting": s, "kind": "replay"} for s in ("normal", "normal-reactive", "hard")]
    table = {r["setting"]: r for r in generator_table(rows, settings)}
    assert set(table) == {"normal", "normal-reactive"}
    assert table["normal"]["ego_success"] == pytest.approx(0.5)
    assert table["normal-reactive"]["ego_success"] == pytest.approx(1.0)


def test_background_presets_resolve() -> None:
    from seal.core.config import ConfigError
    from seal.experiments.fitting.background import resolve_config

    quick = resolve_config("quick")
    assert (quick.limit, quick.eval_limit, quick.stride, quick.dim, quick.epochs) == (24, 6, 3, 32, 2)
    standard = resolve_config("standard", sets=["epochs=2"], seed=5)
    assert (standard.limit, standard.dim, standard.epochs, standard.seed) == (200, 64, 2, 5)
    with pytest.raises(ConfigError, match="drop_intent"):
        resolve_config("quick", sets=["drop_intent=1.5"])


def test_generator_reactive_setting_plays_the_passes_with_reactive_background(dataset: Path, tmp_path: Path) -> None:
    from seal.adversaries.base import make_generator
    from seal.core.dataset import load_split
    from seal.experiments.evaluation import protocol
    from seal.experiments.evaluation.replay_episode import EpisodeSpec, play
    from seal.experiments.training.egos import make_ego

    (setting,) = parse_settings("rule-reactive", dataset)
    assert (setting.generator, setting.reactive, setting.split, setting.kind) == ("rule", True, "eval", "generator")
    with pytest.raises(ValueError, match="GENERATOR-reactive"):
        parse_settings("nope-reactive", dataset)
    store_path = tmp_path / "g.sqlite"
    config = resolve_eval_config(k=2)
    results = evaluate_runs(["heuristic"], "rule,rule-reactive", store_path, dataset=dataset, config=config,
                            progress=False, replay_ego=False, workers=1)
    assert results[0]["written"] == {"rule": 2, "rule-reactive": 2}
    with ResultsStore(store_path) as store:
        info = {s["setting"]: s for s in store.settings()}
        assert info["rule-reactive"]["kwargs"]["background"] == "idm" and "background" not in info["rule"]["kwargs"]
        rows = {(r["setting"], r["scenario_id"]): r for r in store.episodes()}
    # Each row is the scored pass of the K passes played in its own env (queue started by that env's normal episode).
    scenarios = load_split(dataset, "eval")
    ego = make_ego("heuristic")
    for reactive in (False, True):
        env = ScenarioEnv(scenarios, config={"background": "idm"} if reactive else {})
        for i, scenario in enumerate(scenarios):
            normal = protocol.normal_episode(env, scenario, i, ego, 0)
            rollout, _ = protocol.scored_pass(env, scenario, i, ego, make_generator("rule"), 2, 0, normal)
            row = rows[("rule-reactive" if reactive else "rule", scenario.scenario_id)]
            # Exact: the two backgrounds differ here only in the 7th digit of the return.
            assert row["episode_return"] == rollout.episode_return and row["outcome"] == rollout.outcome
            # The report's videos replay the same episode from the setting's record in the store.
            spec = EpisodeSpec.of_setting(info["rule-reactive" if reactive else "rule"], scenario.scenario_id,
                                          "heuristic")
            assert spec.background == ("idm" if reactive else None) and "background" not in spec.kwargs
            assert play(spec)[1].episode_return == rollout.episode_return
    assert all(rows[("rule", s.scenario_id)]["episode_return"] != rows[("rule-reactive", s.scenario_id)][
        "episode_return"] for s in scenarios)
    from seal.experiments.report.write import write_report

    report = write_report(store_path, tmp_path / "rep", plots=False, videos=1, progress=False, n_boot=50,
                          n_boot_poi=50)  # the videos rebuild each generator from its record (no background kwarg)
    assert {Path(v).name.split("_")[0] for v in report["videos"]} == {"rule", "rule-reactive"}
