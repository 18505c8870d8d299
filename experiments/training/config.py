"""Configuration of ``seal train``: the ``train:`` section of a preset YAML (``experiments/configs/<preset>.yaml``)
as the frozen dataclass `EgoTrainConfig`, resolved for one pipeline and seed.

Resolution (`seal.core.config.load_config`): `EgoTrainConfig` defaults < the file's ``train:`` section < options
(dotted keys, e.g. ``{"pipeline": "cat", "seed": 1, "hyperparams.td3.learning_starts": 500}``) < ``--set KEY=VALUE``.
The resolved config (`resolve`; what a run folder's ``config.yaml`` records) is a plain mapping that keeps the chosen
algorithm's hyper-parameters only and the pipeline's generator as ``generator: {name, kwargs}`` (``name`` None for
``noadv``). Other top-level sections of a preset file (``data``, ``fit``, ``eval``, ``pipelines``, ``seeds``) belong
to the orchestrator and are not read here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from seal.adversaries.base import GENERATORS, NO_ADVERSARY, model_file_options, pipeline_names
from seal.core.config import ConfigError, coerce, load_config, read_yaml, to_dict
from seal.experiments.training.zoo import check_algo_settings, check_schedule, parse_policy_kwargs

ALGOS = ("td3", "sac", "ppo", "reskill")
PIPELINES = pipeline_names()
"""``noadv`` and every generator the registry marks as a training pipeline (`seal.adversaries.base.GENERATORS`)."""


_POSITIVE = (lambda v: v > 0, "> 0")
_AT_LEAST_1 = (lambda v: v >= 1, ">= 1")
_NON_NEGATIVE = (lambda v: v >= 0, ">= 0")
_UNIT = (lambda v: 0 < v <= 1, "in (0, 1]")
_RATE = (lambda v: check_schedule(v), "> 0, or an rl-zoo schedule lin_<start> with start > 0")


def _check_ranges(config: Any, rules: dict[str, tuple[Callable[[Any], bool], str]]) -> None:
    """Refuse out-of-range values when the config is built, before any run folder exists (None = unset)."""
    for name, (ok, allowed) in rules.items():
        value = getattr(config, name)
        if value is not None and not ok(value):
            raise ConfigError(f"{type(config).__name__}.{name} must be {allowed}, got {value!r}")


@dataclass(frozen=True)
class OffPolicyHyperparams:
    """SB3 settings shared by the off-policy algorithms (``train_freq`` in vec-env steps, each ``n_envs`` env
    steps)."""

    learning_rate: float | str = 3e-4
    """Adam learning rate, or an rl-zoo schedule ``lin_<start>`` (linear from start to 0 over the run)."""
    gamma: float = 0.99
    """Discount factor."""
    tau: float = 0.005
    """Polyak averaging coefficient of the target networks."""
    batch_size: int = 256
    """Transitions per gradient step."""
    learning_starts: int = 10_000
    """Env steps of random actions before learning."""
    buffer_size: int = 1_000_000
    """Replay buffer capacity (transitions)."""
    net_arch: tuple[int, ...] = (256, 256)
    """Hidden layer widths of actor and critics."""
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    """Other SB3 ``policy_kwargs`` (``activation_fn`` by name: ReLU, Tanh, ...; ``log_std_init``, ``n_critics``,
    ...); a ``net_arch`` here replaces the one above."""
    train_freq: int = 1
    """Vec-env steps between training calls."""
    gradient_steps: int = -1
    """Gradient steps per training call (-1: as many as env steps collected, one per env step as in CAT)."""

    def __post_init__(self) -> None:
        _check_ranges(self, {
            "learning_rate": _RATE, "gamma": _UNIT, "tau": _UNIT, "batch_size": _AT_LEAST_1,
            "learning_starts": _NON_NEGATIVE, "buffer_size": _AT_LEAST_1, "train_freq": _AT_LEAST_1,
            "gradient_steps": (lambda v: v >= 1 or v == -1, ">= 1 or -1"),
        })


@dataclass(frozen=True)
class TD3Hyperparams(OffPolicyHyperparams):
    """SB3 TD3 settings."""

    policy_delay: int = 2
    """Critic updates per actor update."""
    action_noise_std: float = 0.1
    """Gaussian exploration noise (0 = none)."""

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_ranges(self, {"policy_delay": _AT_LEAST_1, "action_noise_std": _NON_NEGATIVE})


@dataclass(frozen=True)
class SACHyperparams(OffPolicyHyperparams):
    """SB3 SAC settings."""

    ent_coef: str | float = "auto"
    """Entropy coefficient (``"auto"``: learned)."""


@dataclass(frozen=True)
class PPOHyperparams:
    """SB3 PPO settings."""

    learning_rate: float | str = 3e-4
    """Adam learning rate, or an rl-zoo schedule ``lin_<start>``."""
    gamma: float = 0.99
    """Discount factor."""
    n_steps: int = 1024
    """Roll-out length per env between updates."""
    batch_size: int = 256
    """Mini-batch size."""
    n_epochs: int = 10
    """Epochs over each roll-out."""
    gae_lambda: float = 0.95
    """GAE lambda."""
    clip_range: float | str = 0.2
    """Policy ratio clip, or an rl-zoo schedule ``lin_<start>``."""
    ent_coef: float = 0.0
    """Entropy bonus weight."""

    def __post_init__(self) -> None:
        _check_ranges(self, {
            "learning_rate": _RATE, "gamma": _UNIT, "n_steps": _AT_LEAST_1, "batch_size": _AT_LEAST_1,
            "n_epochs": _AT_LEAST_1, "gae_lambda": _UNIT, "clip_range": _RATE, "ent_coef": _NON_NEGATIVE,
        })
    net_arch: tuple[int, ...] = (256, 256)
    """Hidden layer widths of policy and value networks."""
    policy_kwargs: dict[str, Any] = field(default_factory=dict)
    """Other SB3 ``policy_kwargs`` (``activation_fn`` by name, ``ortho_init``, ``log_std_init``, a ``net_arch``
    mapping ``{pi: [...], vf: [...]}`` replacing the one above, ...)."""


def _high_level_td3() -> TD3Hyperparams:
    # One transition per skill (H = 10 env steps): gamma 0.9 ~ 0.99^10 keeps the low-level TD3's horizon in
    # seconds; one gradient step per decision (train_freq 1 vec-step of 2 decisions, 2 steps); learning_starts in
    # env steps, as for every algorithm; wider exploration noise in the prior's noise space.
    return TD3Hyperparams(gamma=0.9, learning_starts=5_000, buffer_size=100_000, train_freq=1, gradient_steps=2,
                          action_noise_std=0.2)


def _high_level_sac() -> SACHyperparams:
    # The same decision-level schedule as the high-level TD3 (gamma, buffer, one gradient step per decision). The
    # entropy coefficient starts at 0.1, not SB3's 1: a decision earns ~10 reward (decisive preset: ~70 an episode of
    # ~7 skills) against the 8-dimensional policy's ~7 nats of entropy, so at 1 the bonus would drown the reward for
    # most of a 100k-step run (~10k gradient steps for the learned coefficient to come down).
    return SACHyperparams(gamma=0.9, learning_starts=5_000, buffer_size=100_000, train_freq=1, gradient_steps=2,
                          ent_coef="auto_0.1")


HIGH_ALGOS = ("td3", "sac")
"""Learners of the ReSkill ego's high-level agent (``hyperparams.reskill.high_algo``)."""


