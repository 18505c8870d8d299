"""The ReSkill ego in ``seal train --algo reskill`` (thesis 6.4.1, after ReSkill): the trainer-side parts.

Two agents learn from the env reward:

- the **high-level agent** is an SB3 TD3 or SAC (``hyperparams.high_algo``; `high_level`) on `ReSkillEnv` (one
  transition per skill: the state where the skill was picked, the prior-noise action, the summed reward of its H
  env steps, the state after it); SB3's loop drives it like any other run (curriculum, checkpoints, evaluation),
  with ``num_timesteps`` counting env steps (`EnvStepCounter`), so budgets, ``learning_starts``, checkpoints and
  curves are in env steps as for the other algorithms;
- the **residual agent** is a second SB3 TD3 used as a learner only (`build_residual_model`: replay buffer, critics,
  actor): `ResidualTrainer` adds the residual transitions the env workers return, runs its gradient steps (one per
  ``train_freq`` transitions, overlapped with env stepping when the run overlaps updates), copies its actor to the
  workers every ``residual_sync_every`` env steps with the current gate and logs ``residual/*`` and its
  ``train/*`` losses to ``tb/residual``.

Gate (ReSkill's gating of the residual; `seal.experiments.training.reskill_policy.residual_gate`): off for the first
``residual_start`` env steps, so the high-level agent first learns in the pure skill space, where every action
is an in-distribution skill; then a linear ramp over ``residual_ramp`` steps, so the residual's corrections grow
as its critic learns instead of hitting a trained high-level agent at full size. ReSkill gates the residual to
the same end; we chose a fixed schedule in env steps (reproducible, resumable from the step count).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from seal.experiments.training.numpy_actor import actor_mlp
from seal.experiments.training.overlap import find_overlap_env
from seal.experiments.training.reskill_env import ReSkillEnv, residual_space
from seal.experiments.training.reskill_policy import ReSkillPolicy, residual_gate
from seal.experiments.training.skill_prior import BenignSkills, EgoSkills

RESIDUAL = "residual"
"""Name of the residual agent in checkpoints (``residual.zip``, ``residual_replay_buffer.npz``)."""
FINAL_RESIDUAL = "final_residual.zip"


def load_skills(hyper: Mapping[str, Any]) -> BenignSkills:
    """The ego's skills from ``hyperparams.skills`` (a ``seal fit skills`` folder)."""
    folder = hyper.get("skills")
    if not folder:
        raise ValueError("algo reskill: train.hyperparams.reskill.skills is not set (a `seal fit skills` folder; "
                         "--ego-skills PATH or --set hyperparams.reskill.skills=PATH)")
    if not Path(folder).is_dir():
        raise FileNotFoundError(f"train.hyperparams.reskill.skills = {folder!r} is not a folder (seal fit skills)")
    return BenignSkills(folder)


def high_level(hyper: Mapping[str, Any]) -> tuple[str, Mapping[str, Any]]:
    """(algorithm, its settings) of the high-level agent: ``hyperparams.high_algo`` (td3 for runs recorded before
    it existed) and ``high`` (TD3) or ``high_sac`` (SAC)."""
    algo = str(hyper.get("high_algo", "td3"))
    return algo, hyper["high_sac"] if algo == "sac" else hyper["high"]


def wrap_env_fns(fns: list[Callable[[], gym.Env]], hyper: Mapping[str, Any], seed: int) -> list[Callable[[], Any]]:
    """Each worker's env constructor wrapped in `ReSkillEnv` (skills loaded inside the worker)."""
    def make(fn: Callable[[], gym.Env], i: int) -> Callable[[], ReSkillEnv]:
        def build() -> ReSkillEnv:
            return ReSkillEnv(fn(), load_skills(hyper), float(hyper["noise_bound"]), float(hyper["residual_bound"]),
                              float(hyper["residual_noise_std"]), seed=seed * 1000 + i)

        return build

    return [make(fn, i) for i, fn in enumerate(fns)]


