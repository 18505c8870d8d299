"""Skill demonstrations: every vehicle of a scenario driven from its own observation, recorded as (own observation,
applied action) per step, with the collisions and near misses of the simulated tracks and who struck them
(`seal.models.skills.events`). Two sources (`DemoConfig.source`):

* ``log``: the logged traffic's own drivers (`roll_out_log_demonstrations`): each vehicle applies the actions that
  reproduce its logged track. Clean driving, no injected noise: the benign skills are learned from these.
* ``heuristic``: the noisy `HeuristicDriver` of thesis 6.3.3 (all agents follow the heuristic), with the noise
  model below. Its collisions give adversarial windows (the striker's, `seal.models.skills.demos.WindowSpec`);
  its other windows are not benign demonstrations (the noise is not how the logged traffic drives).
* ``expert``: DART-style demonstrations of the clean `HeuristicDriver` (`roll_out_expert_demonstrations`): the
  scenario's ego and a share of the other vehicles are driven by it with OU noise added to the *applied* action,
  while the *recorded* action is the driver's clean one from the state the noise led to; the other vehicles
  replay the log as in ``log``. A skill decoder imitating plain demonstrations never sees the states its own small
  errors lead to and drifts in closed loop (issue 17: the ReSkill ego's prior mode reaches 0.60-0.71 success
  where the heuristic reaches ~0.85, and it strikes ~90 % of its crashes); these windows show how a driver
  recovers from them (Laskey et al., DART, 2017).

Noise model of the heuristic source (`DemoConfig`), per agent:

* every driver gets its own IDM time headway and minimum gap (drawn uniformly from the configured ranges);
* additive Ornstein-Uhlenbeck noise on steering and acceleration (stationary std ``steer_noise`` /
  ``accel_noise``, time constant ``noise_tau_s``): smooth human-like drift rather than per-step jitter, so a
  10-step window carries a consistent deviation a skill latent can encode;
* a share ``impaired_share`` of agents is impaired: ``impaired_noise_scale`` times the noise, a longitudinal
  reaction delay (acceleration decided on the observation of ``d`` steps ago, ``d`` uniform in
  ``reaction_delay_steps``; steering stays on the current observation) and distractions (starting at rate
  ``distraction_rate_hz``, lasting ``distraction_s``) during which the agent does not see other vehicles. These
  produce the rear-end and merge collisions the adversarial skills are learned from.

`build_demonstrations` runs a list of scenarios in parallel processes in resumable chunks and writes one
`seal.models.skills.demos.Demonstrations` file.
"""

from __future__ import annotations

import math
import shutil
import zlib
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.chunked import fingerprint, run_chunked
from seal.core.config import check_keys
from seal.core.scenario import DT_S, N_STEPS, VALID, Scenario
from seal.envs import observation as ob
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import recover_actions
from seal.envs.multi_agent import HORIZON, MultiAgentSim, SimConfig
from seal.models.skills.demos import EXPERT, HEURISTIC, LOG, Demonstrations
from seal.models.skills.events import EventSpec, find_events

DEMO_SOURCES = ("heuristic", "log", "expert")
"""Sources a `DemoConfig` simulates (the closed-loop ego roll-outs are built by `seal.experiments.fitting`)."""


