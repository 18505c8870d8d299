"""`seal train` internals: config resolution, the run-folder rules, checkpointed roll-out queues (no pickle), and a
tiny training run killed mid-way and resumed (same step count at the end, queues and counters restored)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf
import yaml
from train_fixtures import tiny_dataset, tiny_scenarios, tiny_train_config

from seal.adversaries.closed_loop import ClosedLoopEnv
from seal.adversaries.history import RolloutHistory
from seal.adversaries.rule import RuleGenerator
from seal.envs.heuristic import HeuristicDriver
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.training import state as ts
from seal.experiments.training.config import load_train_config

CONFIG_DIR = Path(__file__).resolve().parents[2] / "experiments" / "configs"


def _scenarios() -> list:
    return tiny_scenarios()


def _play(env: ClosedLoopEnv, episodes: int) -> None:
    driver = HeuristicDriver()
    for _ in range(episodes):
        obs, _ = env.reset()
        done = False
        while not done:
            obs, _, term, trunc, _ = env.step(driver.act(np.asarray(obs, dtype=np.float64)))
            done = term or trunc


# ------------------------------------------------------------------------------------------------- config
def test_presets_resolve_pipelines_to_generators() -> None:
    for preset in ("quick", "standard", "paper"):
        path = CONFIG_DIR / f"{preset}.yaml"
        cat = load_train_config(path, {"pipeline": "cat", "seed": 3, "pipelines.cat.kwargs.prior": "p.pt"})
        assert cat["preset"] == preset and cat["seed"] == 3 and cat["algo"] == "td3"
        assert cat["generator"] == {"name": "cat", "kwargs": {"prior": "p.pt"}}
        assert set(cat["hyperparams"]) >= {"learning_rate", "gamma", "tau", "batch_size", "net_arch"}
        assert load_train_config(path, {"pipeline": "noadv"})["generator"] == {"name": None, "kwargs": {}}
        assert load_train_config(path, {"pipeline": "goose"})["generator"]["name"] == "goose"
        seal = load_train_config(path, {"pipeline": "seal"})["generator"]
        assert seal["name"] == "seal" and set(seal["kwargs"]) == {"prior", "objective", "skills"}
    paper = load_train_config("paper", {})  # a preset name resolves to experiments/configs/paper.yaml
    assert paper["preset"] == "paper"
    assert paper["total_timesteps"] == 1_000_000
    h = paper["hyperparams"]  # CAT's TD3
    assert (h["net_arch"], h["learning_rate"], h["gamma"], h["tau"], h["batch_size"], h["learning_starts"],
            h["buffer_size"]) == ([256, 256], 3e-4, 0.99, 0.005, 256, 10_000, 1_000_000)


def test_config_errors_name_the_key(tmp_path: Path) -> None:
    path = CONFIG_DIR / "quick.yaml"
    with pytest.raises(ValueError, match="unknown key"):
        load_train_config(path, {"no_such_key": 1})
    with pytest.raises(ValueError, match="--pipeline"):
        load_train_config(path, {"pipeline": "nope"})
    with pytest.raises(ValueError, match="hyperparams.td3"):
        load_train_config(path, {"hyperparams.td3.bogus": 1})
    with pytest.raises(ValueError, match=r"train.revisit_prob must be in \[0, 1\), got 1.0"):
        load_train_config(path, {"revisit_prob": 1.0})
    bad = tmp_path / "bad.yaml"
    bad.write_text("data: {}\n")
    with pytest.raises(ValueError, match="no 'train:' section"):
        load_train_config(bad, {})


# ----------------------------------------------------------------------------------------- folder rules
def test_run_folder_rules(tmp_path: Path) -> None:
    run = tmp_path / "run"
    assert ts.check_out_folder(run, resume=False) == "new"
    with pytest.raises(ts.RunFolderError, match="no run there"):
        ts.check_out_folder(run, resume=True)
    run.mkdir()
    (run / "notes.txt").write_text("x")
    with pytest.raises(ts.RunFolderError, match="not a `seal train` run"):
        ts.check_out_folder(run, resume=False)
    (run / ts.CONFIG).write_text("algo: td3\n")
    with pytest.raises(ts.RunFolderError, match="--resume"):
        ts.check_out_folder(run, resume=False)
    assert ts.check_out_folder(run, resume=True) == "unfinished"
    (run / ts.DONE).write_text("{}")
    for resume in (False, True):
        with pytest.raises(ts.RunFolderError, match="finished run"):
            ts.check_out_folder(run, resume=resume)


# ------------------------------------------------------------------------------------- queue state
def test_history_state_round_trip_without_pickle(tmp_path: Path) -> None:
    scenarios = _scenarios()[:3]
    env = ClosedLoopEnv(ScenarioEnv(scenarios), RuleGenerator(), k=3)
    env.reset(seed=5)
    _play(env, 6)
    state = env.get_state()
    path = tmp_path / "w.npz"
    np.savez(path, **state)
    with np.load(path, allow_pickle=False) as z:
        loaded = {k: z[k] for k in z.files}
    # Logged copies are stored once: fewer roll-outs than queue slots.
    meta = json.loads(str(loaded["meta"]))
    assert len(meta["rollouts"]) < sum(len(q) for q in meta["queues"].values())

    other = ClosedLoopEnv(ScenarioEnv(scenarios), RuleGenerator(), k=3)
    other.reset(seed=99)  # different rng and a queue touched before the restore
    other.set_state(loaded, str(path))
    for s in scenarios:
        assert (s.scenario_id in other.history) == (s.scenario_id in env.history)
        if s.scenario_id in env.history:
            assert other.history.digests(s) == env.history.digests(s)
            for a, b in zip(other.history.queue(s), env.history.queue(s), strict=True):
                np.testing.assert_array_equal(a.tracks, b.tracks)
                assert (a.outcome, a.ego_crashes, a.last_step, a.route_completion) == (
                    b.outcome, b.ego_crashes, b.last_step, b.route_completion)
    # Same rng state: both envs now draw the same scenarios.
    picks = [[e.reset()[1]["scenario_id"] for _ in range(5)] for e in (env, other)]
    assert picks[0] == picks[1]


def test_history_state_rejects_bad_queue() -> None:
    h = RolloutHistory(2)
    h.queue(sf.lane_change_scenario())
    state = h.get_state()
    meta = json.loads(str(state["meta"]))
    meta["k"] = 3
    state["meta"] = np.array(json.dumps(meta))
    with pytest.raises(ValueError, match="expected k = 3"):
        RolloutHistory.from_state(state, "w.npz")


# ------------------------------------------------------------------------------------- kill and resume
def test_killed_run_resumes_to_the_same_step_count(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from seal.experiments.training import callbacks as train_callbacks
    from seal.experiments.training.train import train_run

    run = tmp_path / "run"
    config = tiny_train_config(tiny_dataset(tmp_path))

    # Simulated kill between two checkpoints (step 100; the last checkpoint is at 80).
    original_on_step = train_callbacks.EpisodeStatsCallback._on_step

    def killing_on_step(self: train_callbacks.EpisodeStatsCallback) -> bool:
        if self.num_timesteps >= 100:
            raise KeyboardInterrupt
        return original_on_step(self)

    monkeypatch.setattr(train_callbacks.EpisodeStatsCallback, "_on_step", killing_on_step)
    with pytest.raises(KeyboardInterrupt):
        train_run(config, run, progress=False)
    monkeypatch.setattr(train_callbacks.EpisodeStatsCallback, "_on_step", original_on_step)
    assert not (run / ts.DONE).exists()
    with pytest.raises(ts.RunFolderError, match="--resume"):
        train_run(config, run, progress=False)

    ckpt = ts.latest_checkpoint(run)
    assert ckpt is not None and ckpt.name == "step_80"
    state, _, workers = ts.read_checkpoint_state(ckpt)
    assert state["step"] == 80 and state["n_updates"] == 25  # one update per vec step from step 32 to 80
    saved_meta = [json.loads(str(w["meta"])) for w in workers]
    # Each worker's queues hold roll-outs played in training (not only the log copies).
    assert all(any(r["adversary"] != "log" for r in m["rollouts"]) for m in saved_meta)

    # Capture what the workers hold right after the restore.
    seen: list = []
    original_restore = train_callbacks.RestoreCallback._on_training_start

    def capturing_restore(self: train_callbacks.RestoreCallback) -> None:
        original_restore(self)
        seen.extend(self.training_env.env_method("get_state"))
        seen.append(int(self.model.num_timesteps))
        seen.append(int(self.model._n_updates))

    monkeypatch.setattr(train_callbacks.RestoreCallback, "_on_training_start", capturing_restore)
    train_run({}, run, resume=True, progress=False)

    restored_meta = [json.loads(str(w["meta"])) for w in seen[:2]]
    assert restored_meta == saved_meta
    for w_saved, w_restored in zip(workers, seen[:2], strict=True):
        for key in w_saved:
            if key.startswith("tracks_"):
                np.testing.assert_array_equal(w_saved[key], w_restored[key])
    assert seen[2] == 80 and seen[3] == state["n_updates"]

    done = ts.read_done(run)
    assert done["steps"] == 160 and done["resumed_from"] == 80
    recorded = yaml.safe_load((run / ts.CONFIG).read_text())
    assert recorded["pipeline"] == "cat" and recorded["seed"] == 1 and recorded["n_envs"] == 2
    # One provenance entry per session (the killed start and the resume), with the generator's options resolved.
    sessions = json.loads((run / "provenance.json").read_text())["sessions"]
    assert len(sessions) == 2 and all(s["generator"]["name"] == recorded["generator"]["name"] for s in sessions)
    options = sessions[1]["generator"]["options"]
    assert options == sessions[0]["generator"]["options"]
    assert set(options) >= set(recorded["generator"]["kwargs"]) and len(options) > len(recorded["generator"]["kwargs"])
    # Logs: no row after the checkpoint survives twice; evaluations at 80 and the end.
    import csv

    steps = [int(r["time/total_timesteps"]) for r in csv.DictReader((run / ts.PROGRESS).open())
             if r["time/total_timesteps"]]
    assert steps == sorted(steps) and steps[-1] <= 160
    edge = [float(r["actor/edge_share"]) for r in csv.DictReader((run / ts.PROGRESS).open())
            if r.get("actor/edge_share")]
    assert edge and all(0.0 <= e <= 1.0 for e in edge)  # the actor's saturation, logged once there are states
    evals = [int(r["step"]) for r in csv.DictReader((run / "eval" / "evaluations.csv").open())]
    assert evals == [80, 160]
    assert (run / ts.FINAL_MODEL).is_file() and any((run / "tb").iterdir())

    # The final model loads for evaluation without unpickling.
    from seal.experiments.training.egos import load_sb3_model

    model = load_sb3_model(run)
    action, _ = model.predict(np.zeros(100, dtype=np.float32), deterministic=True)
    assert action.shape == (2,)

    with pytest.raises(ts.RunFolderError, match="finished run"):
        train_run(config, run, progress=False)


def test_episode_end_info_and_warm_up() -> None:
    scenarios = _scenarios()[:3]
    env = ClosedLoopEnv(ScenarioEnv(scenarios), RuleGenerator(), k=2, perturb_prob=1.0)
    assert env.warm_up() == 3
    assert all(s.scenario_id in env.history for s in scenarios)
    obs, reset_info = env.reset(seed=0)
    driver = HeuristicDriver()
    done, info = False, {}
    while not done:
        obs, _, term, trunc, info = env.step(driver.act(np.asarray(obs, dtype=np.float64)))
        done = term or trunc
    # The last step repeats the episode's reset metadata (a vec env's reset info is the next episode's).
    assert info["episode_adversary"] == reset_info["adversary"]
    assert info["episode_adversary"]["generator"] == "rule" and info["episode_adversary"]["perturbed"]


def test_the_training_envs_revisit_at_the_configured_rate(tmp_path: Path) -> None:
    from seal.core.dataset import load_split
    from seal.experiments.training.train import build_vec_env

    config = tiny_train_config(tiny_dataset(tmp_path))
    scenarios = load_split(config["dataset"], "train")
    assert config["revisit_prob"] == 0.0  # the presets draw every episode's scenario afresh
    venv = build_vec_env({**config, "n_envs": 1, "revisit_prob": 0.7}, scenarios, 1)
    try:
        assert venv.get_attr("revisit_prob") == [0.7]
    finally:
        venv.close()


def test_episode_stats_give_clean_success_and_the_share_of_perturbed_episodes_aimed_at_the_log() -> None:
    from seal.experiments.training.callbacks import EpisodeStatsCallback

    stats = EpisodeStatsCallback()
    base = {"outcome": "success", "crashed": False, "completion": 1.0, "generation_s": 0.0}
    stats.recent.extend([{**base, "perturbed": True, "targets_log": True},
                         {**base, "perturbed": True, "targets_log": False},
                         {**base, "perturbed": True, "targets_log": False},
                         {**base, "perturbed": False, "targets_log": False}])
    rates = stats.rates()
    assert rates["perturbed_share"] == 0.75 and abs(rates["log_target_share"] - 1 / 3) < 1e-12
    assert rates["success_rate"] == rates["clean_success_rate"] == 1.0
    stats.recent.clear()
    stats.recent.append({**base, "perturbed": False, "targets_log": False})
    assert stats.rates()["log_target_share"] == 0.0  # nothing perturbed: nothing aimed
    # with terminate_on_crash false an ego that touched someone and drove on to the goal ends in success; the
    # clean success rate (the evaluation's success) does not count it
    stats.recent.extend([{**base, "crashed": True, "perturbed": True, "targets_log": False},
                         {**base, "outcome": "crash", "crashed": True, "perturbed": True, "targets_log": False}])
    rates = stats.rates()
    assert rates["success_rate"] == 2 / 3 and rates["clean_success_rate"] == 1 / 3 and rates["crash_rate"] == 2 / 3


def test_replay_buffer_round_trip(tmp_path: Path) -> None:
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    obs_space = spaces.Box(-1.0, 1.0, (3,), np.float32)
    act_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
    rng = np.random.default_rng(0)

    def filled(n: int) -> ReplayBuffer:
        buf = ReplayBuffer(8, obs_space, act_space, device="cpu", n_envs=2)
        for _ in range(n):
            o, o2 = rng.uniform(-1, 1, (2, 3)), rng.uniform(-1, 1, (2, 3))
            buf.add(o, o2, rng.uniform(-1, 1, (2, 2)), rng.uniform(size=2), np.array([0.0, 1.0]),
                    [{"TimeLimit.truncated": True}, {}])
        return buf

    for n in (3, 6):  # part-filled, and wrapped around (size 8 / 2 envs = 4 rows)
        src = filled(n)
        ts.save_replay_buffer(src, tmp_path / "rb.npz")
        dst = ReplayBuffer(8, obs_space, act_space, device="cpu", n_envs=2)
        ts.load_replay_buffer(dst, tmp_path / "rb.npz")
        assert (dst.pos, dst.full) == (src.pos, src.full)
        for name in ("observations", "next_observations", "actions", "rewards", "dones", "timeouts"):
            np.testing.assert_array_equal(getattr(dst, name), getattr(src, name))
    wrong = ReplayBuffer(16, obs_space, act_space, device="cpu", n_envs=2)
    with pytest.raises(ValueError, match="replay buffer of size"):
        ts.load_replay_buffer(wrong, tmp_path / "rb.npz")


def test_truncate_progress_drops_rows_after_the_checkpoint(tmp_path: Path) -> None:
    path = tmp_path / "progress.csv"
    path.write_text("a,time/total_timesteps\n1,10\n2,20\n3,\n4,30\n")
    ts.truncate_progress(path, 20)
    assert path.read_text() == "a,time/total_timesteps\n1,10\n2,20\n3,\n"
    path.write_text("a,time/total_timesteps\n1,10\n2,1")  # the kill cut the last row short
    ts.truncate_progress(path, 20)
    assert path.read_text() == "a,time/total_timesteps\n1,10\n"
