"""Bring your own ego (issue 25): plain SB3 saves, custom policy_kwargs, VecNormalize, seal checkpoints and Python
policies evaluate with one command / call, safely."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf

from seal.cli import main
from seal.core.scenario import CURRENT_STEP
from seal.envs.heuristic import HeuristicDriver
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.evaluate import read_run
from seal.experiments.evaluation.policies import evaluate_policy
from seal.experiments.evaluation.results_store import ResultsStore
from seal.experiments.training.egos import as_ego, make_ego
from seal.experiments.training.sb3_load import ModelLoadError, infer_algo, load_sb3_model


def _sac(tmp_path: Path) -> tuple[object, Path, np.ndarray]:
    from stable_baselines3 import SAC

    env = ScenarioEnv(sf.curve_scenario())
    model = SAC("MlpPolicy", env, seed=0, device="cpu", buffer_size=100, learning_starts=8, batch_size=8)
    model.learn(16)  # a trained model keeps _last_obs and the episode buffers (pickled) in its zip
    model.save(tmp_path / "my_sac")
    obs, _ = env.reset(seed=0)
    return model, tmp_path / "my_sac.zip", obs


def test_plain_sac_save_evaluates_with_one_command(tmp_path: Path, dataset: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    model, path, obs = _sac(tmp_path)
    data = json.loads(zipfile.ZipFile(path).read("data"))
    assert ":serialized:" in data["_last_obs"]  # what the old loader refused
    assert infer_algo(path) == "SAC"
    ego = make_ego(str(path))
    np.testing.assert_allclose(ego.act(obs, CURRENT_STEP), model.predict(obs, deterministic=True)[0], atol=1e-6)
    store = tmp_path / "r.sqlite"
    code = main(["eval", "runs", "--ego", str(path), "--algo", "sac", "--dataset", str(dataset), "--settings",
                 "normal", "--store", str(store), "--no-replay-ego", "--workers", "1", "--no-progress"])
    assert code == 0, capsys.readouterr().err
    with ResultsStore(store) as s:
        rows = s.episodes()
        (run,) = s.runs()
    assert len(rows) == 2 and {r["run"] for r in rows} == {str(path.resolve())}
    assert run["pipeline"] == f"{tmp_path.name}/my_sac"  # a label of its own: never a seed of another model


def test_ppo_with_custom_policy_kwargs_loads_without_pickle(tmp_path: Path) -> None:
    import torch.nn as nn
    from stable_baselines3 import PPO

    env = ScenarioEnv(sf.curve_scenario())
    model = PPO("MlpPolicy", env, seed=1, device="cpu", n_steps=16, batch_size=16,
                policy_kwargs={"net_arch": [64, 64], "activation_fn": nn.ReLU})
    model.learn(16)
    model.save(tmp_path / "ppo.zip")
    loaded = load_sb3_model(tmp_path / "ppo.zip")
    assert type(loaded).__name__ == "PPO" and loaded.policy_kwargs["activation_fn"] is nn.ReLU
    assert [layer.out_features for layer in loaded.policy.mlp_extractor.policy_net if hasattr(layer, "out_features")
            ] == [64, 64]
    obs, _ = env.reset(seed=3)
    np.testing.assert_allclose(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0],
                               atol=1e-6)
    # a class outside the allowed activations / optimisers is refused with what to do
    with zipfile.ZipFile(tmp_path / "ppo.zip") as zf:
        entries = {n: zf.read(n) for n in zf.namelist()}
    data = json.loads(entries["data"])
    data["policy_kwargs"]["features_extractor_class"] = "<class 'evil.Extractor'>"
    entries["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(tmp_path / "evil.zip", "w") as zf:
        for n, b in entries.items():
            zf.writestr(n, b)
    with pytest.raises(ModelLoadError, match=r"policy_kwargs\['features_extractor_class'\].*evaluate the policy from"):
        load_sb3_model(tmp_path / "evil.zip")


def test_vecnormalize_stats_beside_the_model_are_applied(tmp_path: Path) -> None:
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    model, path, obs = _sac(tmp_path)
    venv = VecNormalize(DummyVecEnv([lambda: ScenarioEnv(sf.curve_scenario())]), clip_obs=5.0)
    venv.reset()
    for _ in range(20):
        venv.step(np.array([venv.action_space.sample()]))
    venv.save(str(tmp_path / "vecnormalize.pkl"))
    ego = make_ego(str(path))
    normalised = venv.normalize_obs(obs)
    assert not np.allclose(normalised, obs)
    expected = model.predict(normalised.astype(np.float32), deterministic=True)[0]
    np.testing.assert_allclose(ego.act(obs, CURRENT_STEP), expected, atol=1e-5)


def test_seal_checkpoint_is_its_own_ego(tmp_path: Path) -> None:
    from stable_baselines3 import TD3

    run = tmp_path / "cat-s3"
    ckpt = run / "checkpoints" / "step_2000"
    ckpt.mkdir(parents=True)
    (run / "config.yaml").write_text("algo: td3\npipeline: cat\nseed: 3\n")
    env = ScenarioEnv(sf.curve_scenario())
    model = TD3("MlpPolicy", env, seed=0, device="cpu", buffer_size=100, learning_starts=4, batch_size=4)
    model.learn(8)
    model.save(ckpt / "model.zip")  # no exclude list: _last_obs and action noise are in it
    spec = read_run(ckpt / "model.zip")
    assert (spec.pipeline, spec.seed, spec.algo) == ("cat@step_2000", 3, "td3")
    obs, _ = env.reset(seed=0)
    np.testing.assert_allclose(make_ego(spec.ego).act(obs, CURRENT_STEP), model.predict(obs, deterministic=True)[0],
                               atol=1e-6)


def test_python_policies_evaluate_from_python(tmp_path: Path, dataset: Path) -> None:
    store = tmp_path / "r.sqlite"
    calls: list[tuple[int, ...]] = []

    def brake(obs: np.ndarray) -> np.ndarray:
        calls.append(obs.shape)
        return np.array([0.0, -1.0])

    result = evaluate_policy(brake, "brake-policy", dataset, settings="normal,hard", store=store, progress=False)
    assert result == [{"run": "brake-policy", "written": {"normal": 2, "hard": 1}}]
    assert calls and set(calls) == {(100,)}
    # an object with SB3's predict drives exactly as the built-in heuristic ego
    evaluate_policy(HeuristicDriver(), "my-heuristic", dataset, settings="normal", store=store, progress=False)
    from seal.experiments.evaluation.parallel import evaluate_runs

    evaluate_runs(["heuristic"], "normal", store, dataset=dataset, replay_ego=False, progress=False)
    with ResultsStore(store) as s:
        mine = {r["scenario_id"]: r["route_completion"] for r in s.episodes(run="my-heuristic")}
        builtin = {r["scenario_id"]: r["route_completion"] for r in s.episodes(run="heuristic")}
        stopped = s.episodes(run="brake-policy")
    assert mine == pytest.approx(builtin) and len(mine) == 2
    assert all(r["outcome"] != "success" for r in stopped)  # full braking from the start never arrives
    with pytest.raises(ValueError, match="is not a policy"):
        as_ego(42, "x")