def _residual_td3() -> TD3Hyperparams:
    # learning_starts counts residual transitions (collected once the gate opens); train_freq / gradient_steps:
    # one gradient step per 4 residual transitions, the low-level TD3 preset's ratio. Exploration noise is added
    # in the env workers (``residual_noise_std``), not by SB3.
    return TD3Hyperparams(learning_starts=2_000, buffer_size=100_000, train_freq=4, gradient_steps=1,
                          action_noise_std=0.0)


@dataclass(frozen=True)
class ReSkillHyperparams:
    """The ReSkill ego (``algo: reskill``; `seal.experiments.training.reskill`): a high-level agent whose action
    is the benign prior's noise, one decision per skill horizon, and a residual TD3 agent adding a bounded
    correction to each decoded action, both trained on the env reward."""

    skills: Path | None = None
    """Skills folder (``seal fit skills``: ``vae.pt``, ``prior_benign.pt``) the ego draws its skills from."""
    noise_bound: float = 1.0
    """Prior noise per unit of high-level action (actions in [-1, 1] reach +-1 standard deviation of the prior's
    base Gaussian). 1 rather than 2: TD3's tanh actor sits at the box edges early on, and +-2 sigma skills are the
    prior's rare ones (standard preset, noadv, seed 0: 0.64 / 0.52 / 0.54 Normal-eval success at 10k / 20k / 30k
    env steps with 1.0 against 0.41 / 0.43 / 0.46 with 2.0)."""
    residual_bound: float = 0.2
    """Largest residual per action dimension (normalised action units) once the gate is fully open."""
    residual_start: int = 30_000
    """Env steps before the residual gate opens (the high-level agent first learns to use the skills alone)."""
    residual_ramp: int = 20_000
    """Env steps over which the gate rises linearly from 0 to 1 (0: at once)."""
    residual_noise_std: float = 0.1
    """Gaussian exploration noise on the residual action (in its [-1, 1] units), added in the env workers."""
    residual_sync_every: int = 200
    """Env steps between copies of the residual actor's weights to the env workers."""
    high_algo: str = "td3"
    """Learner of the high-level agent: ``td3`` (settings ``high``) or ``sac`` (settings ``high_sac``). TD3's
    deterministic tanh actor saturates on this problem: of the 28 decisive ReSkill egos (session 33) 3 took one and
    the same corner of the action box in every state and 6 more nearly so, and they scored like the others. SAC's
    entropy term (with the tanh squashing's log-density correction) keeps its policy off the corners."""
    high: TD3Hyperparams = field(default_factory=_high_level_td3)
    """High-level TD3 (transitions are skills; ``learning_starts`` in env steps)."""
    high_sac: SACHyperparams = field(default_factory=_high_level_sac)
    """High-level SAC, when ``high_algo`` is ``sac`` (same units as ``high``)."""
    residual: TD3Hyperparams = field(default_factory=_residual_td3)
    """Residual TD3 (``train_freq``: residual transitions per ``gradient_steps`` gradient steps)."""

    def __post_init__(self) -> None:
        _check_ranges(self, {
            "noise_bound": _POSITIVE, "residual_bound": _NON_NEGATIVE, "residual_start": _NON_NEGATIVE,
            "residual_ramp": _NON_NEGATIVE, "residual_noise_std": _NON_NEGATIVE, "residual_sync_every": _AT_LEAST_1,
        })
        if self.high_algo not in HIGH_ALGOS:
            raise ConfigError(f"ReSkillHyperparams.high_algo must be one of {HIGH_ALGOS}, got {self.high_algo!r}")


