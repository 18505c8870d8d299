"""Egos for evaluation episodes: the heuristic reactive driver, the logged ego replayed open loop, an SB3 model
(a seal run folder, a checkpoint or any SB3 ``.zip``, loaded safely by `seal.experiments.training.sb3_load`), a
Python policy (`register_policy`: a callable ``obs -> action`` or an object with SB3's ``predict``) or an
installed package's ``seal.egos`` entry point (`seal.core.plugins`).

An `Ego` is reset with the scenario of each episode and then maps (observation, scenario step) to a normalised
action ``[steering, acceleration]``. An ego whose ``deadline_obs`` is True (a trained ego whose observation space
says it learned with `seal.envs.deadline`) gets the deadline slots appended to each observation by the episode
loop (`seal.experiments.evaluation.episodes.run_episode`).
"""

from __future__ import annotations

import inspect
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np

from seal.core.errors import SealError
from seal.core.scenario import CURRENT_STEP, Scenario
from seal.envs.deadline import needs_deadline
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import recover_actions
from seal.experiments.training.numpy_actor import deterministic_actor
from seal.experiments.training.sb3_load import (
    MODEL_FILES,
    find_model,
    find_vecnormalize,
    load_sb3_model,
    read_vecnormalize,
    resolve_algo,
)

__all__ = ["MODEL_FILES", "Ego", "as_ego", "load_sb3_model", "make_ego", "register_policy"]

EGO_NAMES = ("heuristic", "replay")


class EgoError(SealError, ValueError):
    """An ego specification names nothing that can drive."""


class Ego(Protocol):
    name: str

    def reset(self, scenario: Scenario) -> None: ...

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        """Normalised ``[steering, acceleration]`` moving the ego from scenario step ``step`` to ``step + 1``."""
        ...


class HeuristicEgo:
    """The reactive rule-based driver (`seal.envs.heuristic.HeuristicDriver`)."""

    name = "heuristic"

    def __init__(self, **driver_kwargs: Any) -> None:
        self.driver = HeuristicDriver(**driver_kwargs)

    def reset(self, scenario: Scenario) -> None:
        pass

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        return self.driver.act(np.asarray(observation, dtype=np.float64))


class ReplayEgo:
    """The logged ego, replayed open loop: the actions `recover_actions` finds for its logged track (it does not
    react to anything; after the log ends it holds speed and heading)."""

    name = "replay"

    def __init__(self) -> None:
        self._actions = np.zeros((0, 2))

    def reset(self, scenario: Scenario) -> None:
        self._actions = recover_actions(scenario.track(scenario.ego_id), start_step=CURRENT_STEP)

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        return self._actions[step] if step < len(self._actions) else np.zeros(2)


class PolicyEgo:
    """A policy with SB3's ``predict`` (a loaded SB3 model, `HeuristicDriver`, any object of the same interface):
    deterministic actions; a recurrent policy's state is carried through the episode. ``normalize`` (VecNormalize
    statistics saved with an SB3 model) is applied to each observation first. ``numpy_actor``: act through a numpy
    copy of a TD3 / DDPG actor (`seal.experiments.training.numpy_actor.deterministic_actor`; same actions to float32
    rounding, ~10x cheaper a step) where the model has one; only for a model whose weights no longer change."""

    def __init__(self, model: Any, name: str, normalize: Callable[[np.ndarray], np.ndarray] | None = None,
                 numpy_actor: bool = False) -> None:
        self.model = model
        self.name = name
        self.normalize = normalize
        self._fast = deterministic_actor(model) if numpy_actor else None
        params = inspect.signature(model.predict).parameters
        varkw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
        self._kwargs = [k for k in ("state", "episode_start", "deterministic") if varkw or k in params]
        self._state: Any = None
        self.deadline_obs = needs_deadline(getattr(model, "observation_space", None))
        """Trained on the deadline observation (`seal.envs.deadline`): its episodes append those slots."""

    def reset(self, scenario: Scenario) -> None:
        self._state = None

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        obs = np.asarray(observation, dtype=np.float32)
        if self.normalize is not None:
            obs = self.normalize(obs).astype(np.float32)
        if self._fast is not None:
            return np.asarray(self._fast(obs), dtype=np.float64).reshape(-1)
        given = {"state": self._state, "episode_start": np.array([step == 0]), "deterministic": True}
        action, self._state = self.model.predict(obs, **{k: given[k] for k in self._kwargs})
        return np.asarray(action, dtype=np.float64).reshape(-1)


class CallableEgo:
    """A plain function (or callable object) ``observation [100] -> action [2]``."""

    def __init__(self, policy: Callable[[np.ndarray], Any], name: str) -> None:
        self.policy = policy
        self.name = name

    def reset(self, scenario: Scenario) -> None:
        reset = getattr(self.policy, "reset", None)
        if callable(reset):
            reset()

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        return np.asarray(self.policy(np.asarray(observation, dtype=np.float32)), dtype=np.float64).reshape(-1)


def as_ego(policy: Any, name: str) -> Ego:
    """Adapt a Python policy to `Ego`: an `Ego` itself (``reset(scenario)`` and ``act(obs, step)``), an object with
    SB3's ``predict(obs, state, episode_start, deterministic)`` (`PolicyEgo`), or a callable ``obs -> action``
    (`CallableEgo`). Actions are normalised ``[steering, acceleration]`` in ``[-1, 1]``."""
    act = getattr(policy, "act", None)
    if callable(act) and callable(getattr(policy, "reset", None)) and _positional(act) >= 2:
        if not getattr(policy, "name", None):
            policy.name = name
        return cast(Ego, policy)
    if callable(getattr(policy, "predict", None)):
        return PolicyEgo(policy, name)
    if callable(policy):
        return CallableEgo(policy, name)
    raise EgoError(f"ego {name!r}: {type(policy).__name__} is not a policy (give a callable obs -> action, an "
                   "object with SB3's predict(obs), or one with reset(scenario) and act(obs, step))")