@dataclass(frozen=True)
class DemoConfig:
    """Settings of the demonstration roll-outs (see the module docstring).

    Attributes:
        start_step, end_step: simulated scenario steps (`seal.envs.multi_agent.SimConfig`).
        steer_noise, accel_noise: stationary std of the OU noise on the normalised steering / acceleration.
        noise_tau_s: OU time constant (s).
        headway_range_s, min_gap_range_m: per-driver IDM time headway (s) and minimum gap (m) ranges.
        impaired_share: share of impaired agents.
        impaired_noise_scale: noise multiplier for impaired agents.
        reaction_delay_steps: inclusive range of the impaired longitudinal reaction delay (steps).
        distraction_rate_hz: rate at which an impaired agent starts a distraction (1/s).
        distraction_s: range of a distraction's duration (s).
        max_lateral_m, offroad_tolerance_m: road checks (`SimConfig`).
        seed: base seed; each scenario's stream is derived from it and the scenario id.
        source: ``heuristic`` (the noisy drivers above), ``log`` (the logged traffic's own actions, no noise:
            `roll_out_log_demonstrations`; the noise settings are ignored) or ``expert`` (DART demonstrations of
            the clean heuristic driver: `roll_out_expert_demonstrations`).
        expert_share: ``expert`` source: share of the non-ego vehicles driven by the expert (the ego always is).
        expert_steer_noise, expert_accel_noise: ``expert`` source: stationary std of the OU noise added to the
            applied normalised steering / acceleration (time constant ``noise_tau_s``); the recorded action is the
            clean one.
        near_miss_gap_m, near_miss_closing_mps, striker_margin_mps: event thresholds
            (`seal.models.skills.events.EventSpec`).
    """

    start_step: int = 0
    end_step: int = N_STEPS - 1
    steer_noise: float = 0.02
    accel_noise: float = 0.08
    noise_tau_s: float = 1.0
    headway_range_s: tuple[float, float] = (0.6, 1.4)
    min_gap_range_m: tuple[float, float] = (1.5, 3.0)
    impaired_share: float = 0.5
    impaired_noise_scale: float = 3.0
    reaction_delay_steps: tuple[int, int] = (5, 15)
    distraction_rate_hz: float = 0.3
    distraction_s: tuple[float, float] = (1.0, 2.5)
    max_lateral_m: float = 10.0
    offroad_tolerance_m: float = 0.5
    seed: int = 0
    source: str = "heuristic"
    near_miss_gap_m: float = 0.5
    near_miss_closing_mps: float = 1.0
    striker_margin_mps: float = 0.5
    expert_share: float = 0.25
    expert_steer_noise: float = 0.05
    expert_accel_noise: float = 0.2

    def __post_init__(self) -> None:
        for name in ("steer_noise", "accel_noise", "impaired_noise_scale", "distraction_rate_hz", "expert_steer_noise",
                     "expert_accel_noise"):
            if float(getattr(self, name)) < 0:
                raise ValueError(f"DemoConfig: {name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.impaired_share <= 1.0:
            raise ValueError(f"DemoConfig: impaired_share must be in [0, 1], got {self.impaired_share}")
        if not 0.0 <= self.expert_share <= 1.0:
            raise ValueError(f"DemoConfig: expert_share must be in [0, 1], got {self.expert_share}")
        if self.noise_tau_s <= 0:
            raise ValueError(f"DemoConfig: noise_tau_s must be > 0, got {self.noise_tau_s}")
        for name in ("headway_range_s", "min_gap_range_m", "reaction_delay_steps", "distraction_s"):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f"DemoConfig: {name} must be a range 0 <= low <= high, got {(lo, hi)}")
        self.sim_config()  # validates the time span
        self.event_spec()
        if self.source not in DEMO_SOURCES:
            raise ValueError(f"DemoConfig: source must be one of {DEMO_SOURCES}, got {self.source!r}")

    def event_spec(self) -> EventSpec:
        return EventSpec(near_miss_gap_m=self.near_miss_gap_m, near_miss_closing_mps=self.near_miss_closing_mps,
                         striker_margin_mps=self.striker_margin_mps)

    def sim_config(self) -> SimConfig:
        return SimConfig(start_step=self.start_step, end_step=self.end_step, max_lateral_m=self.max_lateral_m,
                         offroad_tolerance_m=self.offroad_tolerance_m)

    def to_dict(self) -> dict[str, Any]:
        """The settings as plain values, only those the source uses (the ``expert_*`` settings for ``expert``, the
        noisy drivers' for ``heuristic``): the identity of a source's file (what `seal.experiments.fitting.skill_data`
        reuses) does not change with settings it ignores."""
        d = asdict(self)
        unused = {"log": (*_EXPERT_FIELDS, *_NOISE_FIELDS, "noise_tau_s"), "expert": _NOISE_FIELDS,
                  "heuristic": _EXPERT_FIELDS}[self.source]
        for name in unused:
            d.pop(name)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "demo config") -> DemoConfig:
        check_keys(cls, d, where)
        values: dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}
        return cls(**values)


_EXPERT_FIELDS = ("expert_share", "expert_steer_noise", "expert_accel_noise")
_NOISE_FIELDS = ("steer_noise", "accel_noise", "headway_range_s", "min_gap_range_m", "impaired_share",
                 "impaired_noise_scale", "reaction_delay_steps", "distraction_rate_hz", "distraction_s")
"""The noisy heuristic drivers' settings: only the ``heuristic`` source uses them."""


def scenario_seed(base_seed: int, scenario_id: str) -> np.random.SeedSequence:
    """Seed stream of one scenario: independent of which process or chunk simulates it."""
    return np.random.SeedSequence([int(base_seed) & 0xFFFFFFFF, zlib.crc32(scenario_id.encode())])


