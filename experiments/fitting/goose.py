"""``seal fit goose``: train GOOSE's goal-conditioned agent (SB3 SAC or TD3 + HER) in `GooseEnv` against the
heuristic reactive ego, then measure its goal success on held-out scenarios against reference policies.

Outputs: the agent file ``--out`` (`seal.adversaries.goose.agent`, written atomically) and a run folder with the
resolved ``config.yaml``, SB3's ``progress.csv`` (+ TensorBoard events when tensorboard is installed),
``success.csv`` (goal success rate per ``log_every`` environment steps = observed roll-outs), ``eval.json``
(held-out success of the zero / random / untrained / trained policies) and ``summary.json``.

The fit learns in chunks of ``checkpoint_every`` roll-outs and checkpoints after each (`seal.experiments.fitting.
goose_state`): the same command run again after a kill goes on from the last checkpoint and writes the same agent
as an uninterrupted fit.
"""

from __future__ import annotations

import csv
import importlib.util
import io
import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from tqdm import tqdm

from seal.adversaries.goose.agent import GooseAgent, load_goose_agent, policy_kwargs, save_goose_agent
from seal.adversaries.goose.env import GooseEnv
from seal.adversaries.goose.spec import GooseSpec
from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.chunked import fingerprint
from seal.core.config import load_config, overrides_field, to_dict
from seal.experiments import presets
from seal.experiments.evaluation.goose_eval import evaluate, random_actor, zero_actor
from seal.experiments.fitting import goose_state

logger = logging.getLogger(__name__)

PRESETS = ("quick", "standard")
FIT_THREADS = 1
"""Torch threads of ``seal fit goose``: small networks, threads only add overhead on a shared 2-core machine."""


@dataclass(frozen=True)
class GooseFitConfig:
    """Settings of ``seal fit goose`` (presets: ``experiments/configs/goose_<preset>.yaml``)."""

    algo: Literal["sac", "td3"] = "sac"
    """SB3 algorithm."""
    total_steps: int = 8000
    """Env steps = observed roll-outs of training."""
    learning_starts: int = 300
    """Random-action steps before learning."""
    batch_size: int = 128
    """Transitions per gradient step."""
    buffer_size: int = 50_000
    """Replay buffer capacity."""
    learning_rate: float = 0.001
    """Adam learning rate."""
    gamma: float = 0.9
    """Discount factor."""
    tau: float = 0.02
    """Polyak averaging coefficient."""
    train_freq: int = 1
    """Env steps between training calls."""
    gradient_steps: int = 1
    """Gradient steps per training call."""
    net_arch: tuple[int, ...] = (128, 128)
    """Hidden layer widths of actor and critics."""
    gru_hidden: int = 32
    """GRU width of the roll-out encoder."""
    her_n_sampled_goal: int = 4
    """HER: relabelled goals per transition."""
    her_strategy: Literal["future", "final", "episode"] = "future"
    """HER goal selection strategy."""
    td3_action_noise: float = 0.2
    """Gaussian exploration sigma for TD3."""
    seed: int = 0
    """Random seed."""
    split: str | None = "train"
    """Split of the training scenarios."""
    limit: int | None = None
    """Use the first N training scenarios (None: all)."""
    eval_split: str | None = "eval"
    """Held-out split (None: skip the held-out evaluation)."""
    eval_limit: int | None = None
    """Use the first N held-out scenarios (None: all)."""
    log_every: int = 500
    """Env steps per success.csv row."""
    checkpoint_every: int = 1000
    """Env steps between checkpoints of a running fit (0: none); a fit run again with the same settings goes on
    from the last one. Does not change what is learnt."""
    spec: dict[str, Any] = overrides_field(GooseSpec)
    """`GooseSpec` overrides."""

    def __post_init__(self) -> None:
        for key in ("total_steps", "batch_size", "buffer_size", "log_every", "gru_hidden", "train_freq"):
            if int(getattr(self, key)) < 1:
                raise ValueError(f"{key} must be >= 1, got {getattr(self, key)}")
        if int(self.checkpoint_every) < 0 or int(self.checkpoint_every) % int(self.train_freq):
            raise ValueError(f"checkpoint_every must be 0 or a multiple of train_freq ({self.train_freq}), got "
                             f"{self.checkpoint_every}")
        GooseSpec.from_dict(self.spec or {}, where="config key 'spec'")


