"""``seal train``: an SB3 ego (TD3 with CAT's settings by default; SAC / PPO) trained in the closed loop of
DESIGN section 4 under CAT's curriculum.

Each env worker (``SubprocVecEnv``, one per core) plays its share of the train scenarios (`ClosedLoopEnv`; a
scenario's roll-out queue lives in the worker that plays it): a random scenario per episode, perturbed by the
pipeline's generator with probability p(t) = min(1.8 t / T, 0.9) (`seal.experiments.training.curriculum`), else
replayed from
the log. The run folder (`seal.experiments.training.state`) holds the resolved config, CSV + TensorBoard logs (SB3's
``rollout/`` and ``train/`` keys plus ``episode/*`` outcome rates, ``curriculum/p``, ``generator/time_ms``),
periodic evaluations on the Normal eval split, checkpoints and, at the end, ``final_model.zip`` and ``done.json``.

Resume: a run killed at any point continues from its last checkpoint (``train_run(config, out, resume=True)``,
``seal train --resume RUN``) with the model, optimiser states, replay buffer, step and update counters, rng
states and every worker's roll-out queues of that checkpoint, and ends after exactly ``total_timesteps`` env
steps. Episodes in flight at the checkpoint are dropped (the envs are reset). Trust: checkpoints are files this
run wrote into its own folder; they are still read without unpickling (arrays with ``allow_pickle=False``,
parameters with ``torch.load(weights_only=True)``), and the model is rebuilt from ``config.yaml``. What is not
restored: generator-internal memory (GOOSE's per-scenario curve edits restart from the fitted curve).
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from seal.core.dataset import load_split
from seal.experiments.training import state as ts
from seal.experiments.training.config import check_resolved, load_train_config

logger = logging.getLogger(__name__)

__all__ = ["build_model", "build_vec_env", "load_train_config", "train_run"]


def resolve_n_envs(config: Mapping[str, Any]) -> int:
    return int(config["n_envs"]) if config.get("n_envs") else max(1, os.cpu_count() or 1)


def check_steps(config: Mapping[str, Any], n_envs: int) -> None:
    """``total_timesteps`` must be reachable exactly: a multiple of ``n_envs`` (PPO: of ``n_envs * n_steps``)."""
    total = int(config["total_timesteps"])
    unit = n_envs * (int(config["hyperparams"]["n_steps"]) if config["algo"] == "ppo" else 1)
    if total % unit:
        lo, hi = total // unit * unit, (total // unit + 1) * unit
        raise ValueError(
            f"train.total_timesteps = {total} is not a multiple of {unit} (env steps per "
            f"{'PPO roll-out' if config['algo'] == 'ppo' else 'vec-env step'} with {n_envs} envs); use {lo or hi} "
            f"or {hi}"
        )


def _generator_kwargs(config: Mapping[str, Any]) -> dict[str, Any]:
    kwargs = dict(config["generator"]["kwargs"])
    missing = [k for k, v in kwargs.items() if v is None]
    if missing:
        name = config["pipeline"]
        raise ValueError(
            f"pipeline {name!r}: generator option(s) {missing} not set; set train.pipelines.{name}.kwargs in the "
            f"config or give them on the command line (--prior / --goose-model / --objective / --skills / --set)"
        )
    for key, value in kwargs.items():
        # Only values that look like paths: e.g. SEAL's ``objective`` may also name a built-in ranking ("cat").
        looks_like_path = isinstance(value, str) and ("/" in value or Path(value).suffix != "")
        if key in ("prior", "model", "objective", "skills") and looks_like_path and not Path(value).exists():
            raise FileNotFoundError(
                f"pipeline {config['pipeline']!r}: {key} = {value!r} does not exist (fit it first, or set "
                f"train.pipelines.{config['pipeline']}.kwargs.{key})"
            )
    return kwargs


def _worker(fn: Callable[[], Any], threads: int, plugins: Sequence[str] = ()) -> Callable[[], Any]:
    """``fn`` in an env worker: torch threads set and this process's ``--plugin`` modules imported first (SB3's
    forkserver workers do not see environment variables set after the server started)."""
    plugins = list(plugins)

    def build() -> Any:
        import torch

        from seal.core.plugins import load_plugins

        torch.set_num_threads(threads)
        load_plugins(plugins)
        return fn()

    return build


def build_vec_env(config: Mapping[str, Any], scenarios: list[Any], n_envs: int) -> Any:
    """``VecMonitor`` over one `ClosedLoopEnv` per worker (``SubprocVecEnv`` when ``n_envs > 1``; for ``reskill``
    each wrapped in `ReSkillEnv`), perturb probability 0 until the curriculum sets it; off-policy runs with
    ``overlap_updates`` get an `OverlapVecEnv` on top (`seal.experiments.training.overlap`)."""
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor

    from seal.adversaries.closed_loop import closed_loop_env_fns
    from seal.experiments.training.overlap import OverlapVecEnv

    gen = config["generator"]
    kwargs = _generator_kwargs(config) if gen["name"] else {}
    fns: list[Callable[[], Any]] = list(closed_loop_env_fns(
        scenarios, n_envs, gen["name"], kwargs, env_config=config["env"], k=int(config["k"]), perturb_prob=0.0,
        revisit_prob=float(config.get("revisit_prob") or 0.0)))
    if config["algo"] == "reskill":
        from seal.experiments.training.reskill import wrap_env_fns

        fns = wrap_env_fns(fns, config["hyperparams"], int(config["seed"]))
    if config.get("deadline_obs"):
        fns = [_deadline(fn) for fn in fns]
    from seal.core.plugins import plugin_specs

    workers: list[Callable[[], Any]] = [_worker(fn, 1, plugin_specs()) for fn in fns]
    venv = VecMonitor(SubprocVecEnv(workers) if n_envs > 1 else DummyVecEnv(workers))
    return OverlapVecEnv(venv) if config.get("overlap_updates") and config["algo"] != "ppo" else venv


def _deadline(fn: Callable[[], Any]) -> Callable[[], Any]:
    """``fn``'s env wrapped in `seal.envs.deadline.DeadlineObservation` (outermost: the agent's observation)."""
    def build() -> Any:
        from seal.envs.deadline import DeadlineObservation

        return DeadlineObservation(fn())

    return build


def build_model(config: Mapping[str, Any], env: Any) -> Any:
    """The SB3 model of ``config["algo"]`` with ``config["hyperparams"]`` (see `seal.experiments.training.config`);
    for ``reskill`` the high-level agent (TD3 ``hyperparams.high`` or SAC ``hyperparams.high_sac``). Off-policy
    classes defer ``train()`` to an `OverlapVecEnv` in ``env`` when there is one."""
    import stable_baselines3 as sb3

    from seal.experiments.training.overlap import overlapped

    if config["algo"] == "reskill":
        from seal.experiments.training.reskill import high_level

        algo, hyper = high_level(config["hyperparams"])
        return build_model({**config, "algo": algo, "hyperparams": hyper}, env)
    import torch

    from seal.experiments.training.zoo import parse_policy_kwargs, parse_schedule

    h = dict(config["hyperparams"])
    policy_kwargs = {"net_arch": list(h.pop("net_arch")), **parse_policy_kwargs(h.pop("policy_kwargs", None) or {})}
    if isinstance(policy_kwargs.get("activation_fn"), str):
        policy_kwargs["activation_fn"] = getattr(torch.nn, policy_kwargs["activation_fn"])
    for key in ("learning_rate", "clip_range"):
        if key in h:
            h[key] = parse_schedule(h[key], f"hyperparams.{config['algo']}.{key}")
    common = {"policy": "MlpPolicy", "env": env, "seed": int(config["seed"]), "device": config["device"],
              "policy_kwargs": policy_kwargs, "verbose": 0}
    algo = config["algo"]
    if algo == "td3":
        from stable_baselines3.common.noise import NormalActionNoise

        std = float(h.pop("action_noise_std"))
        n_act = env.action_space.shape[0]
        noise = NormalActionNoise(np.zeros(n_act), std * np.ones(n_act)) if std > 0 else None
        return overlapped(sb3.TD3)(action_noise=noise, **h, **common)
    if algo == "sac":
        return overlapped(sb3.SAC)(**h, **common)
    return sb3.PPO(**h, **common)


def _absolute_paths(config: dict[str, Any]) -> dict[str, Any]:
    """The dataset and the generator's existing files as absolute paths, so the recorded config still works from
    another working directory (``--resume``, evaluation)."""
    if config.get("dataset") is not None and Path(config["dataset"]).exists():
        config["dataset"] = str(Path(config["dataset"]).resolve())
    kwargs = dict(config["generator"]["kwargs"])
    for key, value in kwargs.items():
        if isinstance(value, str) and ("/" in value or Path(value).suffix) and Path(value).exists():
            kwargs[key] = str(Path(value).resolve())
    config["generator"] = {**config["generator"], "kwargs": kwargs}
    skills = config["hyperparams"].get("skills") if config.get("algo") == "reskill" else None
    if skills and Path(skills).exists():
        config["hyperparams"] = {**config["hyperparams"], "skills": str(Path(skills).resolve())}
    return config


def _log_interval(config: Mapping[str, Any]) -> int:
    """Off-policy: episodes between log rows (~500 rows per run at ~70 steps an episode); PPO: roll-outs."""
    if config["algo"] == "ppo":
        return 1
    return max(4, int(config["total_timesteps"]) // 70 // 500)


def _write_config(out: Path, config: Mapping[str, Any]) -> None:
    from seal.core.atomic import atomic_write_bytes

    atomic_write_bytes(out / ts.CONFIG, yaml.safe_dump(dict(config), sort_keys=True).encode())


def train_run(config: dict[str, Any], out: Path, resume: bool = False, progress: bool = True) -> Path:
    """Train (or, with ``resume``, continue) the run of ``config`` in folder ``out``; returns ``out``.

    ``config`` is a resolved config (`load_train_config`). A new run needs an absent or empty ``out``; ``resume``
    needs an unfinished run there and continues with its recorded ``config.yaml`` (``config`` is not used). A
    finished run (``done.json``) is never overwritten: `seal.experiments.training.state.RunFolderError` on misuse.
    ``done.json``: ``steps``, ``wall_s`` (seconds of training behind the final model: each session's time up to
    the checkpoint the next one resumed from, plus the last session), ``resumed_from`` (the step the last session
    started at), ``episodes``, ``session_totals`` (the last session's episode outcomes, ``crashed`` episodes with
    any contact, and generation time) and ``final_rates`` (the ``episode/*`` rates progress.csv logged last).
    Torch's thread count is the caller's (entry points set ``config["torch_threads"]``, `run_torch_threads`).
    """
    out = Path(out)
    config = _run_config(config, out, resume)
    n_envs = int(config["n_envs"])
    train_scenarios = load_split(config["dataset"], config["train_split"], config["train_limit"], "train")
    eval_scenarios = (load_split(config["dataset"], config["eval_split"], int(config["eval_episodes"]), "eval")
                      if int(config["eval_every"]) else [])
    if int(config["eval_every"]) and len(eval_scenarios) < int(config["eval_episodes"]):
        logger.warning(f"train.eval_episodes is {config['eval_episodes']} but the {config['eval_split']!r} split of "
                       f"{config['dataset']} has {len(eval_scenarios)} scenarios: each evaluation plays "
                       f"{len(eval_scenarios)}")
    if len(train_scenarios) < n_envs:
        raise ValueError(f"{len(train_scenarios)} train scenarios cannot feed {n_envs} env workers; lower train.n_envs")
    if config["generator"]["name"]:
        _generator_kwargs(config)  # fail before starting workers
    if config["algo"] == "reskill":
        from seal.experiments.training.reskill import load_skills

        load_skills(config["hyperparams"])  # fail before starting workers
    if not resume:
        out.mkdir(parents=True, exist_ok=True)
        _write_config(out, config)
    from seal.experiments.training.provenance import append_session

    append_session(out, config)
    checkpoint, restored = _restore_point(out, resume, n_envs)

    from seal.envs.road_geometry import reserve_road_cache

    # The eval env (and, with one worker, the training env) lives in this process: cache every road it cycles.
    reserve_road_cache(len({id(s.road) for s in eval_scenarios + (train_scenarios if n_envs == 1 else [])}))
    venv = build_vec_env(config, train_scenarios, n_envs)
    try:
        _learn(config, out, venv, checkpoint, restored, eval_scenarios, progress)
    except BaseException:
        close_vec_env(venv, abort=True)
        raise
    close_vec_env(venv, abort=False)
    return out


def close_vec_env(venv: Any, abort: bool, join_s: float = 10.0) -> None:
    """Close ``venv`` and its worker processes. ``abort`` (training was interrupted: SIGTERM, an error) does not
    wait for step results that may never come (SB3's ``close`` would read one reply per worker, and an interrupt
    inside ``step_wait`` leaves some already read: it would block forever); a worker still alive ``join_s``
    seconds after being told to close is killed."""
    from stable_baselines3.common.vec_env import SubprocVecEnv

    inner = venv
    while not isinstance(inner, SubprocVecEnv) and hasattr(inner, "venv"):
        inner = inner.venv
    if not abort or not isinstance(inner, SubprocVecEnv) or inner.closed:
        with contextlib.suppress(OSError, EOFError):  # workers already gone (killed with the process group)
            venv.close()
        return
    inner.waiting = False
    for remote in inner.remotes:
        with contextlib.suppress(OSError, ValueError):
            remote.send(("close", None))
    for process in inner.processes:
        process.join(join_s)
        if process.is_alive():
            process.kill()
            process.join()
    for remote in inner.remotes:
        remote.close()
    inner.closed = True


def run_torch_threads(config: Mapping[str, Any], out: Path, resume: bool) -> int:
    """The torch thread count of the run `train_run` will train (a resumed run's recorded config decides)."""
    if resume and (Path(out) / ts.CONFIG).is_file():
        recorded = yaml.safe_load((Path(out) / ts.CONFIG).read_text()) or {}
        return int(recorded.get("torch_threads", config.get("torch_threads", 1)))
    return int(config.get("torch_threads", 1))


def _run_config(config: dict[str, Any], out: Path, resume: bool) -> dict[str, Any]:
    """The config the run trains with: the recorded one when resuming (its ``plugins`` imported), else ``config``
    with absolute paths, the resolved env-worker count and the ``--plugin`` modules in force (``plugins``); steps
    checked against the worker count."""
    from seal.core.plugins import load_plugins, plugin_specs

    ts.check_out_folder(out, resume)
    if resume:
        config = check_resolved(yaml.safe_load((out / ts.CONFIG).read_text()), str(out / ts.CONFIG))
        load_plugins(config.get("plugins") or [])  # the run's generator may come from a --plugin module
    else:
        config = _absolute_paths(dict(config))
        config["n_envs"] = resolve_n_envs(config)
        if plugin_specs():  # recorded, so --resume and `seal eval runs RUN` find a plugin generator again
            config["plugins"] = plugin_specs()
    check_steps(config, int(config["n_envs"]))
    return config


def _restore_point(out: Path, resume: bool, n_envs: int) -> tuple[Path | None, dict[str, Any]]:
    """The checkpoint a resumed run continues from (None: start at step 0) and its saved state / rng / worker
    states; the progress and eval logs are cut back to that step."""
    checkpoint = ts.latest_checkpoint(out) if resume else None
    restored: dict[str, Any] = {}
    start_step = 0
    if checkpoint is not None:
        restored["state"], restored["rng"], restored["workers"] = ts.read_checkpoint_state(checkpoint)
        start_step = int(restored["state"]["step"])
        if int(restored["state"]["n_workers"]) != n_envs:
            raise ValueError(f"{checkpoint}: written by {restored['state']['n_workers']} env workers, the run "
                             f"config has n_envs = {n_envs}")
    if resume:
        from seal.experiments.training.callbacks import truncate_eval

        logger.info(f"resuming {out} from step {start_step}"
                    + (f" ({checkpoint.name})" if checkpoint else " (no checkpoint)"))
        ts.truncate_progress(out / ts.PROGRESS, start_step)
        truncate_eval(out / "eval", start_step)
    return checkpoint, restored


def _learn(config: Mapping[str, Any], out: Path, venv: Any, checkpoint: Path | None, restored: dict[str, Any],
           eval_scenarios: list[Any], progress: bool) -> None:
    """Build the model (restored from ``checkpoint``), learn to ``total_timesteps``, write the final model and
    ``done.json``."""
    from stable_baselines3.common.logger import Logger, TensorBoardOutputFormat

    from seal.core.atomic import atomic_write_json, naming_the_file
    from seal.experiments.training.callbacks import ResumableCSVOutputFormat
    from seal.experiments.training.overlap import find_overlap_env

    total = int(config["total_timesteps"])
    model = build_model(config, venv)
    reskill = _reskill_run(config, out)
    overlap = find_overlap_env(venv)
    start_step, wall_before = 0, 0.0
    if checkpoint is not None:
        start_step = int(restored["state"]["step"])
        ts.load_model_state(model, checkpoint / "model.zip")
        if getattr(model, "replay_buffer", None) is not None:
            ts.load_replay_buffer(model.replay_buffer, checkpoint / "replay_buffer.npz")
        model.num_timesteps = start_step
        model._n_updates = int(restored["state"]["n_updates"])
        model._episode_num = int(restored["state"]["episode_num"])
        wall_before = float(restored["state"].get("wall_s", 0.0))
        if reskill is not None:
            reskill.restore(checkpoint, restored["state"])
    (out / "eval").mkdir(exist_ok=True)
    model.set_logger(Logger(folder=str(out), output_formats=[
        ResumableCSVOutputFormat(str(out / ts.PROGRESS)), TensorBoardOutputFormat(str(out / "tb"))]))
    session_start = time.perf_counter()

    def save(m: Any) -> None:
        if overlap is not None:
            overlap.flush()  # the checkpoint holds every update of the steps it has seen
        states = m.get_env().env_method("get_state")
        ts.write_checkpoint(out, m, states, {"wall_s": wall_before + time.perf_counter() - session_start},
                            reskill.models() if reskill is not None else None)

    callbacks, stats = _callbacks(config, out, checkpoint, restored, eval_scenarios, save, progress, reskill)
    model.learn(total_timesteps=total - start_step, callback=callbacks, log_interval=_log_interval(config),
                reset_num_timesteps=False)
    if overlap is not None:
        overlap.flush()
    # A ReSkill step plays a whole skill (up to H env steps per worker): it may pass the budget by less than that.
    if model.num_timesteps < total or (reskill is None and model.num_timesteps != total):
        raise RuntimeError(f"training stopped at {model.num_timesteps} env steps, expected {total}")
    tmp_model = out / f".tmp_{ts.FINAL_MODEL}"
    try:
        model.save(tmp_model, exclude=ts.SAVE_EXCLUDE)
        os.replace(tmp_model, out / ts.FINAL_MODEL)
    except BaseException as exc:
        tmp_model.unlink(missing_ok=True)  # disk full: no partial file; the last checkpoint still resumes
        named = naming_the_file(exc, out / ts.FINAL_MODEL, f"resume with `seal train --resume {out}`")
        if named is exc:
            raise
        raise named from exc
    if reskill is not None:
        reskill.save_final(out)
    wall = wall_before + time.perf_counter() - session_start
    done = {"steps": int(model.num_timesteps), "wall_s": round(wall, 1), "resumed_from": start_step,
            "episodes": int(model._episode_num), "session_totals": stats.totals,
            "final_rates": stats.rates()}  # the last logged episode/* values (window of the last episodes)
    atomic_write_json(out / ts.DONE, done)
    logger.info(f"finished {out}: {done['steps']} steps in {done['wall_s']} s")


def _reskill_run(config: Mapping[str, Any], out: Path) -> Any:
    """The ReSkill parts of a ``reskill`` run (`seal.experiments.training.reskill.ReSkillRun`), else None."""
    if config["algo"] != "reskill":
        return None
    from seal.experiments.training.reskill import ReSkillRun

    return ReSkillRun(config, out, build_model)


def _callbacks(config: Mapping[str, Any], out: Path, checkpoint: Path | None, restored: dict[str, Any],
               eval_scenarios: list[Any], save: Callable[[Any], None], progress: bool,
               reskill: Any = None) -> tuple[Any, Any]:
    """The training callbacks, in the order they must run, and the episode-stats callback among them."""
    from stable_baselines3.common.callbacks import CallbackList

    from seal.envs.scenario_env import ScenarioEnv
    from seal.experiments.training.callbacks import (
        CheckpointCallback,
        EpisodeStatsCallback,
        EvalCallback,
        ProgressCallback,
        RestoreCallback,
    )
    from seal.experiments.training.curriculum import CurriculumCallback
    from seal.experiments.training.saturation import ActorSaturationCallback

    total = int(config["total_timesteps"])
    # p is pushed to every env either way; it is logged only where a generator uses it (noadv never perturbs).
    curriculum = CurriculumCallback(total, **config["curriculum"], log=bool(config["generator"]["name"]))
    stats = EpisodeStatsCallback()
    eval_env_config = dict(config["eval_env"])

    def make_eval_env() -> Any:
        return ScenarioEnv(eval_scenarios, eval_env_config)
    counter, residual = reskill.callbacks() if reskill is not None else (None, None)
    callbacks = [
        counter,  # ReSkill: num_timesteps counts env steps before anything reads it
        curriculum,  # first: a resumed run's restore resets the envs, whose first episodes then use p(t)
        RestoreCallback(restored["workers"], restored["state"]["rng"], restored["rng"])
        if checkpoint is not None else None,
        stats,
        ActorSaturationCallback(seed=int(config["seed"])),  # actor/edge_share: a policy stuck at the box edges
        residual,  # after the restore: its first weight copy reaches the restored workers
        CheckpointCallback(int(config["checkpoint_every"]), total, save),
        EvalCallback(int(config["eval_every"]), out / "eval",
                     _deadline(make_eval_env) if config.get("deadline_obs") else make_eval_env,
                     eval_scenarios, make_policy=reskill.make_policy() if reskill is not None else None)
        if eval_scenarios else None,
        ProgressCallback(total, stats, curriculum, enabled=progress),
    ]
    return CallbackList([c for c in callbacks if c]), stats
