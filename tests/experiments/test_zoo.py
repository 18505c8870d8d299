"""rl-zoo habits (issue 25): zoo hyperparameter files, policy_kwargs as text or mapping, lin_ schedules,
n_timesteps; settings for another algorithm refused."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import scenario_factory as sf
from train_fixtures import tiny_dataset

from seal.cli import main
from seal.core.config import ConfigError
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.training.config import load_train_config
from seal.experiments.training.train import build_model
from seal.experiments.training.zoo import parse_policy_kwargs, parse_schedule, zoo_overrides

CONFIGS = Path(__file__).resolve().parents[2] / "experiments" / "configs"

ZOO_SAC = """
seal/Scenario-v0:
  n_timesteps: !!float 80
  policy: 'MlpPolicy'
  learning_rate: lin_7.3e-4
  buffer_size: 300
  batch_size: 16
  ent_coef: 'auto'
  gamma: 0.98
  learning_starts: 20
  policy_kwargs: "dict(log_std_init=-3, net_arch=[40, 30], activation_fn=nn.ReLU)"
"""


def test_policy_kwargs_text_and_schedules() -> None:
    text = "dict(log_std_init=-3, net_arch=dict(pi=[64], vf=[32]), activation_fn=th.nn.Tanh, ortho_init=False)"
    assert parse_policy_kwargs(text) == {"log_std_init": -3, "net_arch": {"pi": [64], "vf": [32]},
                                         "activation_fn": "Tanh", "ortho_init": False}
    assert parse_policy_kwargs({"activation_fn": "nn.ReLU"}) == {"activation_fn": "ReLU"}
    for evil in ("dict(x=__import__('os').system('true'))", "dict(activation_fn=os.system)", "print(1)"):
        with pytest.raises(ConfigError, match="policy_kwargs"):
            parse_policy_kwargs(evil)
    lin = parse_schedule("lin_3e-4", "lr")
    assert callable(lin) and lin(1.0) == pytest.approx(3e-4) and lin(0.25) == pytest.approx(7.5e-5)
    assert parse_schedule("3e-4", "lr") == pytest.approx(3e-4)
    with pytest.raises(ConfigError, match="lr: 'cos_1'"):
        parse_schedule("cos_1", "lr")


def test_zoo_file_builds_the_model_it_describes(tmp_path: Path) -> None:
    import torch.nn as nn

    (tmp_path / "sac.yml").write_text(ZOO_SAC)
    over = zoo_overrides(tmp_path / "sac.yml", "sac")
    assert over["total_timesteps"] == 80 and over["hyperparams.sac.net_arch"] == [40, 30]
    config = load_train_config(CONFIGS / "quick.yaml", {**over, "dataset": "d", "pipeline": "noadv"})
    assert config["algo"] == "sac" and config["hyperparams"]["learning_rate"] == "lin_7.3e-4"
    model = build_model(config, ScenarioEnv(sf.curve_scenario()))
    assert model.lr_schedule(1.0) == pytest.approx(7.3e-4) and model.lr_schedule(0.5) == pytest.approx(3.65e-4)
    layers = [m for m in model.actor.latent_pi if isinstance(m, nn.Linear)]
    assert [m.out_features for m in layers] == [40, 30]
    assert any(isinstance(m, nn.ReLU) for m in model.actor.latent_pi)
    assert model.actor.log_std.bias is not None and model.gamma == 0.98
    # algorithm-keyed files; unsupported keys and other policies are refused by name
    (tmp_path / "by_algo.yml").write_text("ppo: {n_steps: 64, clip_range: lin_0.2}\ntd3: {noise_type: normal, "
                                          "noise_std: 0.3}\n")
    assert zoo_overrides(tmp_path / "by_algo.yml", "td3") == {"algo": "td3", "hyperparams.td3.action_noise_std": 0.3}
    with pytest.raises(ConfigError, match="choose one with --algo"):
        zoo_overrides(tmp_path / "by_algo.yml")
    (tmp_path / "bad.yml").write_text("seal/Scenario-v0: {normalize: true}\n")
    with pytest.raises(ConfigError, match="bad.yml: normalize: VecNormalize"):
        zoo_overrides(tmp_path / "bad.yml", "sac")
    (tmp_path / "cnn.yml").write_text("seal/Scenario-v0: {policy: CnnPolicy}\n")
    with pytest.raises(ConfigError, match="MlpPolicy only"):
        zoo_overrides(tmp_path / "cnn.yml", "sac")
    (tmp_path / "unknown.yml").write_text("seal/Scenario-v0: {frobnicate: 3}\n")
    with pytest.raises(ConfigError, match="frobnicate"):
        load_train_config(CONFIGS / "quick.yaml", zoo_overrides(tmp_path / "unknown.yml", "sac"))


def test_seal_train_with_a_zoo_file_and_refused_other_algo(tmp_path: Path,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    data = tiny_dataset(tmp_path)
    (tmp_path / "sac.yml").write_text(ZOO_SAC)
    base = ["train", "--config", "quick", "--dataset", str(data), "--pipeline", "noadv", "--n-envs", "1",
            "--set", "eval_every=0", "--set", "checkpoint_every=0", "--no-progress"]
    code = main([*base, "--hyperparams", str(tmp_path / "sac.yml"), "--algo", "sac", "--out", str(tmp_path / "run"),
                 "--json"])
    assert code == 0, capsys.readouterr().err
    done = json.loads(capsys.readouterr().out)
    assert done["steps"] == 80  # n_timesteps
    recorded = (tmp_path / "run" / "config.yaml").read_text()
    assert "algo: sac" in recorded and "activation_fn: ReLU" in recorded
    code = main([*base, "--algo", "sac", "--set", "hyperparams.td3.batch_size=7", "--out", str(tmp_path / "x")])
    assert code == 2
    err = capsys.readouterr().err
    assert "hyperparams.td3.batch_size" in err and "trains sac" in err and not (tmp_path / "x").exists()