def preset_file(name: str) -> Path:
    """The YAML preset ``experiments/configs/goose_<name>.yaml``."""
    return presets.preset_file("goose", name, PRESETS)


def resolve_config(preset: str | None = "standard", config_file: str | Path | None = None, sets: Sequence[str] = (),
                   **values: Any) -> GooseFitConfig:
    """Defaults < preset < YAML config file < ``values`` (None values ignored) < ``sets`` (``key=value``)."""
    return load_config(GooseFitConfig, preset=None if preset is None else preset_file(preset), file=config_file,
                       values=values, overrides=sets)


class _Progress:
    """SB3 callback: a tqdm bar over env steps and the goal-success curve (``success.csv``, one row per
    ``log_every`` steps: episodes ended in the window and their success rate)."""

    FIELDS = ("steps", "episodes", "success_rate", "success_rate_all", "mean_final_gap_m", "elapsed_s", "steps_per_s")

    def __init__(self, total: int, log_every: int, path: Path, progress: bool) -> None:
        from stable_baselines3.common.callbacks import BaseCallback

        outer = self

        class Callback(BaseCallback):  # the fit learns in chunks: `close` comes once, after the last
            def _on_training_start(self) -> None:
                outer.start(self.num_timesteps)

            def _on_step(self) -> bool:
                outer.on_step(self.num_timesteps, self.locals["dones"], self.locals["infos"])
                return True

        self.callback = Callback()
        self.total, self.log_every, self.path, self.show = total, log_every, path, progress
        self.rows: list[dict[str, Any]] = []
        self._window: list[tuple[bool, float]] = []
        self._all: list[bool] = []
        self._bar: Any = None
        self._t0 = time.perf_counter()
        self._elapsed_before = 0.0
        """Training seconds of the sessions before this one (a resumed fit)."""

    def start(self, steps: int) -> None:
        if self._bar is None:  # the first chunk of this session
            self._t0 = time.perf_counter()
            self._bar = tqdm(total=self.total, initial=steps, desc="fit goose", unit="roll-out",
                             disable=not self.show)

    @property
    def elapsed_s(self) -> float:
        """Training seconds so far, earlier sessions of a resumed fit included."""
        return self._elapsed_before + (time.perf_counter() - self._t0 if self._bar is not None else 0.0)

    def get_state(self) -> dict[str, Any]:
        """The curve so far, as JSON (checkpoints)."""
        return {"rows": self.rows, "window": self._window, "all": self._all, "elapsed_s": self.elapsed_s}

    def set_state(self, state: dict[str, Any]) -> None:
        self.rows = [dict(r) for r in state["rows"]]
        self._window = [(bool(a), float(b)) for a, b in state["window"]]
        self._all = [bool(a) for a in state["all"]]
        self._elapsed_before = float(state["elapsed_s"])

    def on_step(self, steps: int, dones: np.ndarray, infos: list[dict[str, Any]]) -> None:
        for done, info in zip(dones, infos, strict=True):
            if done:
                gap = float(info.get("achieved_goal", [np.nan])[0])
                self._window.append((bool(info.get("is_success", False)), gap))
                self._all.append(bool(info.get("is_success", False)))
        self._bar.update(1)
        if steps % self.log_every == 0:
            self._flush(steps)

    def _flush(self, steps: int) -> None:
        elapsed = self.elapsed_s
        w = self._window
        row = {
            "steps": steps,
            "episodes": len(w),
            "success_rate": round(float(np.mean([s for s, _ in w])), 4) if w else "",
            "success_rate_all": round(float(np.mean(self._all)), 4) if self._all else "",
            "mean_final_gap_m": round(float(np.nanmean([g for _, g in w])), 3) if w else "",
            "elapsed_s": round(elapsed, 1),
            "steps_per_s": round(steps / max(elapsed, 1e-9), 2),
        }
        self.rows.append(row)
        self._window = []
        self._bar.set_postfix(success=row["success_rate"], refresh=False)
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=self.FIELDS)
        writer.writeheader()
        writer.writerows(self.rows)
        atomic_write_bytes(self.path, buf.getvalue().encode())

    def close(self, steps: int) -> None:
        if self._window:
            self._flush(steps)
        if self._bar is not None:
            self._bar.close()


