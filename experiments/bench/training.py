"""``seal bench training``: env steps/s of ``seal train`` with learning included, against the same vec env
driven by random actions (the reference measured in the same run), and what bounds the speed.

Both measurements use the config's vec env (one `ClosedLoopEnv` worker per core, the pipeline's generator) with
the perturbation probability fixed at the curriculum's mean over a run (0.675 for CAT's schedule), so generation
costs what it costs on average in training. Before measuring, every worker builds its scenarios' road geometries
and logged roll-out queues (`ClosedLoopEnv.warm_up`): a 1M-step run visits each train scenario hundreds of times,
so the first-visit cost (~30 ms a scenario) does not count there; the generator's own per-road caches are not
warmed (a cold CAT call is ~0.3 s instead of ~15 ms), which makes the generation share an upper bound.
The training measurement runs the config's algorithm and hyper-parameters with ``learning_starts`` lowered to
one batch, so every measured step pays its gradient updates.
Reported: both steps/s, the generator's share of env-worker time, the cost of one gradient step, the gradient
steps per env step of the config, and the estimated wall time of a 1M-step run (steps/s with learning).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from typing import Any

import numpy as np

TARGET_S = 2 * 3600.0
"""Target: a 1M-step run of the default preset in under 2 hours."""


def mean_perturb_probability(slope: float, cap: float, warmup: float = 0.0) -> float:
    """Mean of p(t) = min(slope (t / T - warmup), cap) (0 before the warm-up ends) over t in [0, T]."""
    if slope <= 0:
        return 0.0
    span = 1.0 - warmup  # the ramp and the plateau share what the warm-up leaves
    ramp = min(span, cap / slope)
    return float(0.5 * slope * ramp**2 + cap * (span - ramp))


def gradient_steps_per_env_step(config: Mapping[str, Any], n_envs: int, horizon: int = 10) -> float:
    """Gradient steps per env step of the config; ReSkill: the high-level agent's (one transition per skill of
    ``horizon`` env steps) plus the residual's (one transition per env step once its gate is open)."""
    h = config["hyperparams"]
    if config["algo"] == "reskill":
        high, res = h["high"], h["residual"]
        return (float(high["gradient_steps"]) / (int(high["train_freq"]) * n_envs * horizon)
                + float(res["gradient_steps"]) / int(res["train_freq"]))
    if config["algo"] == "ppo":
        return float(h["n_epochs"]) * (n_envs * h["n_steps"] // h["batch_size"]) / (n_envs * h["n_steps"])
    grad = h["gradient_steps"]
    return 1.0 if grad < 0 else float(grad) / (int(h["train_freq"]) * n_envs)


class _GenerationTime:
    """Sums the generation time of finished episodes from vec-env step infos."""

    def __init__(self) -> None:
        self.seconds, self.episodes, self.perturbed = 0.0, 0, 0

    def add(self, infos: Any, dones: Any) -> None:
        for info, done in zip(infos, dones, strict=True):
            if done and "episode_adversary" in info:
                adv = info["episode_adversary"]
                self.episodes += 1
                self.perturbed += bool(adv.get("perturbed"))
                self.seconds += float(adv.get("generation_time_s") or 0.0)


def run_training_bench(config: dict[str, Any], steps: int = 3000, progress: bool = True) -> dict[str, Any]:
    """Measure (module docstring) with ``steps`` env steps per measurement; returns a flat result dict. Torch's
    thread count is the caller's (``seal bench training`` sets the config's ``torch_threads``)."""
    from seal.core.dataset import load_split
    from seal.experiments.training.train import build_vec_env, resolve_n_envs

    n_envs = resolve_n_envs(config)
    scenarios = load_split(config["dataset"], config["train_split"], config["train_limit"], "train")
    p = mean_perturb_probability(**config["curriculum"]) if config["generator"]["name"] else 0.0
    venv = build_vec_env(config, scenarios, n_envs)
    try:
        venv.env_method("set_perturb_prob", p)
        venv.env_method("warm_up")  # road geometries and logged queues, as in a long run (see the docstring)
        rng = np.random.default_rng(int(config["seed"]))
        env_sps, env_s, gen_env = _env_only(venv, rng, n_envs, steps, progress)
        measured, train_sps, grad_ms = _with_learning(config, venv, steps, progress)
        horizon = int(venv.get_attr("skills")[0].horizon) if config["algo"] == "reskill" else 1
    finally:
        venv.close()

    ratio = gradient_steps_per_env_step(config, n_envs, horizon)
    est_1m = 1e6 / train_sps
    env_ms = 1e3 / env_sps
    grad_per_step_ms = ratio * grad_ms if np.isfinite(grad_ms) else float("nan")
    step_ms = 1e3 / train_sps
    return {
        "preset": config["preset"], "algo": config["algo"], "pipeline": config["pipeline"],
        "generator": config["generator"]["name"] or "none", "n_envs": n_envs, "perturb_prob": round(p, 3),
        "measured_steps": int(measured),
        "env_only_steps_per_s": round(env_sps, 1),
        "training_steps_per_s": round(train_sps, 1),
        "ratio_training_vs_env_only": round(train_sps / env_sps, 3),
        "generation_share_of_env_worker_time": round(gen_env.seconds / (env_s * n_envs), 3),
        "generation_ms_per_perturbed_episode": round(1e3 * gen_env.seconds / max(gen_env.perturbed, 1), 1),
        "overlap_updates": bool(config.get("overlap_updates")) and config["algo"] != "ppo",
        "gradient_steps_per_env_step": round(ratio, 4),
        "gradient_step_ms": round(grad_ms, 2),
        "ms_per_env_step_training": round(step_ms, 3),
        "  of which env (wall, parallel workers)": round(env_ms, 3),
        "  of which gradient updates": round(grad_per_step_ms, 3),
        # With overlapped updates env and gradient time run at once: "other" is then what remains after both,
        # negative by as much as the overlap saved.
        "  of which other (SB3 loop, buffer, IPC)": round(step_ms - env_ms - grad_per_step_ms, 3),
        "estimated_1M_steps_h": round(est_1m / 3600, 2),
        "target": "1M steps < 2 h",
        "meets_target": bool(est_1m < TARGET_S),
    }


def _env_only(venv: Any, rng: np.random.Generator, n_envs: int, steps: int,
              progress: bool) -> tuple[float, float, _GenerationTime]:
    """Random actions after a warm-up; returns env steps/s, the measured seconds and the generation time."""
    from tqdm import tqdm

    shape = (n_envs, *venv.action_space.shape)  # ReSkill: a skill's prior noise, several env steps a step
    venv.reset()
    for _ in range(max(1, 100 // n_envs)):  # warm-up: lazy imports, the generator's first (cold) calls
        venv.step(rng.uniform(-1, 1, shape).astype(np.float32))
    gen_env = _GenerationTime()
    bar = tqdm(total=steps, desc="env only", unit="step", disable=not progress)
    done_steps = 0
    start = time.perf_counter()
    while done_steps < steps:
        _, _, dones, infos = venv.step(rng.uniform(-1, 1, shape).astype(np.float32))
        gen_env.add(infos, dones)
        n = sum(int(info.get("env_steps", 1)) for info in infos)
        done_steps += n
        bar.update(n)
    env_s = time.perf_counter() - start
    bar.close()
    return done_steps / env_s, env_s, gen_env


def _bench_config(config: Mapping[str, Any], steps: int) -> dict[str, Any]:
    """The config with learning from the first batch on (and buffers no larger than the measurement needs); ReSkill:
    the residual gate open from the start (its state for most of a run)."""
    def from_first_batch(h: dict[str, Any], per_transition: int) -> dict[str, Any]:
        return {**h, "learning_starts": int(h["batch_size"]) * per_transition,
                "buffer_size": max(int(h["batch_size"]) * 4, min(int(h["buffer_size"]), 4 * steps))}

    h = dict(config["hyperparams"])
    if config["algo"] == "reskill":
        h.update(high=from_first_batch(h["high"], 10), residual=from_first_batch(h["residual"], 1),
                 residual_start=0, residual_ramp=0)
    elif config["algo"] != "ppo":
        h = from_first_batch(h, 1)
    return {**config, "hyperparams": h}


def _gradient_step_ms(model: Any, batch_size: int, venv: Any) -> float:
    """Mean cost of one gradient step of an off-policy ``model`` (its un-deferred ``train``), ms."""
    from seal.experiments.training.overlap import find_overlap_env

    overlap = find_overlap_env(venv)
    n_grad = 50
    start = time.perf_counter()
    model.train(gradient_steps=n_grad, batch_size=batch_size)
    if overlap is not None:
        overlap.flush()  # a deferred train() runs here
    return 1e3 * (time.perf_counter() - start) / n_grad


def _with_learning(config: Mapping[str, Any], venv: Any, steps: int, progress: bool) -> tuple[int, float, float]:
    """The config's algorithm learning on ``venv`` (learning from the first batch on); returns the measured steps,
    steps/s and the cost of one gradient step (ms; NaN for PPO; ReSkill: the mean over its two agents weighted by
    their gradient steps per env step)."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    from seal.experiments.training.overlap import find_overlap_env
    from seal.experiments.training.train import build_model

    bench_config = _bench_config(config, steps)
    h = bench_config["hyperparams"]
    model = build_model(bench_config, venv)
    reskill = None
    if config["algo"] == "reskill":
        from seal.experiments.training.reskill import ReSkillRun

        reskill = ReSkillRun(bench_config, None, build_model)
    n_envs = venv.num_envs
    warmup = (int(h["high"]["learning_starts"]) if reskill else int(h.get("learning_starts", 0))) \
        + 2 * n_envs * int(h.get("n_steps", 1))
    bar = tqdm(total=warmup + steps, desc="training", unit="step", disable=not progress)

    class Collect(BaseCallback):
        def _on_step(self) -> bool:
            bar.update(self.model.num_timesteps - bar.n)
            return True

    def callbacks() -> list[BaseCallback]:
        if reskill is None:
            return [Collect()]
        counter, trainer = reskill.callbacks()
        return [counter, Collect(), trainer]

    model.learn(warmup, callback=callbacks())  # fills a batch and compiles nothing; excluded from the timing
    start_steps = int(model.num_timesteps)
    start = time.perf_counter()
    model.learn(steps, callback=callbacks(), reset_num_timesteps=False)
    overlap = find_overlap_env(venv)
    if overlap is not None:
        overlap.flush()
    train_s = time.perf_counter() - start
    bar.close()
    measured = int(model.num_timesteps - start_steps)
    grad_ms = float("nan")
    if reskill is not None:
        high_ms = _gradient_step_ms(model, int(h["high"]["batch_size"]), venv)
        res_ms = _gradient_step_ms(reskill.residual, int(h["residual"]["batch_size"]), venv)
        w_high = float(h["high"]["gradient_steps"]) / (int(h["high"]["train_freq"]) * n_envs * 10)
        w_res = float(h["residual"]["gradient_steps"]) / int(h["residual"]["train_freq"])
        grad_ms = (w_high * high_ms + w_res * res_ms) / (w_high + w_res)
    elif config["algo"] != "ppo":
        grad_ms = _gradient_step_ms(model, int(h["batch_size"]), venv)
    return measured, measured / train_s, grad_ms
