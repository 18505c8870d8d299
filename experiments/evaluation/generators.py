"""``seal eval generators``: compare adversary generators against one ego with the X-Gen protocol.

For every scenario of the split: one normal episode (logged adversary), then for each generator K sequential
perturbation passes against the same ego, each pass's roll-out appended to that generator's queue for the
scenario (queues start as K copies of the logged ego future, then the normal episode is appended); the last pass
is scored. The normal episode is played once and shared by the generators (egos are deterministic). Seeds and
rng streams are `seal.experiments.evaluation.protocol`'s, so a (scenario, ego, generator, seed) plays the same
episode here as in ``seal eval runs`` and the report's videos. Output in
``out``: ``config.yaml`` (the resolved config), ``generators.csv`` / ``generators.md`` / ``generators.json``
(one row per generator, `seal.experiments.evaluation.generator_metrics`) and ``episodes.csv`` (one row per scenario and
generator).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from seal.adversaries.base import K_ROLLOUTS, AdversaryGenerator, available_generators
from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.config import ConfigError, build, check_keys, defaults_of, safe_load_file
from seal.core.dataset import load_split
from seal.core.scenario import Scenario
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.generator_metrics import EpisodeRecord, LoggedAdversary, markdown_table, summarize
from seal.experiments.evaluation.protocol import build_generator, generator_name, generator_passes, normal_episode
from seal.experiments.training.egos import make_ego


@dataclass(frozen=True)
class EvalGeneratorsConfig:
    """Settings of ``seal eval generators`` (YAML keys of ``--config``; command-line options override them)."""

    generators: Any = field(default_factory=lambda: ["replay", "rule", "cat"])
    """Generator names (a list or comma-separated text), or a mapping name -> constructor kwargs."""
    ego: str = "replay"
    """The ego: ``heuristic``, ``replay`` or a run folder / model path."""
    algo: str | None = None
    """SB3 algorithm of an ``ego`` model file that does not record it (td3 | sac | ppo | ...)."""
    split: str | None = "eval"
    """Dataset split (None: every scenario)."""
    limit: int | None = None
    """Use the first N scenarios of the split (after ``offset``; None: all)."""
    offset: int = 0
    """Skip the first N scenarios of the split (a held-out slice: scenario i keeps its index, so its episodes are
    the ones a run over the whole split plays)."""
    k: int = K_ROLLOUTS
    """Perturbation passes per scenario (the length of the roll-out queue); the last is scored."""
    seed: int = 0
    """Episode and generator rng seed."""
    prior: str | None = None
    """Trajectory prior file handed to every generator that takes one."""
    candidates: str | None = None
    """Built-in candidate source instead of a prior (lanes | constant_velocity), handed on likewise."""
    objective: str | None = None
    """SEAL's learned objective file, or ``cat``, handed to every generator that takes one."""
    skills: str | None = None
    """SEAL's skill model folder, handed on likewise."""
    env: dict[str, Any] = field(default_factory=dict)
    """`ScenarioEnv` config overrides."""

    def __post_init__(self) -> None:
        if self.k < 1:
            raise ConfigError(f"k must be >= 1, got {self.k}")
        if self.offset < 0:
            raise ConfigError(f"offset must be >= 0, got {self.offset}")


DEFAULTS: dict[str, Any] = defaults_of(EvalGeneratorsConfig)
"""The defaults of `EvalGeneratorsConfig` as plain data."""

SHARED_OPTIONS = ("prior", "candidates", "objective", "skills")
"""Options passed to every generator whose constructor has a parameter of that name."""


def _names(spec: str | Sequence[str]) -> list[str]:
    """Generator names or labels from comma-separated text or a list."""
    parts = spec.split(",") if isinstance(spec, str) else [str(n) for n in spec]
    return [n.strip() for n in parts if n.strip()]


def parse_generators(spec: str | Sequence[str] | Mapping[str, Any]) -> dict[str, dict[str, Any]]:
    """Generator names (comma-separated text, a list, or a mapping name -> kwargs) checked against the
    registry; unknown names raise an error listing the available ones.

    In a mapping, an entry may name its generator with a ``generator`` key, so one generator can be compared in
    several configurations under labels of its own (e.g. ``seal_benign: {generator: seal, switch: benign}``)."""
    parsed = {str(k): dict(v or {}) for k, v in spec.items()} if isinstance(spec, Mapping) else {
        name: {} for name in _names(spec)
    }
    if not parsed:
        raise ValueError("--generators: no generator given")
    unknown = [f"{name} (generator: {generator_name(name, kw)})" if "generator" in kw else name
               for name, kw in parsed.items() if generator_name(name, kw) not in available_generators()]
    if unknown:
        raise ValueError(
            f"--generators: unknown generator(s) {', '.join(unknown)}; available: {', '.join(available_generators())}"
        )
    return parsed


def apply_generator_options(generators: dict[str, dict[str, Any]], options: Sequence[str]) -> None:
    """Apply ``NAME.KEY=VALUE`` options (VALUE read as YAML: numbers, booleans, strings) to ``generators``."""
    for option in options:
        target, sep, text = option.partition("=")
        name, dot, key = target.partition(".")
        if not (sep and dot and name and key):
            raise ValueError(f"--gen-opt {option!r}: expected NAME.KEY=VALUE, e.g. goose.model=agent.pt")
        if name not in generators:
            raise ValueError(f"--gen-opt {option!r}: generator {name!r} is not among {', '.join(generators)}")
        generators[name][key] = yaml.safe_load(text)