@dataclass(frozen=True)
class Hyperparams:
    """Settings of each algorithm (the run uses ``algo``'s)."""

    td3: TD3Hyperparams = field(default_factory=TD3Hyperparams)
    """TD3 settings."""
    sac: SACHyperparams = field(default_factory=SACHyperparams)
    """SAC settings."""
    ppo: PPOHyperparams = field(default_factory=PPOHyperparams)
    """PPO settings."""
    reskill: ReSkillHyperparams = field(default_factory=ReSkillHyperparams)
    """ReSkill ego settings."""


@dataclass(frozen=True)
class Curriculum:
    """CAT's perturbation probability p(t) = min(slope (t / T - warmup), cap), 0 before warmup T."""

    slope: float = 1.8
    """Growth of p over the run (per fraction of total_timesteps)."""
    cap: float = 0.9
    """Largest p."""
    warmup: float = 0.0
    """Share of the run with p = 0 before the ramp starts (SEAL's non-reactive start), in [0, 1)."""


@dataclass(frozen=True)
class PipelineSpec:
    """What a pipeline trains against: a registered generator and its constructor options."""

    name: str
    """Generator name (`seal.adversaries.base.GENERATORS`)."""
    kwargs: dict[str, Any] = field(default_factory=dict)
    """Constructor options; model-file options (prior, GOOSE model, objective, skills) are paths filled in by the
    preset, the command line or ``seal run``."""


def default_pipelines() -> dict[str, PipelineSpec | None]:
    """``noadv: None`` and, per pipeline generator, its model-file options unset."""
    pipelines: dict[str, PipelineSpec | None] = {NO_ADVERSARY: None}
    for name in PIPELINES[1:]:
        pipelines[name] = PipelineSpec(name, {opt: None for opt in GENERATORS[name].model_files()})
    return pipelines