class NoisyHeuristicDrivers:
    """Per-agent noisy heuristic drivers for one roll-out (see the module docstring); agents are created on
    first use, so agents entering late get a driver when they first act."""

    def __init__(self, config: DemoConfig, rng: np.random.Generator) -> None:
        self.cfg = config
        self.rng = rng
        self._drivers: dict[int, HeuristicDriver] = {}
        self._noise: dict[int, np.ndarray] = {}
        self._scale: dict[int, float] = {}
        self._delay: dict[int, int] = {}
        self._history: dict[int, list[np.ndarray]] = {}
        self._distracted: dict[int, int] = {}
        self._impaired: dict[int, bool] = {}
        self._decay = math.exp(-DT_S / config.noise_tau_s)
        self._sigma = np.array([config.steer_noise, config.accel_noise])

    def impaired(self, agent: int) -> bool:
        """Whether ``agent`` drives with the impaired model (False for agents not seen yet)."""
        return self._impaired.get(agent, False)

    def _add(self, agent: int) -> None:
        cfg, rng = self.cfg, self.rng
        self._drivers[agent] = HeuristicDriver(
            time_headway_s=float(rng.uniform(*cfg.headway_range_s)),
            min_gap_m=float(rng.uniform(*cfg.min_gap_range_m)),
        )
        impaired = bool(rng.random() < cfg.impaired_share)
        self._impaired[agent] = impaired
        self._scale[agent] = cfg.impaired_noise_scale if impaired else 1.0
        self._delay[agent] = int(rng.integers(cfg.reaction_delay_steps[0], cfg.reaction_delay_steps[1] + 1)) \
            if impaired else 0
        # Start from the stationary distribution so there is no noise-free transient.
        self._noise[agent] = rng.normal(0.0, 1.0, 2) * self._sigma * self._scale[agent]
        self._history[agent] = []
        self._distracted[agent] = 0

    def act(self, agents: np.ndarray, obs: np.ndarray) -> np.ndarray:
        """Actions ``[n, 2]`` (float32, clipped to [-1, 1]) of ``agents`` given their observations ``[n, D]``."""
        out = np.empty((len(agents), 2), dtype=np.float32)
        cfg, rng = self.cfg, self.rng
        innov = math.sqrt(1.0 - self._decay**2)
        for k, agent in enumerate(np.asarray(agents).tolist()):
            if agent not in self._drivers:
                self._add(agent)
            o = obs[k].astype(np.float64)
            driver = self._drivers[agent]
            steer, accel = driver.act(o)
            if self._impaired[agent]:
                hist = self._history[agent]
                hist.append(o)
                if len(hist) > self._delay[agent] + 1:
                    hist.pop(0)
                seen = hist[0]  # the observation of `delay` steps ago (the oldest one early on)
                if self._distracted[agent] > 0:
                    self._distracted[agent] -= 1
                    seen = _blind(seen)
                elif rng.random() < cfg.distraction_rate_hz * DT_S:
                    self._distracted[agent] = int(round(rng.uniform(*cfg.distraction_s) / DT_S))
                if seen is not o:
                    accel = driver.act(seen)[1]
            n = self._noise[agent]
            n *= self._decay
            n += innov * rng.normal(0.0, 1.0, 2) * self._sigma * self._scale[agent]
            out[k] = (steer + n[0], accel + n[1])
        np.clip(out, -1.0, 1.0, out=out)
        return out


def _blind(obs: np.ndarray) -> np.ndarray:
    """The observation without other vehicles (lidar at full range, no nearest-vehicle slots)."""
    o = obs.copy()
    o[ob.LIDAR] = 1.0
    o[ob.NEAREST] = 0.0
    return o


Act = Callable[[np.ndarray, np.ndarray, int], np.ndarray]
"""``(agent rows [n], observations [n, D], scenario step) -> actions [n, 2]`` of the active driven agents."""