def resolve_config(
    config_file: str | Path | None = None, gen_opts: Sequence[str] = (), **overrides: Any
) -> dict[str, Any]:
    """Defaults < YAML config file < explicit overrides (None values are ignored) < ``gen_opts``
    (`apply_generator_options`); generators normalised to a mapping name -> constructor kwargs. Names given as an
    override (``--generators``) that label entries of the file's ``generators`` mapping take those entries, so
    ``--generators cat,seal_traj_only`` picks two configurations out of an ablation file."""
    config = dict(DEFAULTS)
    if config_file is not None:
        path = Path(config_file)
        loaded = safe_load_file(path) or {}
        if not isinstance(loaded, dict):
            raise ValueError(f"{path}: expected a mapping of options")
        check_keys(EvalGeneratorsConfig, loaded, str(path))
        config.update(loaded)
    picked = overrides.get("generators")
    if isinstance(picked, str | list | tuple) and isinstance(config.get("generators"), Mapping):
        entries = config["generators"]
        overrides = {**overrides, "generators": {n: dict(entries.get(n) or {}) for n in _names(picked)}}
    config.update({k: v for k, v in overrides.items() if v is not None})
    build(EvalGeneratorsConfig, config, str(config_file or "eval generators options"))  # types and ranges
    config["generators"] = parse_generators(config["generators"])
    apply_generator_options(config["generators"], gen_opts)
    return config


def evaluate_generators(
    scenarios: Sequence[Scenario], generators: Mapping[str, AdversaryGenerator], ego_spec: str, k: int = K_ROLLOUTS,
    seed: int = 0, env_config: Mapping[str, Any] | None = None, progress: bool = True, algo: str | None = None,
    first_index: int = 0,
) -> tuple[list[dict[str, Any]], list[EpisodeRecord]]:
    """Run the protocol (module docstring); returns the summary rows (one per generator) and the episode records.
    ``ego_spec``: anything `seal.experiments.training.egos.make_ego` takes (``algo`` for a model file).
    ``first_index``: the split index of ``scenarios[0]`` (its episode seeds and generator streams follow it)."""
    from tqdm import tqdm

    env = ScenarioEnv(list(scenarios), config=dict(env_config or {}))
    ego = make_ego(ego_spec, algo)
    records: dict[str, list[EpisodeRecord]] = {name: [] for name in generators}
    logged: list[LoggedAdversary] = []
    bar = tqdm(scenarios, desc="scenarios", unit="scenario", disable=not progress)
    for i, scenario in enumerate(bar, start=first_index):
        normal = normal_episode(env, scenario, i, ego, seed)
        logged.append(LoggedAdversary.of(scenario))
        for name, generator in generators.items():
            passes = generator_passes(env, scenario, i, ego, generator, k, seed, normal)
            last = passes[-1]
            records[name].append(
                EpisodeRecord.from_rollout(
                    scenario, name, last.rollout, [p.generation.generation_time_s for p in passes],
                    predicted_step=last.generation.predicted_step,
                    chosen_candidate=last.generation.chosen_candidate,
                    extra=last.generation.extra,
                )
            )
    env.close()
    rows = [summarize(records[name], logged) for name in generators]
    return rows, [r for name in generators for r in records[name]]


def _csv(rows: Sequence[dict[str, Any]]) -> bytes:
    buf = io.StringIO()
    fields = list(dict.fromkeys(key for row in rows for key in row))  # union, in order of first appearance
    writer = csv.DictWriter(buf, fieldnames=fields, restval="")
    writer.writeheader()
    writer.writerows(rows)
    return buf.getvalue().encode()


def jsonable(value: Any) -> Any:
    """Plain JSON / YAML data: numpy scalars as Python numbers, non-finite floats as None, tuples as lists."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    return value


def split_slice(dataset: str | Path, split: str | None, limit: int | None, offset: int) -> list[Scenario]:
    """Scenarios ``offset .. offset + limit`` of ``split`` (all after ``offset`` when ``limit`` is None); an error
    naming ``--offset`` when nothing is left."""
    if not offset:
        return load_split(dataset, split, limit)
    scenarios = load_split(dataset, split)[offset:]
    if not scenarios:
        raise ValueError(f"--offset {offset}: the split {split or 'all'} of {dataset} has no scenario after the first "
                         f"{offset}")
    return scenarios if limit is None else scenarios[:limit]


def run_eval_generators(
    dataset: str | Path, out: str | Path, config: dict[str, Any], progress: bool = True
) -> list[dict[str, Any]]:
    """Evaluate the configured generators on ``dataset`` and write the results into ``out``; returns the rows."""
    out = Path(out)
    offset = int(config.get("offset") or 0)
    scenarios = split_slice(dataset, config["split"], config["limit"], offset)
    shared = {key: config.get(key) for key in SHARED_OPTIONS}
    generators = {name: build_generator(name, kw, shared) for name, kw in config["generators"].items()}
    resolved = {**config, "dataset": str(dataset), "scenarios": len(scenarios)}
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(jsonable(resolved), sort_keys=True).encode())
    rows, records = evaluate_generators(
        scenarios, generators, config["ego"], k=int(config["k"]), seed=int(config["seed"]),
        env_config=config["env"], progress=progress, algo=config.get("algo"), first_index=offset,
    )
    table = markdown_table(rows)
    atomic_write_bytes(out / "generators.csv", _csv(rows))
    atomic_write_json(out / "generators.json", jsonable({"config": resolved, "rows": rows}))
    atomic_write_bytes(out / "episodes.csv", _csv([r.row() for r in records]))
    header = (
        f"# Generator evaluation\n\nDataset `{dataset}`, split `{config['split']}`, {len(scenarios)} scenarios, "
        f"ego `{config['ego']}`, K = {config['k']} perturbation passes (the last is scored).\n\n"
    )
    atomic_write_bytes(out / "generators.md", (header + table).encode())
    return rows