@dataclass(frozen=True)
class EgoTrainConfig:
    """The ``train:`` section of a preset: everything ``seal train`` needs besides the run folder."""

    algo: str = "td3"
    """Ego algorithm: td3 | sac | ppo (SB3) | reskill (skill prior + residual; high level TD3 or SAC)."""
    pipeline: str = "cat"
    """Adversary pipeline: one of ``pipelines`` (noadv | goose | cat | seal)."""
    seed: int = 0
    """Random seed of the run."""
    total_timesteps: int = 1_000_000
    """Env steps of the run (a multiple of n_envs; PPO: of n_envs * n_steps)."""
    dataset: Path | None = None
    """Dataset directory."""
    train_split: str | None = "train"
    """Split of the training scenarios."""
    train_limit: int | None = None
    """Use the first N training scenarios (None: all)."""
    eval_split: str | None = "eval"
    """Split of the Normal evaluation."""
    n_envs: int | None = None
    """Env worker processes (None: the machine's cores)."""
    k: int = 5
    """Roll-out queue length per scenario."""
    curriculum: Curriculum = field(default_factory=Curriculum)
    """Perturbation probability schedule."""
    revisit_prob: float = 0.0
    """Probability that a worker's next episode replays the scenario of its last one, in [0, 1)
    (`seal.adversaries.closed_loop.ClosedLoopEnv`): the generator then targets the ego's roll-out just played, as
    in the evaluation's K passes, instead of the logged ego of a scenario not played before. 0: every episode
    draws its scenario afresh."""
    env: dict[str, Any] = field(default_factory=lambda: {"terminate_on_crash": False})
    """`ScenarioEnv` config overrides for training (CAT: episodes go on after a crash)."""
    eval_env: dict[str, Any] = field(default_factory=lambda: {"terminate_on_crash": True})
    """`ScenarioEnv` config overrides for evaluation (a crash ends the episode)."""
    deadline_obs: bool = False
    """Time-aware ego (`seal.envs.deadline`): the time left and the speed needed to arrive in time appended to its
    observation, and the time limit a terminal state instead of a bootstrapped truncation; evaluations give the
    ego the same slots."""
    eval_every: int = 50_000
    """Env steps between evaluations (0 = never)."""
    eval_episodes: int = 100
    """Evaluation scenarios (the first N of the split, one deterministic episode each)."""
    checkpoint_every: int = 50_000
    """Env steps between checkpoints (model, replay buffer, queues, rng)."""
    torch_threads: int = 1
    """Torch threads of the learner."""
    overlap_updates: bool = True
    """Off-policy: run each training call's gradient updates while the env workers step the next transitions
    (`seal.experiments.training.overlap`; same number of updates, sampled one vec-step earlier)."""
    device: str = "cpu"
    """Torch device of the learner."""
    hyperparams: Hyperparams = field(default_factory=Hyperparams)
    """Per-algorithm settings."""
    pipelines: dict[str, PipelineSpec | None] = field(default_factory=default_pipelines)
    """Pipeline name -> generator (None for noadv). An entry naming its generator replaces the old one whole; one
    without ``name`` (``pipelines.cat.kwargs.prior``) patches it."""

    def __post_init__(self) -> None:
        _check_ranges(self, {
            "total_timesteps": _AT_LEAST_1, "train_limit": _AT_LEAST_1, "n_envs": _AT_LEAST_1, "k": _AT_LEAST_1,
            "eval_every": _NON_NEGATIVE, "eval_episodes": _NON_NEGATIVE, "checkpoint_every": _NON_NEGATIVE,
            "torch_threads": _AT_LEAST_1,
        })


RESOLVED_ONLY = ("generator", "preset", "hyperparams")
ADDED_LATER: dict[str, Any] = {"overlap_updates": False, "deadline_obs": False}
"""Fields a run folder recorded before they existed may lack, with the value that reproduces those runs."""

PRESETS = ("quick", "standard", "paper", "decisive")
DEFAULT_PRESET = "standard"


def preset_path(name_or_path: str | Path) -> Path:
    """A preset name (quick | standard | paper | decisive) -> ``experiments/configs/<name>.yaml`` of the installed
    package; anything else is taken as a path."""
    from seal.experiments.presets import CONFIG_DIR

    text = str(name_or_path)
    return CONFIG_DIR / f"{text}.yaml" if text in PRESETS else Path(text)