def _scenarios(dataset: str | Path, split: str | None, limit: int | None) -> list:
    from seal.core.dataset import load_split

    return load_split(dataset, split, limit)


def build_model(env: GooseEnv, config: GooseFitConfig, spec: GooseSpec) -> Any:
    """An SB3 SAC / TD3 model with the GOOSE policy and a HER replay buffer, from a resolved config."""
    from stable_baselines3 import SAC, TD3, HerReplayBuffer
    from stable_baselines3.common.noise import NormalActionNoise

    common: dict[str, Any] = dict(
        learning_rate=config.learning_rate, buffer_size=int(config.buffer_size),
        learning_starts=int(config.learning_starts), batch_size=int(config.batch_size),
        tau=config.tau, gamma=config.gamma, train_freq=int(config.train_freq),
        gradient_steps=int(config.gradient_steps), replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": int(config.her_n_sampled_goal),
                              "goal_selection_strategy": config.her_strategy},
        policy_kwargs=policy_kwargs(spec, list(config.net_arch), config.gru_hidden),
        seed=int(config.seed), device="cpu", verbose=0,
    )
    if config.algo == "sac":
        return SAC("MultiInputPolicy", env, **common)
    noise = NormalActionNoise(np.zeros(12), float(config.td3_action_noise) * np.ones(12))
    return TD3("MultiInputPolicy", env, action_noise=noise, **common)


def _logger(run: Path, resumed_step: int | None) -> Any:
    """SB3's logger into the run folder: ``progress.csv`` (a resumed fit keeps its rows up to the checkpoint) and
    TensorBoard events when tensorboard is installed."""
    from stable_baselines3.common.logger import Logger, TensorBoardOutputFormat

    from seal.experiments.training.callbacks import ResumableCSVOutputFormat
    from seal.experiments.training.state import truncate_progress

    progress_csv = run / "progress.csv"
    if resumed_step is None:
        progress_csv.unlink(missing_ok=True)
    else:
        truncate_progress(progress_csv, resumed_step)
    formats: list[Any] = [ResumableCSVOutputFormat(str(progress_csv))]
    if importlib.util.find_spec("tensorboard") is not None:
        formats.append(TensorBoardOutputFormat(str(run)))
    return Logger(folder=str(run), output_formats=formats)


def _learn_in_chunks(model: Any, total: int, every: int, tracker: _Progress, checkpoint: Any) -> None:
    """``model.learn`` up to ``total`` env steps in chunks of ``every`` (0: one chunk), ``checkpoint()`` after each
    chunk but the last. A chunk is a whole number of SB3's collect-then-train cycles (``every`` is a multiple of
    ``train_freq``), so its boundary changes nothing that is learnt: the next chunk goes on from the same
    observation, buffer and counters (``reset_num_timesteps=False``)."""
    while model.num_timesteps < total:
        done = int(model.num_timesteps)
        chunk = total - done if every <= 0 else min(every - done % every, total - done)
        model.learn(total_timesteps=chunk, callback=tracker.callback, reset_num_timesteps=done == 0,
                    progress_bar=False)
        if model.num_timesteps < total:
            checkpoint()
    tracker.close(int(model.num_timesteps))


def default_run_dir(out: str | Path) -> Path:
    out = Path(out)
    return out.with_name(out.stem + "_run")


