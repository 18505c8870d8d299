"""The ReSkill ego: the high-level action decodes through the benign prior (zero action = the prior at zero noise),
the residual is bounded by its gate, the skill env plays whole skills and returns complete residual transitions,
and a killed ReSkill run resumes with both agents exactly as checkpointed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf
import torch

from seal.core.dataset import Dataset, write_dataset
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.training import state as ts
from seal.experiments.training.config import load_train_config
from seal.experiments.training.numpy_actor import NumpyMLP
from seal.experiments.training.reskill_env import ReSkillEnv
from seal.experiments.training.reskill_policy import ReSkillPolicy, combine, residual_gate
from seal.experiments.training.skill_prior import BenignSkills, noise_of
from seal.models.skills.io import VAE_FILE, prior_file, save_model
from seal.models.skills.realnvp import ConditionalRealNVP, RealNVPConfig
from seal.models.skills.vae import SkillVAE, VAEConfig

CONFIG_DIR = Path(__file__).resolve().parents[2] / "experiments" / "configs"


@pytest.fixture(scope="module")
def skills_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A skills folder with a small random VAE and a benign prior whose noise map depends on the state."""
    torch.manual_seed(0)
    vae = SkillVAE(VAEConfig(latent_dim=4, decoder_hidden=(32, 32), encoder_hidden=16))
    prior = ConditionalRealNVP(RealNVPConfig(latent_dim=4, hidden=16, cond_embed=8))
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in prior.parameters():  # couplings start as the identity: give them a state-dependent map
            p.copy_(torch.randn(p.shape, generator=gen) * 0.3)
        prior.z_std.fill_(2.0)
    folder = tmp_path_factory.mktemp("skills")
    save_model(vae, folder / VAE_FILE)
    save_model(prior, folder / prior_file("benign"))
    save_model(prior, folder / prior_file("adversarial"))
    return folder


def _obs(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0, 1, 100).astype(np.float32)


