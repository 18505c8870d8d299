"""The GOOSE agent file, the `goose` generator's per-scenario curve updates, and `seal fit goose` end to end."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from seal.adversaries.base import make_generator
from seal.adversaries.goose.agent import GooseAgent, GooseExtractor, build_policy, load_goose_agent, save_goose_agent
from seal.adversaries.goose.env import simulate
from seal.adversaries.goose.generator import GooseGenerator, driven_by
from seal.adversaries.goose.obs import observation_space
from seal.adversaries.goose.spec import GooseSpec
from seal.core.scenario import Scenario
from seal.envs.behaviors import ReplayBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv

NET = [16, 16]
GRU = 8


def _agent(spec: GooseSpec | None = None, seed: int = 0) -> GooseAgent:
    torch.manual_seed(seed)
    spec = spec or GooseSpec()
    return GooseAgent(build_policy("sac", spec, NET, GRU), spec, "sac")


def _obs(spec: GooseSpec, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {k: rng.normal(size=v.shape).astype(np.float32) for k, v in observation_space(spec).spaces.items()}


def test_extractor_runs_the_gru_over_the_rollout_block() -> None:
    spec = GooseSpec()
    space = observation_space(spec)
    ext = GooseExtractor(space, n_time=spec.n_time, n_features=10, gru_hidden=GRU)
    n_seq = spec.n_time * 10
    assert ext.features_dim == GRU + space["observation"].shape[0] - n_seq + 6
    obs = {k: torch.as_tensor(v)[None] for k, v in _obs(spec, 0).items()}
    base = ext(obs)
    assert base.shape == (1, ext.features_dim)
    changed = {k: v.clone() for k, v in obs.items()}
    changed["observation"][0, 3] += 1.0  # one roll-out value: only the GRU state moves
    out = ext(changed)
    assert not torch.allclose(out[0, :GRU], base[0, :GRU])
    torch.testing.assert_close(out[0, GRU:], base[0, GRU:])
    changed = {k: v.clone() for k, v in obs.items()}
    changed["desired_goal"][0, 0] = 1.0
    torch.testing.assert_close(ext(changed)[0, -3], torch.tensor(0.1))  # 1 m / 10 m scale


def test_agent_file_round_trip_and_errors(tmp_path: Path) -> None:
    spec = GooseSpec(shift_m=3.0)
    agent = _agent(spec)
    path = tmp_path / "agent.zip"
    save_goose_agent(path, agent.policy, "sac", spec, NET, GRU, summary={"env_steps": 12})
    loaded = load_goose_agent(path)
    assert loaded.spec == spec and loaded.algo == "sac" and loaded.meta["summary"]["env_steps"] == 12
    for seed in range(3):
        obs = _obs(spec, seed)
        np.testing.assert_allclose(loaded.act(obs), agent.act(obs), atol=1e-6)
    assert np.all(np.abs(loaded.act(_obs(spec, 5))) <= 1.0)

    with pytest.raises(FileNotFoundError, match="seal fit goose"):
        load_goose_agent(tmp_path / "missing.zip")
    (tmp_path / "junk.zip").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="junk.zip"):
        load_goose_agent(tmp_path / "junk.zip")
    with zipfile.ZipFile(tmp_path / "other.zip", "w") as zf:
        zf.writestr("goose.json", '{"format": "something-else"}')
        zf.writestr("policy.pt", b"")
    with pytest.raises(ValueError, match="'format'"):
        load_goose_agent(tmp_path / "other.zip")
    with zipfile.ZipFile(path) as zf:
        meta, weights = zf.read("goose.json"), zf.read("policy.pt")
    with zipfile.ZipFile(tmp_path / "bigger.zip", "w") as zf:
        zf.writestr("goose.json", meta.replace(b'"gru_hidden": 8', b'"gru_hidden": 9'))
        zf.writestr("policy.pt", weights)
    with pytest.raises(ValueError, match="does not match"):
        load_goose_agent(tmp_path / "bigger.zip")


def _roll(scenario: Scenario, behavior: ReplayBehavior) -> Rollout:
    return simulate(ScenarioEnv([scenario]), HeuristicDriver(), scenario.scenario_id, behavior)


def test_generator_updates_once_per_observed_rollout_up_to_k(lane_change: Scenario, tmp_path: Path) -> None:
    spec = GooseSpec(max_updates=2)
    path = tmp_path / "agent.zip"
    agent = _agent(spec, seed=1)
    save_goose_agent(path, agent.policy, "sac", spec, NET, GRU)
    gen = make_generator("goose", model=str(path))
    assert isinstance(gen, GooseGenerator)
    rng = np.random.default_rng(0)
    history = [_roll(lane_change, ReplayBehavior())]

    g1 = gen.generate(lane_change, history, rng)
    assert g1.extra["reason"] == "update" and g1.extra["updates"] == 1
    track1 = g1.behavior._given
    assert track1 is not None and not driven_by(history[-1], track1)  # the curve moved away from the log
    history.append(_roll(lane_change, g1.behavior))
    assert driven_by(history[-1], track1)

    # The adversary starts ~58 m ahead of the ego: a small untrained edit does not reach the goal, so the
    # second observed roll-out gives the second (last, K = 2) update and the third keeps the curve.
    g2 = gen.generate(lane_change, history, rng)
    assert g2.extra["reason"] == "update" and g2.extra["updates"] == 2
    assert not np.array_equal(g2.behavior._given, track1)
    history.append(_roll(lane_change, g2.behavior))
    g3 = gen.generate(lane_change, history, rng)
    assert g3.extra["reason"] == "max_updates" and g3.extra["updates"] == 2
    np.testing.assert_array_equal(g3.behavior._given, g2.behavior._given)  # the curve is kept

    # A roll-out not driven by the kept curve (here: the log again) starts the scenario over.
    g4 = gen.generate(lane_change, history[:1], rng)
    assert g4.extra["updates"] == 1 and g4.extra["reason"] == "update"
    np.testing.assert_allclose(g4.behavior._given, track1)  # deterministic agent: same first update


def test_generator_keeps_a_curve_that_reached_the_goal(lane_change: Scenario) -> None:
    gen = GooseGenerator(_agent(GooseSpec(desired_goal=(50.0, 100.0, 100.0))))
    g = gen.generate(lane_change, [_roll(lane_change, ReplayBehavior())], np.random.default_rng(0))
    assert g.extra["reason"] == "goal_met" and g.extra["updates"] == 0
    empty = gen.generate(lane_change, [], np.random.default_rng(0))
    assert empty.extra["reason"] == "no_history"
    with pytest.raises(ValueError, match="model=PATH"):
        make_generator("goose")
    other = _roll(lane_change, ReplayBehavior())
    other.scenario_id = "elsewhere"
    with pytest.raises(ValueError, match="elsewhere"):
        gen.generate(lane_change, [other], np.random.default_rng(0))


def test_fit_goose_command_trains_saves_and_evaluates(
    lane_change: Scenario, highway: list[Scenario], tmp_path: Path
) -> None:
    from seal.cli import main
    from seal.core.dataset import write_dataset

    ds = write_dataset(tmp_path / "ds", [lane_change, *highway])
    ds.update_manifest(splits={"train": [s.scenario_id for s in [lane_change, *highway[:2]]],
                               "eval": [highway[2].scenario_id]})
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump({"learning_starts": 10, "batch_size": 8, "net_arch": NET, "gru_hidden": GRU,
                                      "log_every": 10, "spec": {"max_updates": 2}}))
    out = tmp_path / "goose.zip"
    code = main(["fit", "goose", str(tmp_path / "ds"), "--out", str(out), "--preset", "quick", "--config", str(config),
                 "--steps", "20", "--no-progress", "--seed", "3"])
    assert code == 0
    agent = load_goose_agent(out)
    assert agent.spec.max_updates == 2 and agent.meta["summary"]["env_steps"] == 20
    run = tmp_path / "goose_run"
    resolved = yaml.safe_load((run / "config.yaml").read_text())
    assert resolved["total_steps"] == 20 and resolved["seed"] == 3 and resolved["eval_limit"] == 40
    rows = (run / "success.csv").read_text().splitlines()
    assert rows[0].startswith("steps,episodes,success_rate") and [r.split(",")[0] for r in rows[1:]] == ["10", "20"]
    assert (run / "progress.csv").exists()
    ev = json.loads((run / "eval.json").read_text())
    assert set(ev) == {"zero", "random", "untrained", "trained"}
    assert all(ev[name]["scenarios"] == 1 for name in ev)
    with pytest.raises(SystemExit):
        main(["fit", "goose", str(tmp_path / "ds"), "--out", str(out), "--algo", "ppo"])
    assert main(["fit", "goose", str(tmp_path / "ds"), "--out", str(out), "--split", "nope", "--no-progress"]) == 2


def test_config_resolution_names_bad_keys(tmp_path: Path) -> None:
    import dataclasses

    from seal.experiments.fitting.goose import GooseFitConfig, resolve_config

    quick = resolve_config("quick")
    assert quick.total_steps < resolve_config("standard").total_steps
    assert resolve_config("standard", total_steps=77).total_steps == 77
    assert resolve_config("standard", sets=["total_steps=78"], total_steps=77).total_steps == 78  # --set last
    assert {f.name for f in dataclasses.fields(quick)} == {f.name for f in dataclasses.fields(GooseFitConfig)}
    bad = tmp_path / "bad.yaml"
    bad.write_text("total_step: 3\n")
    with pytest.raises(ValueError, match=r"bad\.yaml.*total_step"):
        resolve_config("quick", bad)
    bad.write_text("spec: {shift: 1}\n")
    with pytest.raises(ValueError, match="spec"):
        resolve_config("quick", bad)
    with pytest.raises(ValueError, match="algo"):
        resolve_config("quick", algo="ppo")