RUN_CONFIG_FILE = "config.yaml"
"""The resolved config a run folder records (`resolve`'s output); `seal train --config` takes it back."""
_RUN_CONFIG_KEYS = frozenset({"algo", "pipeline", "generator", "hyperparams"})


def config_file(name_or_path: str | Path) -> Path:
    """`preset_path`, with a run folder meaning its recorded ``config.yaml``."""
    path = preset_path(name_or_path)
    return path / RUN_CONFIG_FILE if path.is_dir() else path


def is_run_config(loaded: Mapping[str, Any]) -> bool:
    """Whether a loaded YAML mapping is a run folder's resolved config (no ``train:`` section; flat hyperparameters
    of one algorithm and the pipeline's generator)."""
    return "train" not in loaded and set(loaded) >= _RUN_CONFIG_KEYS


def train_section_of_run(run_config: Mapping[str, Any]) -> dict[str, Any]:
    """A run's resolved config as a ``train:`` section that resolves to the same run: the hyperparameters go under
    the run's algorithm, its generator becomes the definition of its pipeline, the recorded preset name is dropped
    (``--set`` and the command-line options then change what they change in any preset)."""
    section = {k: v for k, v in run_config.items() if k not in ("generator", "preset")}
    section["hyperparams"] = {str(run_config["algo"]).lower(): run_config["hyperparams"]}
    generator = run_config.get("generator") or {}
    spec = None if generator.get("name") is None else {"name": generator["name"],
                                                        "kwargs": dict(generator.get("kwargs") or {})}
    section["pipelines"] = {str(run_config["pipeline"]): spec}
    return section


def _read_config(path: str | Path) -> tuple[Path, dict[str, Any]]:
    """(file, its YAML) of a preset name, a preset file, a run folder or a run's ``config.yaml``; a clear error for a
    missing file."""
    file = config_file(path)
    if not file.is_file():
        raise FileNotFoundError(
            f"--config {file}: no such file (presets: experiments/configs/quick|standard|paper|decisive.yaml, or a "
            "run folder)"
        )
    return file, read_yaml(file)


def _train_section(file: Path, loaded: Mapping[str, Any]) -> dict[str, Any]:
    """The ``train:`` mapping of a loaded file, or a loaded run config as one (`train_section_of_run`)."""
    if is_run_config(loaded):
        return train_section_of_run(loaded)
    if not isinstance(loaded.get("train"), dict):
        raise ConfigError(f"{file}: no 'train:' section (a mapping of the fields of "
                          f"seal.experiments.training.config.EgoTrainConfig)")
    return dict(loaded["train"])


def read_train_section(path: str | Path) -> dict[str, Any]:
    """The ``train:`` mapping of the YAML file ``path`` (a preset name or a path; keys checked when loaded), or of a
    run folder / its ``config.yaml`` (`train_section_of_run`)."""
    return _train_section(*_read_config(path))


def _load_with_preset(path: str | Path, overrides: Mapping[str, Any] | None, sets: Sequence[str]
                      ) -> tuple[EgoTrainConfig, str]:
    """`load_ego_train_config` and the ``preset`` name its run records: the preset file's stem, or the preset a
    given run recorded."""
    file, loaded = _read_config(path)
    section = _train_section(file, loaded)  # a clear error for a missing section
    if is_run_config(loaded):
        config = load_config(EgoTrainConfig, file=section, values=overrides, overrides=sets)
        return config, str(loaded.get("preset") or file.parent.name)
    return load_config(EgoTrainConfig, file=file, section="train", values=overrides, overrides=sets), file.stem


def load_ego_train_config(path: str | Path, overrides: Mapping[str, Any] | None = None,
                          sets: Sequence[str] = ()) -> EgoTrainConfig:
    """The `EgoTrainConfig` of the preset file ``path`` (or a preset name, or a run folder / its recorded
    ``config.yaml``) with ``overrides`` (dotted keys; None values ignored) and ``sets`` (``"key.sub=value"``) on
    top."""
    return _load_with_preset(path, overrides, sets)[0]