def test_high_level_action_decodes_through_the_prior(skills_dir: Path) -> None:
    from seal.models.skills.io import load_skill_models

    skills = BenignSkills(skills_dir)
    models = load_skill_models(skills_dir, priors=("benign",))
    obs = _obs(0)
    # Zero action = zero noise = the prior's mode of its base Gaussian, mapped through the state's bijection.
    z0 = skills.skill(noise_of(np.zeros(4), 2.0), obs)
    with torch.no_grad():
        expect = models.priors["benign"].sample(torch.zeros(1, 4), torch.as_tensor(obs)[None])[0].numpy()
    np.testing.assert_allclose(z0, expect, rtol=1e-4, atol=1e-5)
    assert not np.allclose(z0, models.priors["benign"].z_mean.numpy())  # the state matters (not the plain mean)
    # Any action in the box: noise = 2 * action, the decoded action is the VAE decoder's for that skill.
    u = np.array([1.0, -0.5, 0.25, 3.0])  # out of the box: clipped to 1
    z = skills.skill(noise_of(u, 2.0), obs)
    with torch.no_grad():
        zt = models.priors["benign"].sample(torch.tensor([[2.0, -1.0, 0.5, 2.0]]), torch.as_tensor(obs)[None])
        a = models.vae.decode(torch.as_tensor(obs)[None], zt)[0].numpy()
    np.testing.assert_allclose(z, zt[0].numpy(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(skills.action(obs), a, rtol=1e-4, atol=1e-5)


def test_residual_starts_as_no_correction_and_learns(tmp_path: Path, skills_dir: Path) -> None:
    """The residual actor (and its target) outputs exactly 0 before any update, whatever the input, so opening the
    gate does not change the skill policy; one gradient step on a batch whose reward favours a positive
    correction moves it off zero (the zeroed layer still receives gradient)."""
    from stable_baselines3.common.logger import Logger

    from seal.experiments.training.numpy_actor import actor_mlp
    from seal.experiments.training.reskill import build_residual_model
    from seal.experiments.training.train import build_model

    config = _tiny_config(_dataset(tmp_path), skills_dir)
    config["hyperparams"]["residual"]["learning_starts"] = 0
    config["hyperparams"]["residual"]["policy_delay"] = 1
    residual = build_residual_model(config, BenignSkills(skills_dir), build_model)
    residual.set_logger(Logger(folder=None, output_formats=[]))
    actor = actor_mlp(residual)
    rng = np.random.default_rng(0)
    x = rng.normal(0, 3, (50, residual.observation_space.shape[0])).astype(np.float32)
    for row in x:
        assert np.array_equal(actor(row), np.zeros(2, np.float32))
    with torch.no_grad():
        assert torch.count_nonzero(residual.actor_target(torch.as_tensor(x))) == 0
    buffer = residual.replay_buffer
    for row in x:  # reward = the first action component: the critic learns that more steering pays
        a = rng.uniform(-1, 1, (1, 2)).astype(np.float32)
        buffer.add(row[None], row[None], a, np.array([a[0, 0]]), np.array([1.0]), [{}])
    residual.train(gradient_steps=20, batch_size=16)
    moved = np.stack([actor_mlp(residual)(row) for row in x[:10]])
    assert np.abs(moved).max() > 1e-4


def test_residual_is_bounded_by_gate_and_bound() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        base = rng.uniform(-1, 1, 2).astype(np.float32)
        r = rng.uniform(-3, 3, 2).astype(np.float32)  # even an out-of-range residual
        gate = float(rng.uniform(0, 1))
        a = combine(base, r, gate, 0.2)
        assert np.all(np.abs(a - base) <= gate * 0.2 + 1e-6) and np.all(np.abs(a) <= 1.0)
    assert np.array_equal(combine(np.array([0.5, 0.5]), np.array([1.0, -1.0]), 0.0, 0.2), np.array([0.5, 0.5],
                                                                                                  np.float32))
    np.testing.assert_allclose(combine(np.array([0.5, 0.0]), np.array([1.0, -1.0]), 1.0, 0.2), [0.7, -0.2])
    assert [residual_gate(s, 100, 50) for s in (0, 99, 100, 125, 150, 1000)] == [0.0, 0.0, 0.0, 0.5, 1.0, 1.0]
    assert residual_gate(100, 100, 0) == 1.0
    actor = NumpyMLP(((np.eye(3, dtype=np.float32) * 10, np.zeros(3, np.float32)),
                      (np.ones((2, 3), np.float32), np.zeros(2, np.float32))), (("ReLU", ()), ("Tanh", ())))
    out = actor(np.array([1.0, -1.0, 2.0], np.float32))
    np.testing.assert_allclose(out, np.tanh([30.0, 30.0]), rtol=1e-6)


class _FixedHigh:
    def __init__(self, u: np.ndarray) -> None:
        self.u, self.calls = u, 0

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        self.calls += 1
        return self.u, None


def test_skill_env_plays_whole_skills_and_returns_residual_transitions(skills_dir: Path) -> None:
    from seal.adversaries.closed_loop import ClosedLoopEnv

    skills = BenignSkills(skills_dir)
    env = ReSkillEnv(ClosedLoopEnv(ScenarioEnv([sf.highway_scenario(0)]), None), skills, 2.0, 0.2, 0.0, seed=0)
    layers = NumpyMLP(((np.full((2, 106), 0.01, np.float32), np.array([0.3, -0.3], np.float32)),), (("Tanh", ()),))
    env.set_residual(layers, 0.5)
    obs, _ = env.reset(seed=0)
    u = np.full(4, 0.3, np.float32)
    # The same skill played by the policy the evaluation uses gives the same actions and env steps.
    policy = ReSkillPolicy(_FixedHigh(u), skills, layers, 0.5, 2.0, 0.2)
    ref = ScenarioEnv([sf.highway_scenario(0)])
    ref_obs, _ = ref.reset(seed=0)
    np.testing.assert_array_equal(obs, ref_obs)
    ref_rewards: list[float] = []
    total_steps, rows, done = 0, [], False
    while not done:
        obs, reward, term, trunc, info = env.step(u)
        n = info["env_steps"]
        assert n == 10 or term or trunc
        part = []
        for _ in range(n):
            ref_obs, r, t1, t2, _ = ref.step(policy.predict(ref_obs)[0])
            part.append(float(r))
        ref_rewards += part
        assert reward == pytest.approx(sum(part), abs=1e-5)
        np.testing.assert_allclose(obs, ref_obs, atol=1e-5)
        total_steps += n
        done = term or trunc
        rows.append(info.get("residual"))
    # Every env step gave one residual transition; x' of one is x of the next, across skill boundaries too.
    got = {k: np.concatenate([r[k] for r in rows if r is not None]) for k in rows[0]}
    assert len(got["reward"]) == total_steps
    np.testing.assert_allclose(got["next_obs"][:-1], got["obs"][1:])
    np.testing.assert_allclose(got["reward"], ref_rewards, atol=1e-5)
    assert got["done"][:-1].sum() == 0 and (got["done"][-1] == 1.0) == term
    assert np.all(np.abs(got["action"]) <= 1.0)
    # Gate closed: no residual transitions at all.
    env.set_residual(layers, 0.0)
    env.reset(seed=1)
    assert "residual" not in env.step(u)[4]


def _dataset(tmp_path: Path) -> Path:
    root = tmp_path / "data"
    scenarios = [sf.lane_change_scenario(), sf.curve_scenario(), *(sf.highway_scenario(i) for i in range(3))]
    write_dataset(root, scenarios)
    ids = [s.scenario_id for s in scenarios]
    Dataset.open(root).update_manifest(splits={"train": ids[:4], "eval": ids[4:]})
    return root


def _tiny_config(data: Path, skills: Path, high_algo: str = "td3") -> dict:
    small = {"batch_size": 16, "net_arch": [16, 16], "buffer_size": 400}
    high = {**small, "learning_starts": 60, "train_freq": 1, "gradient_steps": 1}
    over = {
        "algo": "reskill", "pipeline": "noadv", "seed": 2, "dataset": str(data), "total_timesteps": 400,
        "n_envs": 2, "checkpoint_every": 200, "eval_every": 200, "eval_episodes": 1,
        "hyperparams.reskill": {"skills": str(skills), "residual_start": 100, "residual_ramp": 100,
                                "residual_sync_every": 40, "high_algo": high_algo,
                                "high" if high_algo == "td3" else "high_sac": high,
                                "residual": {**small, "learning_starts": 20, "train_freq": 4, "gradient_steps": 1}},
    }
    return load_train_config(CONFIG_DIR / "quick.yaml", over)


def _params(model: object) -> dict[str, np.ndarray]:
    return {k: v.detach().numpy().copy() for k, v in model.policy.state_dict().items()}  # type: ignore[attr-defined]


def _ent_coef(model: object) -> float | None:
    """SAC's learned log entropy coefficient (None for TD3)."""
    log_ent = getattr(model, "log_ent_coef", None)
    return None if log_ent is None else float(log_ent.detach().item())


@pytest.mark.parametrize("high_algo", ["td3", "sac"])
def test_killed_reskill_run_resumes_both_agents_exactly(tmp_path: Path, skills_dir: Path,
                                                        monkeypatch: pytest.MonkeyPatch, high_algo: str) -> None:
    from stable_baselines3 import SAC, TD3

    from seal.experiments.training import callbacks as train_callbacks
    from seal.experiments.training import reskill as rk
    from seal.experiments.training.egos import EgoError, ReSkillEgo, make_ego
    from seal.experiments.training.train import train_run

    run = tmp_path / "run"
    config = _tiny_config(_dataset(tmp_path), skills_dir, high_algo)
    saved: dict[str, dict[str, np.ndarray]] = {}
    original_write = ts.write_checkpoint

    def recording_write(out, model, states, extra, extra_models=None):  # type: ignore[no-untyped-def]
        folder = original_write(out, model, states, extra, extra_models)
        saved[folder.name] = {"high": _params(model), "residual": _params(extra_models[rk.RESIDUAL]),
                              "n_res": extra_models[rk.RESIDUAL]._n_updates,
                              "res_size": extra_models[rk.RESIDUAL].replay_buffer.size(),
                              "ent": _ent_coef(model), "high_sac": isinstance(model, SAC)}
        return folder

    monkeypatch.setattr(ts, "write_checkpoint", recording_write)
    original_on_step = train_callbacks.EpisodeStatsCallback._on_step

    def killing_on_step(self: train_callbacks.EpisodeStatsCallback) -> bool:
        if self.num_timesteps >= 300:
            raise KeyboardInterrupt
        return original_on_step(self)

    monkeypatch.setattr(train_callbacks.EpisodeStatsCallback, "_on_step", killing_on_step)
    with pytest.raises(KeyboardInterrupt):
        train_run(config, run, progress=False)
    monkeypatch.setattr(train_callbacks.EpisodeStatsCallback, "_on_step", original_on_step)
    ckpt = ts.latest_checkpoint(run)
    assert ckpt is not None and ckpt.name in saved
    rec = saved[ckpt.name]
    assert rec["n_res"] > 0 and rec["res_size"] > 0  # the residual had started learning before the kill
    assert (ckpt / "residual.zip").is_file() and (ckpt / "residual_replay_buffer.npz").is_file()

    seen: dict[str, object] = {}
    original_restore = rk.ResidualTrainer._on_training_start

    def capturing(self: rk.ResidualTrainer) -> None:
        seen.update(high=_params(self.model), residual=_params(self.residual), n_res=self.residual._n_updates,
                    res_size=self.residual.replay_buffer.size(), step=self.model.num_timesteps,
                    ent=_ent_coef(self.model))
        original_restore(self)

    monkeypatch.setattr(rk.ResidualTrainer, "_on_training_start", capturing)
    train_run({}, run, resume=True, progress=False)
    assert seen["step"] == int(ckpt.name.split("_")[1])
    for agent in ("high", "residual"):
        for key, value in rec[agent].items():
            np.testing.assert_array_equal(seen[agent][key], value)  # type: ignore[index]
    assert (seen["n_res"], seen["res_size"]) == (rec["n_res"], rec["res_size"])
    # the high-level learner is the one asked for; SAC's entropy coefficient had moved and resumes as saved
    assert rec["high_sac"] == (high_algo == "sac")
    assert (rec["ent"] is None) == (high_algo == "td3") and seen["ent"] == rec["ent"]
    if high_algo == "sac":
        assert rec["ent"] != 0.0  # log(1) at the start: the coefficient was learning

    done = ts.read_done(run)
    assert 400 <= done["steps"] < 400 + 2 * 10  # whole skills: at most one skill per worker past the budget
    assert (run / rk.FINAL_RESIDUAL).is_file() and (run / "tb" / rk.RESIDUAL).is_dir()
    ego = make_ego(str(run))
    assert isinstance(ego, ReSkillEgo)
    ego.reset(sf.highway_scenario(4))
    action = ego.act(_obs(3), 0)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)
    # the trained ego loads its high level as the algorithm it was trained with, and decides through the numpy copy
    # of its actor exactly as SB3's predict would
    assert isinstance(ego.policy.high, {"td3": TD3, "sac": SAC}[high_algo])
    for seed in range(5):
        np.testing.assert_allclose(ego.policy.high_action(_obs(seed)),
                                   ego.policy.high.predict(_obs(seed), deterministic=True)[0], atol=1e-5)
    # a checkpoint is an ego too (seal eval runs RUN/checkpoints/step_N/model.zip): its own two agents, the gate
    # at its step, whether or not the caller names the algorithm
    for algo in (None, "reskill"):
        at_ckpt = make_ego(str(ckpt / "model.zip"), algo)
        assert isinstance(at_ckpt, ReSkillEgo)
        for key, value in rec["high"].items():
            np.testing.assert_array_equal(at_ckpt.policy.high.policy.state_dict()[key].numpy(), value)
        assert at_ckpt.policy.gate == rk.residual_gate(
            int(ckpt.name.split("_")[1]), int(config["hyperparams"]["residual_start"]),
            int(config["hyperparams"]["residual_ramp"]))
    (ckpt / "residual.zip").unlink()
    with pytest.raises(EgoError, match="no residual.zip"):
        make_ego(str(ckpt / "model.zip"))


def test_reskill_config_resolves_and_refuses_bad_values() -> None:
    for preset in ("quick", "standard", "paper"):
        config = load_train_config(CONFIG_DIR / f"{preset}.yaml", {"algo": "reskill", "pipeline": "noadv"})
        h = config["hyperparams"]
        assert config["algo"] == "reskill" and config["overlap_updates"] is True
        assert set(h) >= {"skills", "noise_bound", "residual_bound", "residual_start", "residual_ramp", "high",
                          "residual"}
        assert h["high"]["gamma"] == pytest.approx(0.9) and h["residual"]["action_noise_std"] == 0.0
    with pytest.raises(ValueError, match="noise_bound"):
        load_train_config(CONFIG_DIR / "quick.yaml", {"algo": "reskill", "hyperparams.reskill.noise_bound": 0})
    # the high-level learner: TD3 unless asked; a run recorded before high_algo existed is a TD3 run
    from seal.experiments.training.reskill import high_level

    h = load_train_config(CONFIG_DIR / "standard.yaml", {"algo": "reskill", "pipeline": "noadv"})["hyperparams"]
    assert high_level(h) == ("td3", h["high"])
    assert high_level({k: v for k, v in h.items() if k != "high_algo"}) == ("td3", h["high"])
    # the decisive preset's high level learns with SAC; asked for TD3 it is a TD3 run
    sac = load_train_config(CONFIG_DIR / "decisive.yaml", {"algo": "reskill", "pipeline": "noadv"})["hyperparams"]
    assert high_level(sac) == ("sac", sac["high_sac"]) and sac["high_sac"]["ent_coef"] == "auto_0.1"
    td3 = load_train_config(CONFIG_DIR / "decisive.yaml", {"algo": "reskill", "pipeline": "noadv",
                                                           "hyperparams.reskill.high_algo": "td3"})["hyperparams"]
    assert high_level(td3) == ("td3", td3["high"])
    with pytest.raises(ValueError, match="high_algo must be one of"):
        load_train_config(CONFIG_DIR / "quick.yaml", {"algo": "reskill", "hyperparams.reskill.high_algo": "ppo"})
    with pytest.raises(ValueError, match="train.algo"):
        load_train_config(CONFIG_DIR / "quick.yaml", {"algo": "nope"})


def test_time_aware_reskill_run_learns_and_evaluates_on_the_deadline_observation(tmp_path: Path,
                                                                                 skills_dir: Path) -> None:
    """``deadline_obs``: the high-level agent learns on the observation plus the deadline slots (its replay buffer
    holds them, the time limit is terminal); the trained ego says so, and an evaluation episode gives its high-level
    agent those slots while its skills read the observation alone."""
    from seal.envs.deadline import DEADLINE_OBS_DIM, deadline_features
    from seal.experiments.evaluation.episodes import run_episode
    from seal.experiments.training.egos import ReSkillEgo, make_ego
    from seal.experiments.training.train import train_run

    run = tmp_path / "run"
    config = _tiny_config(_dataset(tmp_path), skills_dir)
    config["deadline_obs"] = True
    train_run(config, run, progress=False)
    ego = make_ego(str(run))
    assert isinstance(ego, ReSkillEgo) and ego.deadline_obs
    assert ego.policy.high.observation_space.shape == (DEADLINE_OBS_DIM,)
    high_seen: list[np.ndarray] = []
    skill_seen: list[int] = []
    high_action, skill = ego.policy.high_action, ego.policy.skills.skill

    def recording_high_action(obs):  # type: ignore[no-untyped-def]
        high_seen.append(np.asarray(obs).copy())
        return high_action(obs)

    def recording_skill(noise, obs):  # type: ignore[no-untyped-def]
        skill_seen.append(np.asarray(obs).size)
        return skill(noise, obs)

    ego.policy.high_action, ego.policy.skills.skill = recording_high_action, recording_skill
    scenario = sf.lane_change_scenario()
    env = ScenarioEnv([scenario])
    rollout = run_episode(env, scenario, ego)
    assert rollout.last_step > 10 and len(high_seen) >= 1
    assert {o.size for o in high_seen} == {DEADLINE_OBS_DIM} and set(skill_seen) == {100}
    route = env._route
    np.testing.assert_array_equal(high_seen[0][100:], deadline_features(route, route.start_s, 10, 90, 0.95))