def fit_goose(
    dataset: str | Path, out: str | Path, config: GooseFitConfig, run_dir: str | Path | None = None,
    progress: bool = True,
) -> dict[str, Any]:
    """Train, save the agent to ``out``, evaluate; returns the summary (also written to the run folder).

    The caller sets torch's threads (the CLI: one, `FIT_THREADS`)."""
    spec = GooseSpec.from_dict(config.spec or {}, where="config key 'spec'")
    train = _scenarios(dataset, config.split, config.limit)
    held_scenarios = None
    if config.eval_split is not None:
        held_scenarios = _scenarios(dataset, config.eval_split, config.eval_limit)
    out = Path(out)
    run = Path(run_dir) if run_dir is not None else default_run_dir(out)
    run.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(run / "config.yaml", yaml.safe_dump(
        {**to_dict(config), "dataset": str(dataset), "out": str(out)}, sort_keys=True).encode())

    env = GooseEnv(train, spec)
    model = build_model(env, config, spec)
    held_out = None if held_scenarios is None else GooseEnv(held_scenarios, spec, skip_solved=False)
    ids = [s.scenario_id for s in held_out.scenarios] if held_out is not None else []
    fit_fp = fingerprint({"config": {k: v for k, v in to_dict(config).items() if k != "checkpoint_every"},
                          "dataset": str(Path(dataset).resolve()), "out": str(out.resolve()),
                          "train": [s.scenario_id for s in train], "eval": ids})
    resumed = goose_state.read_checkpoint(run, fit_fp)
    model.set_logger(_logger(run, None if resumed is None else int(resumed["step"])))
    tracker = _Progress(int(config.total_steps), int(config.log_every), run / "success.csv", progress)

    evaluation: dict[str, Any] = {}
    if resumed is not None:
        goose_state.restore(run, model, env, resumed)
        tracker.set_state(resumed["tracker"])
        evaluation = resumed["baseline"]
        logger.info(f"resuming the fit from its checkpoint at {resumed['step']} of {config.total_steps} roll-outs")
    elif held_out is not None:
        logger.info(f"held-out baseline on {len(ids)} {config.eval_split} scenarios (zero, random, untrained)")
        untrained = GooseAgent(model.policy, spec, config.algo)
        evaluation.update(evaluate(held_out, ids, {
            "zero": zero_actor, "random": random_actor(int(config.seed)), "untrained": untrained.act,
        }, progress))

    def checkpoint() -> None:
        goose_state.write_checkpoint(run, model, env, {
            "fingerprint": fit_fp, "tracker": tracker.get_state(), "baseline": evaluation})

    _learn_in_chunks(model, int(config.total_steps), int(config.checkpoint_every), tracker, checkpoint)
    train_s = tracker.elapsed_s
    drawn, solved = env.start_counts
    summary_train = {
        "train_scenarios": len(train), "train_solved_at_start": solved, "train_scenarios_drawn": drawn,
        "train_seconds": round(train_s, 1), "resumed_from_step": None if resumed is None else int(resumed["step"]),
        "env_steps": int(model.num_timesteps), "steps_per_s": round(model.num_timesteps / train_s, 2),
        "success_curve": tracker.rows,
    }
    save_goose_agent(out, model.policy, config.algo, spec, list(config.net_arch), config.gru_hidden,
                     summary={k: v for k, v in summary_train.items() if k != "success_curve"})
    goose_state.remove(run)

    if held_out is not None:
        logger.info(f"held-out evaluation of the trained agent (as saved in {out}) on {len(ids)} scenarios")
        evaluation.update(evaluate(held_out, ids, {"trained": load_goose_agent(out).act}, progress))
        atomic_write_json(run / "eval.json", evaluation)
    summary = {
        **summary_train, "out": str(out), "run_dir": str(run),
        "held_out": {name: {k: v for k, v in r.items() if k != "rows"} for name, r in evaluation.items()},
    }
    atomic_write_json(run / "summary.json", summary)
    return summary


def format_summary(summary: dict[str, Any]) -> str:
    """Plain-text report: training speed, the success curve and the held-out comparison."""
    lines = [
        f"agent: {summary['out']}   run folder: {summary['run_dir']}",
        f"trained {summary['env_steps']} roll-outs in {summary['train_seconds']} s ({summary['steps_per_s']}/s) on "
        f"{summary['train_scenarios']} scenarios ({summary['train_solved_at_start']} of "
        f"{summary['train_scenarios_drawn']} drawn were solved by the log already and skipped)",
        "goal success per window (steps: success rate over episodes ended in the window):",
    ]
    lines += [
        f"  {r['steps']:>7}: {r['success_rate']!s:>6}  ({r['episodes']} episodes)" for r in summary["success_curve"]
    ]
    if summary["held_out"]:
        lines.append("held-out goal success (all | not solved by the log | updates used | median final goal):")
        for name, r in summary["held_out"].items():
            lines.append(
                f"  {name:>9}: {r['success_rate']:.3f} | {r['success_rate_unsolved']:.3f} | "
                f"{r['mean_updates_unsolved']:.2f} | {r['median_final_goal_unsolved']}"
            )
    return "\n".join(lines)