def load_train_config(path: str | Path, overrides: Mapping[str, Any] | None = None,
                      sets: Sequence[str] = ()) -> dict[str, Any]:
    """The resolved run config (`resolve`) of the preset file ``path`` (or a preset name, `preset_path`; its
    ``train:`` section; or a run folder, which then trains again as recorded), ``overrides`` (dotted keys; None
    values ignored) and ``sets`` (``--set`` strings). ``preset`` is the file's stem (a run folder's: the one it
    recorded)."""
    config, preset = _load_with_preset(path, overrides, sets)
    # A --set for another algorithm would be dropped by `resolve` (files keep every algorithm's section: presets do).
    check_algo_settings(config.algo.lower(), [s.partition("=")[0].strip() for s in sets], "--set")
    return resolve(config, preset=preset)


def _generator(config: EgoTrainConfig) -> dict[str, Any]:
    """The run's ``generator: {name, kwargs}``: the pipeline the config defines, else a generator of that name (a
    built-in, a ``--plugin`` or an installed ``seal.generators`` entry point) with its default options."""
    from seal.adversaries.base import available_generators

    if config.pipeline in config.pipelines:
        spec = config.pipelines[config.pipeline]
    elif config.pipeline in available_generators():
        spec = PipelineSpec(config.pipeline, {})
    else:
        raise ConfigError(f"--pipeline must be one of {sorted(config.pipelines)} (train.pipelines) or a generator "
                          f"name ({', '.join(available_generators())}), got {config.pipeline!r}")
    if spec is None:
        return {"name": None, "kwargs": {}}
    kwargs = dict(spec.kwargs)
    for option in model_file_options(spec.name):  # model files are paths (or a declared built-in name)
        if kwargs.get(option) is not None:
            where = f"train.pipelines.{config.pipeline}.kwargs"
            kwargs[option] = to_dict(coerce(kwargs[option], Path, option, where))
    return {"name": spec.name, "kwargs": kwargs}


def _check_env_keys(config: EgoTrainConfig) -> None:
    """Unknown `ScenarioEnv` keys in ``env`` / ``eval_env`` fail here, before any run folder or env process exists."""
    from seal.envs.scenario_env import DEFAULT_CONFIG

    for section in ("env", "eval_env"):
        unknown = sorted(set(getattr(config, section)) - set(DEFAULT_CONFIG))
        if unknown:
            raise ConfigError(f"train.{section}: unknown ScenarioEnv key(s) {unknown}; known: {sorted(DEFAULT_CONFIG)}")


def resolve(config: EgoTrainConfig, preset: str) -> dict[str, Any]:
    """Validate a config and reduce it to the run's settings (module docstring)."""
    algo = config.algo.lower()
    if algo not in ALGOS:
        raise ConfigError(f"train.algo must be one of {ALGOS}, got {config.algo!r}")
    generator = _generator(config)
    for key in ("total_timesteps", "k", "eval_episodes", "torch_threads"):
        if getattr(config, key) < 1:
            raise ConfigError(f"train.{key} must be >= 1, got {getattr(config, key)}")
    for key in ("eval_every", "checkpoint_every"):
        if getattr(config, key) < 0:
            raise ConfigError(f"train.{key} must be >= 0, got {getattr(config, key)}")
    if config.n_envs is not None and config.n_envs < 1:
        raise ConfigError(f"train.n_envs must be >= 1 or null (all cores), got {config.n_envs}")
    if not 0.0 <= config.revisit_prob < 1.0:
        raise ConfigError(f"train.revisit_prob must be in [0, 1), got {config.revisit_prob}")
    _check_env_keys(config)
    chosen = getattr(config.hyperparams, algo)
    if hasattr(chosen, "policy_kwargs"):
        parse_policy_kwargs(chosen.policy_kwargs)  # activation names checked before any run folder exists
    plain = to_dict(config)
    out = {k: v for k, v in plain.items() if k not in ("pipelines", "hyperparams")}
    out.update(algo=algo, generator=generator, hyperparams=plain["hyperparams"][algo], preset=preset)
    return out


def check_resolved(config: Mapping[str, Any], source: str) -> dict[str, Any]:
    """A run folder's recorded config (``source`` names the file), checked for the keys a run needs."""
    if not isinstance(config, Mapping):
        raise ConfigError(f"{source}: expected a mapping")
    config = {**ADDED_LATER, **config}  # runs recorded before a field existed resume with its old behaviour
    need = {f for f in EgoTrainConfig.__dataclass_fields__ if f != "pipelines"} | set(RESOLVED_ONLY)
    missing = sorted(need - set(config))
    if missing:
        raise ConfigError(f"{source}: missing key(s) {missing}; not a `seal train` run config")
    return dict(config)