def _simulate(scenario: Scenario, cfg: DemoConfig, act: Act, source: int, impaired: Callable[[int], bool],
              record_until: np.ndarray | None = None, labels: Callable[[], np.ndarray] | None = None
              ) -> Demonstrations:
    """Drive ``scenario``'s vehicles with ``act`` in a `MultiAgentSim`, record (observation, action) per agent and
    step, find the collisions and near misses on the simulated tracks (`seal.models.skills.events.find_events`) and
    return the `Demonstrations` (segments in the order agents ended). ``record_until[i]``: agent row ``i``'s
    actions are recorded at steps before it only (its segment is cut there). ``labels``: called after each ``act``,
    the actions to record ``[n, 2]`` instead of the applied ones (the expert's clean actions)."""
    sim = MultiAgentSim(scenario, cfg.sim_config())
    tracks = np.zeros((scenario.n_agents, N_STEPS, 8))
    tracks[:, sim.t] = sim.boxes()
    rec_obs: dict[int, list[np.ndarray]] = {}
    rec_act: dict[int, list[np.ndarray]] = {}
    while not sim.done:
        t = sim.t
        idx, obs = sim.observe()
        actions = act(idx, obs, t)
        recorded = actions if labels is None else labels()
        for k, i in enumerate(idx.tolist()):
            if record_until is None or t < record_until[i]:
                rec_obs.setdefault(i, []).append(obs[k])
                rec_act.setdefault(i, []).append(recorded[k])
        ended = sim.step(idx, actions)
        tracks[:, sim.t] = sim.boxes()
        for end in ended:
            if end.row is not None:
                tracks[end.index, end.end_step] = end.row
    events = find_events(tracks, cfg.event_spec())
    obs_parts: list[np.ndarray] = []
    act_parts: list[np.ndarray] = []
    segs: list[tuple[int, ...]] = []
    seg_of: dict[int, int] = {}
    row = 0
    for end in sim.ends:
        stop = end.end_step if record_until is None else min(end.end_step, int(record_until[end.index]))
        n = stop - end.start_step
        if n < 1 or end.index not in rec_obs:
            continue
        o, a = rec_obs.pop(end.index), rec_act.pop(end.index)
        assert len(o) == n, (scenario.scenario_id, end, len(o))
        obs_parts.append(np.stack(o))
        act_parts.append(np.stack(a))
        reason = end.end_reason if stop == end.end_step else HORIZON  # cut where its log ends
        seg_of[end.index] = len(segs)
        segs.append((row, n, end.agent_id, end.start_step, reason, impaired(end.index)))
        row += n
    seg = np.array(segs, dtype=np.int64).reshape(-1, 6)
    keep = np.array([int(a) in seg_of for a in events.agent.tolist()], dtype=bool)
    ev_seg = np.array([seg_of[int(a)] for a in events.agent[keep].tolist()], dtype=np.int64)
    return Demonstrations(
        obs=np.concatenate(obs_parts).astype(np.float16) if obs_parts else np.zeros((0, ob.OBS_DIM), np.float16),
        actions=np.concatenate(act_parts).astype(np.float32) if act_parts else np.zeros((0, 2), np.float32),
        seg_row=seg[:, 0], seg_len=seg[:, 1].astype(np.int32), seg_scenario=np.zeros(len(seg), dtype=np.int32),
        seg_agent=seg[:, 2], seg_start_step=seg[:, 3].astype(np.int32), seg_end_reason=seg[:, 4].astype(np.int8),
        seg_impaired=seg[:, 5].astype(bool), seg_source=np.full(len(seg), source, dtype=np.int8),
        ev_seg=ev_seg, ev_step=events.step[keep], ev_kind=events.kind[keep], ev_striker=events.striker[keep],
        scenario_ids=np.array([scenario.scenario_id]), params=cfg.to_dict(),
    )


def roll_out_demonstrations(scenario: Scenario, config: DemoConfig | None = None) -> Demonstrations:
    """One scenario's `Demonstrations` of the configured source (``config.source``): `roll_out_log_demonstrations`
    or every vehicle driven by `NoisyHeuristicDrivers` (deterministic for the config's seed and the scenario id)."""
    cfg = config or DemoConfig()
    if cfg.source == "log":
        return roll_out_log_demonstrations(scenario, cfg)
    if cfg.source == "expert":
        return roll_out_expert_demonstrations(scenario, cfg)
    rng = np.random.default_rng(scenario_seed(cfg.seed, scenario.scenario_id))
    drivers = NoisyHeuristicDrivers(cfg, rng)
    return _simulate(scenario, cfg, lambda idx, obs, _t: drivers.act(idx, obs), HEURISTIC, drivers.impaired)


def _log_actions(scenario: Scenario) -> np.ndarray:
    """``[A, T - 1, 2]`` normalised actions that make the bicycle model follow each agent's logged track
    (`seal.envs.kinematics.recover_actions`; row ``t`` moves step ``t`` to ``t + 1``)."""
    log = scenario.tracks.astype(np.float64)
    return np.stack([recover_actions(log[i]) for i in range(scenario.n_agents)])