class _SpacesOnly(gym.Env):
    """The residual learner's env: only its spaces (SB3 builds its networks and buffer from them; never stepped)."""

    def __init__(self, observation_space: gym.spaces.Box, action_space: gym.spaces.Box) -> None:
        self.observation_space, self.action_space = observation_space, action_space

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[Any, dict[str, Any]]:
        raise RuntimeError("the residual learner is trained from the workers' transitions; it has no env")

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        raise RuntimeError("the residual learner is trained from the workers' transitions; it has no env")


def residual_spaces(skills: EgoSkills) -> tuple[gym.spaces.Box, gym.spaces.Box]:
    return residual_space(skills.obs_dim, skills.latent_dim), gym.spaces.Box(-1.0, 1.0, (2,), np.float32)


def build_residual_model(config: Mapping[str, Any], skills: EgoSkills, build: Callable[..., Any]) -> Any:
    """The residual TD3 learner (``build``: `seal.experiments.training.train.build_model`), its actor starting
    as the zero correction (`zero_output_layer`)."""
    hyper = dict(config["hyperparams"]["residual"])
    hyper["action_noise_std"] = 0.0  # exploration noise is added in the workers
    sub = {**config, "algo": "td3", "hyperparams": hyper, "seed": int(config["seed"]) + 1}
    model = build(sub, _SpacesOnly(*residual_spaces(skills)))
    zero_output_layer(model)
    return model


def zero_output_layer(model: Any) -> None:
    """Zero the last linear layer of a TD3 actor and its target, so the residual starts as no correction at all.

    Residual policy learning (Silver et al. 2018; ReSkill follows it) starts the residual at zero: a randomly
    initialised actor adds a fixed, state-dependent bias of up to ~0.3 x ``residual_bound`` the moment the gate
    opens, which measured as the residual *hurting* the skill policy (issue 17). With zero output weights the
    actor's gradient still reaches the last layer (its inputs are not zero), so it learns from the first update.
    """
    import torch

    for actor in (model.actor, model.actor_target):
        last = [m for m in actor.mu if isinstance(m, torch.nn.Linear)][-1]
        with torch.no_grad():
            last.weight.zero_()
            last.bias.zero_()


class EnvStepCounter(BaseCallback):
    """Makes the model's ``num_timesteps`` count env steps: SB3 adds one per env per vec-step (one skill);
    this adds the rest of each skill's ``info["env_steps"]``. Must run before every other callback."""

    def _on_step(self) -> bool:
        extra = sum(int(info.get("env_steps", 1)) - 1 for info in self.locals["infos"])
        self.model.num_timesteps += extra
        self.num_timesteps = self.model.num_timesteps
        return True


class ResidualTrainer(BaseCallback):
    """Trains the residual agent from the workers' transitions (module docstring)."""

    def __init__(self, residual: Any, config: Mapping[str, Any], logger: Any) -> None:
        super().__init__()
        self.residual, self.hyper = residual, config["hyperparams"]
        self.rh = self.hyper["residual"]
        self.residual.set_logger(logger)
        self.unused = 0
        """Residual transitions added since the last gradient steps were scheduled."""
        self.next_sync = 0
        self.gate = 0.0

    def gate_at(self, step: int) -> float:
        return residual_gate(step, int(self.hyper["residual_start"]), int(self.hyper["residual_ramp"]))

    def sync(self) -> None:
        """Copy the residual actor and the gate of the current step to every worker."""
        self.gate = self.gate_at(self.num_timesteps)
        self.training_env.env_method("set_residual", actor_mlp(self.residual), self.gate)
        self.next_sync = self.num_timesteps + int(self.hyper["residual_sync_every"])

    def _on_training_start(self) -> None:
        self.sync()

    def _on_step(self) -> bool:
        buffer = self.residual.replay_buffer
        for info in self.locals["infos"]:
            rows = info.get("residual")
            if rows is None:
                continue
            for i in range(len(rows["reward"])):
                buffer.add(rows["obs"][i:i + 1], rows["next_obs"][i:i + 1], rows["action"][i:i + 1],
                           rows["reward"][i:i + 1], rows["done"][i:i + 1],
                           [{"TimeLimit.truncated": bool(rows["truncated"][i])}])
            self.unused += len(rows["reward"])
        freq, grad = int(self.rh["train_freq"]), int(self.rh["gradient_steps"])
        if buffer.size() >= int(self.rh["learning_starts"]) and self.unused >= freq:
            steps = self.unused // freq * grad
            self.unused %= freq
            self._train(steps)
        if self.num_timesteps >= self.next_sync:
            self.sync()
            self.logger.record("residual/gate", self.gate)
            self.logger.record("residual/transitions", buffer.size())
        return True

    def _train(self, gradient_steps: int) -> None:
        def job() -> None:
            self.residual.train(gradient_steps=gradient_steps, batch_size=int(self.rh["batch_size"]))
            self.residual.logger.record("time/total_timesteps", self.num_timesteps)
            self.residual.logger.dump(self.num_timesteps)

        overlap = find_overlap_env(self.training_env)
        if overlap is None:
            job()
        else:
            overlap.defer(job)  # runs while the workers step the next skills


