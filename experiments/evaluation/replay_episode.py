"""Play one evaluated episode again: any ego, any setting, the same seeds (`seal.experiments.evaluation.protocol`),
so the video of a scenario shows the episode the results store scored (``seal render --ego ... --generator ...``,
the report's failure videos).

An episode is fixed by the dataset, the split and the scenario's index in it, the ego, the generator with its
options and K, and the seed; without a generator it is the normal episode (logged adversary).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from seal.adversaries.base import K_ROLLOUTS
from seal.core.dataset import Dataset, load_split
from seal.core.errors import SealError
from seal.core.scenario import Scenario
from seal.envs.rollout import Rollout
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.protocol import build_generator, normal_episode, scored_pass
from seal.experiments.training.egos import Ego, make_ego

SPLIT_SEARCH = ("eval", "hard", "train")
"""Splits searched, in order, for a scenario when no split is given."""


@dataclass(frozen=True)
class EpisodeSpec:
    """One evaluated episode (module docstring).

    Attributes:
        dataset: dataset directory.
        scenario_id: the scenario.
        ego: anything `seal.experiments.training.egos.make_ego` takes (or an `Ego`).
        generator: generator name, None for the logged adversary.
        kwargs: the generator's constructor options (as recorded with the evaluation setting).
        k: perturbation passes; the last is played.
        seed: the evaluation's seed.
        split: the split the scenario was evaluated in (None: found with `find_split`).
        algo: SB3 algorithm of an ego model file that does not record it.
        env: `ScenarioEnv` config overrides.
        background: reactive background traffic of the setting (``idm`` / ``rapid``: ``normal-reactive`` and the
            ``-reactive`` generator settings), None for the replayed log.
        background_model: RAPID model file of ``background="rapid"``.
    """

    dataset: str
    scenario_id: str
    ego: Any = "heuristic"
    generator: str | None = None
    kwargs: Mapping[str, Any] = field(default_factory=dict)
    k: int = K_ROLLOUTS
    seed: int = 0
    split: str | None = None
    algo: str | None = None
    env: Mapping[str, Any] = field(default_factory=dict)
    background: str | None = None
    background_model: str | None = None

    @classmethod
    def of_setting(cls, setting: Mapping[str, Any], scenario_id: str, ego: Any, algo: str | None = None
                   ) -> EpisodeSpec:
        """The episode of ``scenario_id`` in an evaluation setting as the results store records it (its
        ``settings`` table row: dataset, split, generator, kwargs with the reactive background's ``background`` /
        ``background_model`` for the reactive settings, k, seed)."""
        kwargs = dict(setting.get("kwargs") or {})
        background, background_model = kwargs.pop("background", None), kwargs.pop("background_model", None)
        return cls(dataset=str(setting["dataset"]), scenario_id=scenario_id, ego=ego,
                   generator=setting.get("generator"), kwargs=kwargs, k=int(setting.get("k") or 1),
                   seed=int(setting.get("seed") or 0), split=setting.get("split"), algo=algo,
                   background=background, background_model=background_model)


class EpisodeSpecError(SealError):
    """The scenario, split, ego or generator of an episode to replay does not exist."""


def find_split(dataset: str | Path, scenario_id: str) -> str | None:
    """The first split of `SPLIT_SEARCH` (then any other) holding ``scenario_id``; None when the dataset has no
    splits (evaluations then use every scenario)."""
    splits = Dataset.open(dataset).splits
    if not any(splits.values()):
        return None
    for name in (*SPLIT_SEARCH, *sorted(set(splits) - set(SPLIT_SEARCH))):
        if scenario_id in (splits.get(name) or []):
            return name
    raise EpisodeSpecError(f"scenario {scenario_id!r} is in no split of {dataset}")


def play(spec: EpisodeSpec) -> tuple[Scenario, Rollout, Ego]:
    """The scenario, the played roll-out (the scored pass with a generator, else the normal episode) and the ego."""
    split = spec.split if spec.split is not None else find_split(spec.dataset, spec.scenario_id)
    scenarios = load_split(spec.dataset, split)
    index = next((i for i, s in enumerate(scenarios) if s.scenario_id == spec.scenario_id), None)
    if index is None:
        raise EpisodeSpecError(f"scenario {spec.scenario_id!r} is not in split {split!r} of {spec.dataset}")
    ego = make_ego(spec.ego, spec.algo) if isinstance(spec.ego, str) else spec.ego
    env_config, background_model = dict(spec.env), None
    if spec.background is not None:
        env_config["background"] = spec.background
        if spec.background == "rapid":
            from seal.models.rapid import load_rapid

            background_model = load_rapid(str(spec.background_model))
    env = ScenarioEnv(scenarios, config=env_config, background_model=background_model)
    try:
        scenario = scenarios[index]
        rollout = normal_episode(env, scenario, index, ego, spec.seed)
        if spec.generator:
            generator = build_generator(spec.generator, dict(spec.kwargs), {})
            rollout, _ = scored_pass(env, scenario, index, ego, generator, spec.k, spec.seed, rollout)
    finally:
        env.close()
    return scenario, rollout, ego


def render(spec: EpisodeSpec, out: str | Path, fps: int = 10) -> dict[str, Any]:
    """`play` the episode and write its top-down video (``.mp4`` / ``.gif``); the caption names the generator
    (or "log") and the ego. Returns ``{"path", "scenario_id", "outcome", "route_completion", "frames"}``."""
    from seal.envs.render import render_rollout, write_video

    if Path(out).suffix.lower() not in (".mp4", ".gif"):
        raise EpisodeSpecError(f"--out must end in .mp4 or .gif, got {Path(out).name!r}")
    scenario, rollout, ego = play(spec)
    label = f"{spec.generator} (pass {spec.k} of {spec.k})" if spec.generator else "log"
    frames = render_rollout(rollout, scenario.road, scenario, adversary_label=label,
                            ego_label=Path(str(getattr(ego, "name", spec.ego))).name)
    path = write_video(frames, out, fps)
    return {"path": str(path), "scenario_id": scenario.scenario_id, "outcome": rollout.outcome,
            "route_completion": rollout.route_completion, "frames": len(frames)}
