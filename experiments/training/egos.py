"""Egos for evaluation episodes: the heuristic reactive driver, the logged ego replayed open loop, or a trained
SB3 policy from a run folder.

An `Ego` is reset with the scenario of each episode and then maps (observation, scenario step) to a normalised
action ``[steering, acceleration]``.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import yaml

from seal.core.scenario import CURRENT_STEP, Scenario
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import recover_actions

EGO_NAMES = ("heuristic", "replay")
MODEL_FILES = ("model.zip", "final_model.zip", "best_model.zip")
CONFIG_FILES = ("config.yaml", "config.yml")


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
    """A trained SB3 policy (deterministic actions)."""

    def __init__(self, model: Any, name: str) -> None:
        self.model = model
        self.name = name

    def reset(self, scenario: Scenario) -> None:
        pass

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        action, _ = self.model.predict(np.asarray(observation, dtype=np.float32), deterministic=True)
        return np.asarray(action, dtype=np.float64).reshape(-1)


class ReSkillEgo:
    """A trained ReSkill ego (`seal.experiments.training.reskill_policy.ReSkillPolicy`): a skill from the
    high-level agent every H steps, decoded each step and corrected by the residual agent."""

    def __init__(self, policy: Any, name: str) -> None:
        self.policy = policy
        self.name = name

    def reset(self, scenario: Scenario) -> None:
        self.policy.reset()

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        return np.asarray(self.policy.act(observation), dtype=np.float64)


def make_ego(spec: str) -> Ego:
    """``"heuristic"``, ``"replay"`` or the path of a trained run (a folder or its model ``.zip``; a ReSkill run
    folder gives a `ReSkillEgo`)."""
    if spec == "heuristic":
        return HeuristicEgo()
    if spec == "replay":
        return ReplayEgo()
    path = Path(spec)
    if not path.exists():
        raise FileNotFoundError(
            f"--ego {spec!r}: not 'heuristic', 'replay' or an existing run folder / SB3 model .zip"
        )
    if _find_algo(_find_model(path)) == "RESKILL":
        return ReSkillEgo(load_reskill(path), name=str(path))
    return PolicyEgo(load_sb3_model(path), name=str(path))


def load_reskill(path: Path) -> Any:
    """The `ReSkillPolicy` of a finished ``seal train --algo reskill`` run folder (or its final model file)."""
    from seal.experiments.training.reskill import FINAL_RESIDUAL, load_reskill_policy, load_skills, residual_spaces

    model_path = _find_model(Path(path))
    run = model_path.parent
    config = yaml.safe_load((run / "config.yaml").read_text()) or {}
    residual_path = run / FINAL_RESIDUAL
    if not residual_path.is_file():
        raise FileNotFoundError(f"ReSkill run {run}: no {FINAL_RESIDUAL} (is the run finished?)")
    skills = load_skills(config["hyperparams"])
    from gymnasium import spaces

    high = load_sb3_model(model_path, algo_name="TD3",
                          action_space=spaces.Box(-1.0, 1.0, (skills.latent_dim,), np.float32))
    res_obs, res_act = residual_spaces(skills)
    residual = load_sb3_model(residual_path, algo_name="TD3", observation_space=res_obs, action_space=res_act)
    done = run / "done.json"
    steps = json.loads(done.read_text())["steps"] if done.is_file() else int(config["total_timesteps"])
    return load_reskill_policy(run, config, high, residual, int(steps))


def _find_model(path: Path) -> Path:
    if path.is_file():
        return path
    for name in MODEL_FILES:
        if (path / name).is_file():
            return path / name
    raise FileNotFoundError(f"run folder {path} has none of {', '.join(MODEL_FILES)}")


def _find_algo(model: Path) -> str:
    for folder in (model.parent, model.parent.parent):
        for name in CONFIG_FILES:
            cfg_path = folder / name
            if cfg_path.is_file():
                cfg = yaml.safe_load(cfg_path.read_text()) or {}
                algo = cfg.get("algo") or cfg.get("algorithm") if isinstance(cfg, dict) else None
                if algo:
                    return str(algo).upper()
                raise ValueError(f"{cfg_path}: no 'algo' (e.g. td3, sac, ppo) to load {model} with")
    raise FileNotFoundError(
        f"no {' / '.join(CONFIG_FILES)} with the algorithm name next to {model}: pass a `seal train` run folder "
        "(it writes one), or put a config.yaml with 'algo: td3|sac|ppo' beside the model to load it"
    )


def load_sb3_model(path: Path, algo_name: str | None = None, observation_space: Any = None,
                   action_space: Any = None) -> Any:
    """Load an SB3 model for inference without unpickling anything: every cloudpickled entry of the model's
    ``data`` is replaced by a known-safe object (the env's spaces, the algorithm's ``MlpPolicy``, SB3's buffer
    classes, constant schedules; an unknown pickled entry is an error); parameters are read by SB3 with
    ``torch.load(weights_only=True)``. ``algo_name`` (default: the run config's) and the spaces (default: the
    ego's observation and ``[steering, acceleration]``) are for models of other shapes (the ReSkill agents)."""
    import stable_baselines3 as sb3
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer, RolloutBuffer

    from seal.envs.observation import observation_space as default_observation_space

    obs_space = observation_space
    model_path = _find_model(Path(path))
    algo_name = algo_name or _find_algo(model_path)
    algo = getattr(sb3, algo_name, None)
    if algo is None:
        raise ValueError(f"{model_path}: unknown SB3 algorithm {algo_name!r} in its config")
    with zipfile.ZipFile(model_path) as zf:
        data = json.loads(zf.read("data"))
    safe: dict[str, Any] = {
        "observation_space": obs_space if obs_space is not None else default_observation_space(),
        "action_space": action_space if action_space is not None else spaces.Box(-1.0, 1.0, shape=(2,),
                                                                                  dtype=np.float32),
        "policy_class": algo.policy_aliases["MlpPolicy"],
        "rollout_buffer_class": RolloutBuffer,
        "replay_buffer_class": ReplayBuffer,
        "train_freq": (1, "step"),
    }
    # Inference only: a 1-transition replay buffer instead of allocating the training-size one.
    custom: dict[str, Any] = {"buffer_size": 1} if "buffer_size" in data else {}
    for key, value in data.items():
        if not (isinstance(value, dict) and ":serialized:" in value):
            continue
        if key in safe:
            custom[key] = safe[key]
        elif key.endswith("schedule") or key in ("learning_rate", "clip_range", "clip_range_vf"):
            custom[key] = _constant_zero
        else:
            raise ValueError(
                f"{model_path}: entry {key!r} is pickled and cannot be loaded safely; save runs with "
                "JSON-serialisable settings"
            )
    return algo.load(model_path, device="cpu", custom_objects=custom)


def _constant_zero(_progress: float) -> float:
    return 0.0