def policy_factory(config: Mapping[str, Any], residual: Any, skills: EgoSkills) -> Callable[[Any], ReSkillPolicy]:
    """For the training-time evaluation: the high-level model -> the deterministic ReSkill policy of now."""
    hyper = config["hyperparams"]

    def make(high: Any) -> ReSkillPolicy:
        gate = residual_gate(int(high.num_timesteps), int(hyper["residual_start"]), int(hyper["residual_ramp"]))
        return ReSkillPolicy(high, skills, actor_mlp(residual), gate, float(hyper["noise_bound"]),
                             float(hyper["residual_bound"]))

    return make


def load_reskill_policy(run: Path, config: Mapping[str, Any], high: Any, residual: Any, steps: int) -> ReSkillPolicy:
    """The ReSkill policy of a finished run (``steps``: its env steps, which fix the gate)."""
    hyper = config["hyperparams"]
    skills = load_skills(hyper)
    gate = residual_gate(int(steps), int(hyper["residual_start"]), int(hyper["residual_ramp"]))
    return ReSkillPolicy(high, skills, actor_mlp(residual), gate, float(hyper["noise_bound"]),
                         float(hyper["residual_bound"]))


class ReSkillRun:
    """What a ReSkill run adds to an SB3 run in `seal.experiments.training.train`: the residual learner, its
    callbacks, its checkpoint entries and final file, and the policy the evaluations play."""

    def __init__(self, config: Mapping[str, Any], out: Path | None, build: Callable[..., Any]) -> None:
        """``out``: the run folder (the residual's TensorBoard log goes to ``out/tb/residual``; None: no log)."""
        from stable_baselines3.common.logger import KVWriter, Logger, TensorBoardOutputFormat

        self.config = config
        self.skills = load_skills(config["hyperparams"])
        self.residual = build_residual_model(config, self.skills, build)
        formats: list[KVWriter] = [TensorBoardOutputFormat(str(out / "tb" / RESIDUAL))] if out is not None else []
        self.logger = Logger(folder=str(out) if out is not None else None, output_formats=formats)
        self.trainer = ResidualTrainer(self.residual, config, self.logger)

    def restore(self, checkpoint: Path, state: Mapping[str, Any]) -> None:
        from seal.experiments.training.state import load_extra_model

        load_extra_model(self.residual, checkpoint, RESIDUAL, state)

    def models(self) -> dict[str, Any]:
        return {RESIDUAL: self.residual}

    def callbacks(self) -> tuple[BaseCallback, BaseCallback]:
        """(the step counter: first of all callbacks; the residual trainer: after the episode statistics)."""
        return EnvStepCounter(), self.trainer

    def make_policy(self) -> Callable[[Any], ReSkillPolicy]:
        return policy_factory(self.config, self.residual, self.skills)

    def save_final(self, out: Path) -> None:
        import os

        from seal.experiments.training.state import SAVE_EXCLUDE

        tmp = out / f".tmp_{FINAL_RESIDUAL}"
        self.residual.save(tmp, exclude=SAVE_EXCLUDE)
        os.replace(tmp, out / FINAL_RESIDUAL)