def roll_out_log_demonstrations(scenario: Scenario, config: DemoConfig | None = None) -> Demonstrations:
    """The logged traffic's own drivers: every vehicle acts with the normalised actions that make the bicycle model
    follow its logged track (`seal.envs.kinematics.recover_actions`, row ``t`` moves step ``t`` to ``t + 1``), each
    from its own observation of the simulated scene. No noise: the actions are the log's, so the segments are clean
    driving (benign windows). An agent's segment is cut at its last logged step (afterwards it would only coast)."""
    cfg = config or DemoConfig(source="log")
    actions = _log_actions(scenario)
    valid = scenario.tracks[:, :, VALID] > 0.5
    last = valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1)

    def act(idx: np.ndarray, _obs: np.ndarray, t: int) -> np.ndarray:
        return actions[idx, min(t, actions.shape[1] - 1)].astype(np.float32)

    return _simulate(scenario, cfg, act, LOG, lambda _i: False, record_until=last)


def roll_out_expert_demonstrations(scenario: Scenario, config: DemoConfig | None = None) -> Demonstrations:
    """DART demonstrations of the clean `HeuristicDriver` (module docstring): the ego and each other vehicle with
    probability ``expert_share`` are driven by it with OU noise on the applied action (std ``expert_*_noise``,
    time constant ``noise_tau_s``) and record its clean action; only their segments are recorded. The rest replay
    the log (`roll_out_log_demonstrations`' actions). Deterministic for the config's seed and the scenario id."""
    cfg = config or DemoConfig(source="expert")
    rng = np.random.default_rng(scenario_seed(cfg.seed, scenario.scenario_id))
    log_actions = _log_actions(scenario)
    expert = rng.random(scenario.n_agents) < cfg.expert_share
    expert[scenario.ego_index] = True
    driver = HeuristicDriver()  # stateless between calls: one serves every expert vehicle
    sigma = np.array([cfg.expert_steer_noise, cfg.expert_accel_noise])
    decay = math.exp(-DT_S / cfg.noise_tau_s)
    noise = rng.normal(0.0, 1.0, (scenario.n_agents, 2)) * sigma  # stationary start: no noise-free transient
    innovation = math.sqrt(1.0 - decay**2) * sigma
    clean: list[np.ndarray] = []

    def act(idx: np.ndarray, obs: np.ndarray, t: int) -> np.ndarray:
        applied = log_actions[idx, min(t, log_actions.shape[1] - 1)].astype(np.float32)
        labels = applied.copy()
        step_noise = rng.normal(0.0, 1.0, (len(idx), 2)) * innovation  # drawn for every agent: order-independent
        for k, i in enumerate(idx.tolist()):
            if expert[i]:
                labels[k] = driver.act(obs[k].astype(np.float64))
                noise[i] = noise[i] * decay + step_noise[k]
                applied[k] = labels[k] + noise[i]
        np.clip(applied, -1.0, 1.0, out=applied)
        clean[:] = [labels]
        return applied

    record_until = np.where(expert, N_STEPS, 0)
    return _simulate(scenario, cfg, act, EXPERT, lambda _i: False, record_until=record_until,
                     labels=lambda: clean[0])


def _run_chunk(args: tuple[int, list[Scenario], dict[str, Any]]) -> tuple[int, Demonstrations]:
    index, scenarios, cfg = args
    config = DemoConfig.from_dict(cfg)
    return index, Demonstrations.concat([roll_out_demonstrations(s, config) for s in scenarios], config.to_dict())


def parts_dir(out: str | Path) -> Path:
    """Where `build_demonstrations` keeps finished chunks until the final file is written."""
    out = Path(out)
    return out.with_name(out.name + ".parts")


def build_demonstrations(
    scenarios: Sequence[Scenario],
    out: str | Path,
    config: DemoConfig | None = None,
    workers: int = 2,
    chunk_size: int = 10,
    progress: bool = True,
) -> Demonstrations:
    """Simulate ``scenarios`` in ``workers`` processes and write one `Demonstrations` file to ``out``.

    Resumable: finished chunks of ``chunk_size`` scenarios are kept in `parts_dir` (atomic writes) and reused by a
    re-run with the same config and scenarios (`seal.core.chunked.fingerprint` of both); the folder is removed
    once ``out`` is written. Resuming / restarting is logged by `seal.core.chunked`.
    """
    cfg = config or DemoConfig()
    if not scenarios:
        raise ValueError("build_demonstrations: no scenarios")
    out = Path(out)
    parts = parts_dir(out)
    ids = [s.scenario_id for s in scenarios]
    settings = fingerprint({"config": cfg.to_dict(), "ids": ids, "chunk": chunk_size})
    paths = run_chunked(
        scenarios, parts, settings, {}, _run_chunk, (cfg.to_dict(),),
        lambda demos, file: demos.save(file, compress=False), workers, chunk_size, progress, "demonstrations",
    )
    merged = Demonstrations.concat([Demonstrations.load(p) for p in paths], cfg.to_dict())
    merged.save(out)
    shutil.rmtree(parts)
    return merged