def _positional(fn: Callable[..., Any]) -> int:
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):
        return 0
    kinds = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    return sum(p.kind in kinds for p in params)


_PYTHON_EGOS: dict[str, Any] = {}


def register_policy(name: str, policy: Any) -> None:
    """Make the Python ``policy`` (anything `as_ego` accepts) available as ego ``name`` in this process (what
    `seal.experiments.evaluation.policies.evaluate_policy` evaluates)."""
    if name in EGO_NAMES:
        raise EgoError(f"ego name {name!r} is a built-in ego; choose another")
    as_ego(policy, name)  # refuse a non-policy now, not in the first episode
    _PYTHON_EGOS[name] = policy


def python_ego_names() -> list[str]:
    """Egos registered from Python (`register_policy`)."""
    return sorted(_PYTHON_EGOS)


def plugin_ego(name: str) -> Any | None:
    """The policy of installed entry point ``seal.egos:name`` (its factory called with no arguments), or None."""
    from seal.core.plugins import EGO_GROUP, load_entry_point

    factory = load_entry_point(EGO_GROUP, name)
    if factory is None:
        return None
    if not callable(factory):
        raise EgoError(f"entry point {EGO_GROUP}:{name} is not callable: it must name a factory returning a policy")
    return factory()


class ReSkillEgo:
    """A trained ReSkill ego (`seal.experiments.training.reskill_policy.ReSkillPolicy`): a skill from the
    high-level agent every H steps, decoded each step and corrected by the residual agent."""

    def __init__(self, policy: Any, name: str) -> None:
        self.policy = policy
        self.name = name
        self.deadline_obs = needs_deadline(getattr(policy.high, "observation_space", None))
        """Its high-level agent was trained on the deadline observation (`seal.envs.deadline`)."""

    def reset(self, scenario: Scenario) -> None:
        self.policy.reset()

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        return np.asarray(self.policy.act(observation), dtype=np.float64)


def make_ego(spec: str, algo: str | None = None) -> Ego:
    """``"heuristic"``, ``"replay"``, a policy registered from Python (`register_policy`), an installed
    ``seal.egos`` entry point, or the path of an SB3 model: a seal run folder, its final model or a checkpoint,
    or any SB3 ``.zip`` (``algo``: td3 | sac | ppo | ..., default: the run config's or the file's own; VecNormalize
    statistics beside it are applied). A ReSkill run folder gives a `ReSkillEgo`."""
    if spec == "heuristic":
        return HeuristicEgo()
    if spec == "replay":
        return ReplayEgo()
    if spec in _PYTHON_EGOS:
        return as_ego(_PYTHON_EGOS[spec], spec)
    path = Path(spec)
    if not path.exists():
        from seal.core.plugins import load_env_plugins

        load_env_plugins()
        plugin = plugin_ego(spec)
        if plugin is not None:
            return as_ego(plugin, spec)
        raise EgoError(
            f"--ego {spec!r}: not 'heuristic', 'replay', an installed seal.egos entry point or an existing run "
            "folder / SB3 model .zip"
        )
    model = find_model(path)
    if resolve_algo(model, algo) == "RESKILL":
        return ReSkillEgo(load_reskill(path), name=str(path))
    vecnormalize = find_vecnormalize(model)
    normalize = read_vecnormalize(vecnormalize) if vecnormalize is not None else None
    return PolicyEgo(load_sb3_model(path, algo_name=algo), name=str(path), normalize=normalize, numpy_actor=True)


def load_reskill(path: Path) -> Any:
    """The `ReSkillPolicy` of a ``seal train --algo reskill`` run: its folder or final model file (the finished
    run: ``final_residual.zip`` beside it), or a checkpoint's ``model.zip`` (``RUN/checkpoints/step_N/``: the
    residual saved with it, the gate at step N)."""
    from seal.experiments.training.reskill import (
        FINAL_RESIDUAL,
        RESIDUAL,
        high_level,
        load_reskill_policy,
        load_skills,
        residual_spaces,
    )
    from seal.experiments.training.sb3_load import find_run_config

    model_path = find_model(Path(path))
    found = find_run_config(model_path)
    if found is None:
        raise EgoError(f"{model_path}: a ReSkill model needs its run's config.yaml (in the run folder above it)")
    run, config = found[0].parent, found[1]
    state = model_path.parent / "state.json"
    checkpoint = model_path.parent != run and state.is_file()
    residual_path = model_path.parent / (f"{RESIDUAL}.zip" if checkpoint else FINAL_RESIDUAL)
    if not residual_path.is_file():
        raise EgoError(f"ReSkill {'checkpoint' if checkpoint else 'run'} {model_path.parent}: no "
                       f"{residual_path.name} (is the {'checkpoint complete' if checkpoint else 'run finished'}?)")
    skills = load_skills(config["hyperparams"])
    from gymnasium import spaces

    high = load_sb3_model(model_path, algo_name=high_level(config["hyperparams"])[0].upper(),
                          action_space=spaces.Box(-1.0, 1.0, (skills.latent_dim,), np.float32))
    res_obs, res_act = residual_spaces(skills)
    residual = load_sb3_model(residual_path, algo_name="TD3", observation_space=res_obs, action_space=res_act)
    done = run / "done.json"
    if checkpoint:
        steps = json.loads(state.read_text())["step"]
    else:
        steps = json.loads(done.read_text())["steps"] if done.is_file() else int(config["total_timesteps"])
    return load_reskill_policy(run, config, high, residual, int(steps))
