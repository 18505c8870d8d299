"""``seal eval runs``: the ego evaluation protocol (thesis 6.4), results into the results store.

Each ego (a trained run folder, plus the Replay ego by default) is evaluated on the requested settings:

* ``normal``: the dataset's ``eval`` split (Normal scenarios), logged (replayed) adversary, one episode.
* ``hard``: the ``hard`` split, replayed adversary.
* ``normal-reactive``: ``normal`` with reactive background traffic (config ``background``: ``idm``, or ``rapid``
  with ``background_model``; `ScenarioEnv`'s ``background`` option): compared with ``normal`` it shows how many of
  an ego's crashes the replayed (non-reacting) background caused.
* ``<generator>`` (``cat``, ``goose``, ``seal``, ``rule``, ... any registered generator): "X-Gen", the Normal
  eval scenarios perturbed by that generator. Per scenario one normal episode, then K sequential perturbation
  passes against the same ego, each roll-out appended to the scenario's queue; the last pass is scored
  (`seal.experiments.evaluation.protocol`, the same episodes as ``seal eval generators`` and the report's videos).
  The normal episode is shared with the ``normal`` setting and every generator setting (egos are deterministic).
* ``<generator>-reactive`` (``cat-reactive``, ...): the same with the reactive background of ``normal-reactive``
  (the normal episode of the queue too): how many of an ego's crashes under the generator the replayed background
  caused (an ego that brakes for the adversary is run into by a logged car that does not).
* ``real:DIR``: an imported dataset (``seal data import ...``): its ``eval`` split if it has one, else every
  scenario; replayed adversary.

Every scored episode becomes one results-store row keyed by (run, dataset, setting, scenario); scenarios already
in the store are skipped, so evaluations are incremental and an interrupted evaluation resumes. Rows of one
scenario are written in one transaction. Generators are rebuilt for every ego (some keep per-scenario state).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from seal.adversaries.base import K_ROLLOUTS, available_generators
from seal.core.config import ConfigError, apply_overrides, build, check_keys, defaults_of, safe_load_file
from seal.experiments.evaluation.results_store import ResultsStore

REPLAY_SETTINGS = ("normal", "hard", "normal-reactive")
REACTIVE_SETTING = "normal-reactive"
REACTIVE_SUFFIX = "-reactive"
"""``<generator>-reactive``: a generator setting with the reactive background of ``normal-reactive``."""
REACTIVE_BACKGROUNDS = ("idm", "rapid")
REAL_PREFIX = "real:"
BUILTIN_EGOS = ("replay", "heuristic")

@dataclass(frozen=True)
class EvalRunsConfig:
    """Settings of ``seal eval runs`` (YAML keys of ``--config``, or a ``seal run`` preset's ``eval:`` section)."""

    generators: dict[str, dict[str, Any]] = field(default_factory=dict)
    """Generator name -> constructor kwargs, e.g. ``goose: {model: F}``."""
    prior: str | None = None
    """Trajectory prior file handed to every generator whose constructor takes one."""
    candidates: str | None = None
    """Built-in candidate source instead of a prior (lanes | constant_velocity), handed on likewise."""
    k: int = K_ROLLOUTS
    """Perturbation passes per scenario; the last is scored."""
    limit: int | None = None
    """Use the first N scenarios of each split (None: all)."""
    seed: int = 0
    """Episode / generator rng seed, the same for every ego."""
    env: dict[str, Any] = field(default_factory=dict)
    """`ScenarioEnv` config overrides."""
    background: str = "idm"
    """Background traffic of the ``normal-reactive`` setting: ``idm`` or ``rapid`` (needs ``background_model``)."""
    background_model: str | None = None
    """RAPID model file (`seal fit background`) of ``background: rapid``."""

    def __post_init__(self) -> None:
        if self.k < 1:
            raise ConfigError(f"k must be >= 1, got {self.k}")
        if self.background not in REACTIVE_BACKGROUNDS:
            raise ConfigError(f"background must be one of {list(REACTIVE_BACKGROUNDS)}, got {self.background!r}")
        if self.background == "rapid" and not self.background_model:
            raise ConfigError("background: rapid needs background_model (a seal fit background model file)")


DEFAULTS: dict[str, Any] = defaults_of(EvalRunsConfig)
"""The defaults of `EvalRunsConfig` as plain data."""


@dataclass(frozen=True)
class Setting:
    """One evaluation setting.

    Attributes:
        name: ``normal``, ``hard``, a generator name or ``real:<absolute dataset dir>``.
        dataset: absolute dataset directory its scenarios come from.
        split: dataset split, or None for every scenario.
        generator: generator name for X-Gen settings, None for replayed-adversary settings.
        reactive: the background traffic reacts (``normal-reactive``) instead of replaying its log.
    """

    name: str
    dataset: str
    split: str | None
    generator: str | None = None
    reactive: bool = False

    @property
    def kind(self) -> str:
        return "generator" if self.generator else "replay"


def parse_settings(spec: str | Sequence[str], dataset: str | Path | None) -> list[Setting]:
    """Settings from ``normal,hard,cat,goose,seal,real:DIR`` (text or list); ``dataset`` serves every setting
    but ``real:DIR``. Errors name the unknown setting and list the valid ones."""
    from seal.core.dataset import Dataset

    names = [s.strip() for s in spec.split(",")] if isinstance(spec, str) else [str(s).strip() for s in spec]
    names = [n for n in names if n]
    if not names:
        raise ValueError("--settings: no setting given (e.g. normal,hard,cat)")
    base = str(Path(dataset).resolve()) if dataset is not None else None
    settings: list[Setting] = []
    for name in dict.fromkeys(names):
        if name.startswith(REAL_PREFIX):
            root = Path(name[len(REAL_PREFIX):]).expanduser().resolve()
            ds = Dataset.open(root)  # fails with a message naming the directory
            split = "eval" if ds.splits.get("eval") else None
            settings.append(Setting(f"{REAL_PREFIX}{root}", str(root), split))
            continue
        if base is None:
            raise ValueError(
                f"--settings {name}: needs a dataset (--dataset DIR, or runs whose config.yaml names one)"
            )
        if name in REPLAY_SETTINGS:
            split = "hard" if name == "hard" else "eval"
            settings.append(Setting(name, base, split, reactive=name == REACTIVE_SETTING))
        elif name in available_generators():
            settings.append(Setting(name, base, "eval", generator=name))
        elif name.endswith(REACTIVE_SUFFIX) and name[: -len(REACTIVE_SUFFIX)] in available_generators():
            settings.append(Setting(name, base, "eval", generator=name[: -len(REACTIVE_SUFFIX)], reactive=True))
        else:
            raise ValueError(
                f"--settings: unknown setting {name!r}; use normal, hard, normal-reactive, real:DIR, a generator "
                f"name ({', '.join(available_generators())}) or GENERATOR-reactive (reactive background)"
            )
    return settings


def resolve_eval_config(
    config_file: str | Path | None = None, run_configs: Sequence[Mapping[str, Any]] = (), sets: Sequence[str] = (),
    **overrides: Any,
) -> dict[str, Any]:
    """Defaults < generator kwargs of the runs' own configs (``generator: {name, kwargs}``, first run per name) <
    the YAML ``config_file`` (keys `DEFAULTS`; a preset's ``eval:`` section is also accepted) < ``overrides``
    (None ignored) < ``sets`` (``key.sub=value``). The same resolved config serves every ego, so their settings are
    comparable."""
    config: dict[str, Any] = {**DEFAULTS, "generators": {}, "env": {}}
    for rc in run_configs:
        gen = rc.get("generator") or {}
        name = gen.get("name") if isinstance(gen, Mapping) else None
        if name and name not in config["generators"]:
            config["generators"][name] = dict(gen.get("kwargs") or {})
    if config_file is not None:
        path = Path(config_file)
        loaded = safe_load_file(path) or {}
        if not isinstance(loaded, dict):
            raise ValueError(f"{path}: expected a mapping of eval options")
        if isinstance(loaded.get("eval"), dict):  # a `seal run` preset: use its eval section
            loaded = {k: v for k, v in loaded["eval"].items() if k in DEFAULTS}
        check_keys(EvalRunsConfig, loaded, str(path))
        gens = loaded.pop("generators", None) or {}
        if not isinstance(gens, Mapping):
            raise ValueError(f"{path}: 'generators' must map generator names to constructor kwargs")
        for name, kwargs in gens.items():
            config["generators"][str(name)] = {**config["generators"].get(str(name), {}), **dict(kwargs or {})}
        config.update(loaded)
    config.update({k: v for k, v in overrides.items() if v is not None})
    if sets:
        config = apply_overrides(config, sets)
        check_keys(EvalRunsConfig, config, "--set")
    build(EvalRunsConfig, config, str(config_file or "eval options"))  # types and ranges
    return config


# ---------------------------------------------------------------------------------------------------- egos
@dataclass(frozen=True)
class EgoSpec:
    """An ego to evaluate: ``run`` is the results-store key (absolute run folder or model file, or an ego name);
    ``pipeline`` groups egos as seeds in the report (an ego without a recorded pipeline gets a label of its own,
    so unrelated models are never taken for seeds of one); ``algo`` the SB3 algorithm of a model file (None: the
    file's or its run config's own)."""

    run: str
    pipeline: str
    seed: int
    path: str | None
    config: dict[str, Any]
    algo: str | None = None

    @property
    def ego(self) -> str:
        return self.path or self.run


def read_run(run: str | Path, algo: str | None = None) -> EgoSpec:
    """A built-in ego (``replay``, ``heuristic``), a Python policy (`seal.experiments.training.egos.
    register_policy`), an installed ``seal.egos`` entry point, a trained run folder (``config.yaml`` with
    ``pipeline`` / ``seed`` / ``algo``, and a model), a checkpoint of one (``RUN/checkpoints/step_N/model.zip``:
    pipeline ``<pipeline>@step_N``) or any SB3 model ``.zip`` (``algo`` if the file does not say)."""
    from seal.core.plugins import EGO_GROUP, entry_point_names
    from seal.experiments.training.egos import python_ego_names

    text = str(run)
    if text in BUILTIN_EGOS or text in python_ego_names():
        return EgoSpec(text, text, 0, None, {})
    path = Path(run).expanduser().resolve()
    if not path.exists():
        if text in entry_point_names(EGO_GROUP):
            return EgoSpec(text, text, 0, None, {})
        raise FileNotFoundError(
            f"{run}: not 'replay', 'heuristic', a registered Python policy, an installed seal.egos entry point, a "
            "run folder (seal train) or an SB3 model .zip"
        )
    if path.is_dir() and (path / "config.yaml").is_file():
        return _run_folder(path, algo)
    return _model_file(path, algo)


def _run_folder(path: Path, algo: str | None) -> EgoSpec:
    cfg_path = path / "config.yaml"
    cfg = yaml.safe_load(cfg_path.read_text()) or {}
    if not isinstance(cfg, dict):
        raise ValueError(f"{cfg_path}: expected a mapping")
    pipeline = str(cfg.get("pipeline") or path.name)  # no pipeline: the run is its own group
    if cfg.get("plugins"):  # trained against a --plugin generator: import it again (seal.core.plugins)
        from seal.core.plugins import load_plugins

        load_plugins([str(p) for p in cfg["plugins"]])
    return EgoSpec(str(path), pipeline, int(cfg.get("seed") or 0), str(path), cfg, algo)


def _model_file(path: Path, algo: str | None) -> EgoSpec:
    """An SB3 model file (or a folder holding one without a run config): the final model of a seal run folder is
    that run; a checkpoint or any other model is an ego of its own."""
    from seal.experiments.training.sb3_load import find_model, find_run_config, resolve_algo

    model = find_model(path)
    found = find_run_config(model)
    if found is not None and found[0].parent == model.parent and model.name != "best_model.zip":
        return _run_folder(model.parent, algo)
    cfg = dict(found[1]) if found is not None else {}
    if found is not None and cfg.get("pipeline"):
        # a checkpoint (or a run's best model): not a seed of the final models
        at = model.stem if model.parent == found[0].parent else model.parent.name
        pipeline = f"{cfg['pipeline']}@{at}"
    else:
        pipeline = f"{model.parent.name}/{model.stem}"
    algo = (algo or resolve_algo(model)).lower()
    cfg.update(algo=algo, model=str(model))
    return EgoSpec(str(model), pipeline, int(cfg.get("seed") or 0), str(model), cfg, algo)


def _base_row(ego: EgoSpec, setting: Setting, scenario_id: str, k: int) -> dict[str, Any]:
    return {
        "run": ego.run, "dataset": setting.dataset, "setting": setting.name, "scenario_id": scenario_id,
        "pipeline": ego.pipeline, "seed": ego.seed, "ego": ego.ego, "split": setting.split, "k": k,
    }


WorkItem = tuple[str, "str | None", int, list[str]]
"""One scenario of an ego's evaluation still to play: (dataset, split, index in the split, names of the settings
missing for it). Settings sharing the (dataset, split) share the scenario's normal episode."""


def plan_ego(store: ResultsStore, ego: EgoSpec, settings: Sequence[Setting], config: Mapping[str, Any],
             split_ids: dict[tuple[str, str | None, int | None], list[str]] | None = None) -> list[WorkItem]:
    """Record the ego and the settings in ``store`` and list the scenarios still to play (in split order), each
    with the settings it is missing (scenarios already in the store are skipped). ``split_ids``: a cache of each
    split's scenario ids shared by the plans of several egos (a split is read from the dataset's shards, all of
    them: ~3 s for a 10,000-scene pool, which planning 30 egos x 2 splits paid 60 times)."""
    from seal.core.dataset import load_split

    k, seed = int(config["k"]), int(config["seed"])
    shared = {"prior": config.get("prior"), "candidates": config.get("candidates")}
    records = []
    for s in settings:
        kwargs = dict(config["generators"].get(s.generator, {})) if s.generator else {}
        if s.reactive:
            kwargs = {**kwargs, "background": config.get("background", "idm"),
                      "background_model": config.get("background_model")}
        record = (s.dataset, s.name, s.kind, s.split, s.generator, {**_shared_for(s, shared), **kwargs},
                  k if s.generator else 0, seed)
        if differences := store.setting_differences(*record):
            raise ValueError(f"results store {store.path}: setting {s.name!r} holds episodes played with other "
                             f"settings (differs in {', '.join(differences)}; see its settings table); evaluate "
                             "into another --store, or with the recorded options")
        records.append(record)
    store.upsert_run(ego.run, ego.pipeline, ego.seed, ego.ego, ego.path, ego.config)
    for record in records:
        store.upsert_setting(*record)
    groups: dict[tuple[str, str | None], list[Setting]] = {}
    for s in settings:
        groups.setdefault((s.dataset, s.split), []).append(s)
    todo: list[WorkItem] = []
    cache = {} if split_ids is None else split_ids
    for (dataset, split), members in groups.items():
        key = (dataset, split, config.get("limit"))
        if key not in cache:
            cache[key] = [sc.scenario_id for sc in load_split(dataset, split, config.get("limit"))]
        done = {s.name: store.done_scenarios(ego.run, s.dataset, s.name) for s in members}
        for i, scenario_id in enumerate(cache[key]):
            missing = [s.name for s in members if scenario_id not in done[s.name]]
            if missing:
                todo.append((dataset, split, i, missing))
    return todo


def written_key(setting: Setting, settings: Sequence[Setting]) -> str:
    """The key of ``setting`` in the rows-written counts: its name, or ``name@dataset`` where another of
    ``settings`` has the same name on another dataset (``seal run``'s held-out pools)."""
    clash = any(o.name == setting.name and o.dataset != setting.dataset for o in settings)
    return f"{setting.name}@{setting.dataset}" if clash else setting.name


def play_items(
    store: ResultsStore, ego: EgoSpec, settings: Sequence[Setting], config: Mapping[str, Any],
    items: Sequence[WorkItem], on_scenario: Any = None,
) -> dict[str, int]:
    """Play the scenarios ``items`` (`plan_ego`) for ``ego`` and write one row per missing setting, one transaction
    per scenario (an interrupted evaluation resumes there); returns the rows written per setting.
    ``on_scenario(n_rows)`` is called after each scenario (progress).

    The ego, the generators (one per ego and setting), the splits and the envs come from this process's session
    cache (`seal.experiments.evaluation.worker_cache`), so the chunks of one ego that a worker plays reuse them."""
    from seal.experiments.evaluation import protocol
    from seal.experiments.evaluation.generator_metrics import LoggedAdversary
    from seal.experiments.evaluation.metrics import episode_metrics
    from seal.experiments.evaluation.worker_cache import cached_ego, cached_env, cached_generator, cached_split

    k, seed = int(config["k"]), int(config["seed"])
    # A setting is its dataset and its name: `seal run`'s held-out pools repeat every name on another dataset.
    by_key = {(s.dataset, s.name): s for s in settings}
    keys = {(s.dataset, s.name): written_key(s, settings) for s in settings}
    written = dict.fromkeys(keys.values(), 0)
    if not items:
        return written
    policy = cached_ego(ego.ego, ego.algo)
    for dataset, split, i, missing in items:
        scenarios = cached_split(dataset, split, config.get("limit"))
        env, scenario = cached_env(dataset, split, config), scenarios[i]
        logged = LoggedAdversary.of(scenario)
        normal = protocol.normal_episode(env, scenario, i, policy, seed)
        reactive_env: Any = None
        reactive_normal: Any = None
        rows = []
        for name in missing:
            s = by_key[(dataset, name)]
            row = _base_row(ego, s, scenario.scenario_id, k if s.generator else 0)
            if s.reactive and reactive_normal is None:  # shared by normal-reactive and the -reactive settings
                reactive_env = cached_env(dataset, split, config, reactive=True)
                reactive_normal = protocol.normal_episode(reactive_env, scenario, i, policy, seed)
            if s.generator is None:
                row.update(episode_metrics(scenario, reactive_normal if s.reactive else normal, (), logged))
            else:
                # A generator of its own per setting: some keep per-scenario state across the K passes.
                generator = cached_generator(ego.run, s.generator, config, setting=f"{s.dataset}:{s.name}")
                rollout, times = protocol.scored_pass(reactive_env if s.reactive else env, scenario, i, policy,
                                                      generator, k, seed, reactive_normal if s.reactive else normal)
                row.update(episode_metrics(scenario, rollout, times, logged))
            rows.append(row)
            written[keys[(dataset, name)]] += 1
        store.upsert_episodes(rows)
        if on_scenario is not None:
            on_scenario(len(rows))
    return written


def evaluate_ego(
    store: ResultsStore, ego: EgoSpec, settings: Sequence[Setting], config: Mapping[str, Any],
    progress: bool = True,
) -> dict[str, int]:
    """Evaluate one ego on ``settings`` (module docstring) in this process, skipping scenarios already in
    ``store``; returns the number of episode rows written per setting."""
    import uuid

    from tqdm import tqdm

    from seal.experiments.evaluation.worker_cache import use_session

    use_session(uuid.uuid4().hex)  # a fresh ego, generators and envs, as before the session caches
    items = plan_ego(store, ego, settings, config)
    total = sum(len(m) for *_, m in items)
    with tqdm(total=total, desc=f"eval {Path(ego.run).name}", unit="episode", disable=not progress or not total
              ) as bar:
        return play_items(store, ego, settings, config, items, on_scenario=bar.update)


def _shared_for(setting: Setting, shared: Mapping[str, Any]) -> dict[str, Any]:
    """The shared options the setting's generator constructor accepts (recorded with the setting)."""
    if not setting.generator:
        return {}
    import inspect

    from seal.adversaries.base import generator_class

    params = inspect.signature(generator_class(setting.generator)).parameters
    return {k: v for k, v in shared.items() if v is not None and k in params}


def default_dataset(egos: Sequence[EgoSpec]) -> str | None:
    """The dataset the first trained run was trained on (its config's ``dataset``), if any."""
    for ego in egos:
        ds = ego.config.get("dataset")
        if ds:
            return str(ds)
    return None


def evaluate_job(job: Mapping[str, Any]) -> dict[str, Any]:
    """One ego's evaluation as a picklable job for `seal.experiments.backends` (keys: ``store``, ``run``,
    ``settings`` (list of `Setting` fields), ``config``, ``progress``)."""
    from seal.core.workers import torch_threads

    torch_threads(1)  # without importing torch where the ego and generators need none
    ego = read_run(job["run"], job.get("algo"))
    settings = [Setting(**s) for s in job["settings"]]
    with ResultsStore(job["store"]) as store:
        written = evaluate_ego(store, ego, settings, job["config"], progress=bool(job.get("progress", False)))
    return {"run": ego.run, "written": written}


def check_generator_config(name: str, config: Mapping[str, Any]) -> None:
    """Build the generator once up front, so a missing model file fails before any episode runs."""
    from seal.experiments.evaluation.protocol import build_generator

    shared = {"prior": config.get("prior"), "candidates": config.get("candidates")}
    try:
        build_generator(name, config["generators"].get(name, {}), shared)
    except (TypeError, ValueError, FileNotFoundError) as exc:
        raise ValueError(
            f"setting {name!r}: cannot build generator {name!r} ({exc}); give its options with --config YAML "
            f"(generators: {{{name}: {{...}}}}), --gen-opt {name}.KEY=VALUE, --prior or --candidates"
        ) from None
