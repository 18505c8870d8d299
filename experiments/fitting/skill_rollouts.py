"""Adversarial skill demonstrations from closed-loop roll-outs against egos (issue 16; thesis 6.3.2).

The skill policy acts from the adversary's own observation, in which the ego is a learning policy that may brake
hard, stop or weave; the simulated demonstrations (`seal.models.skills.demonstrations`) only ever show heuristic
drivers around the demonstrator. Here each scenario of the split is played in `ScenarioEnv` once per ego (the
heuristic driver and trained `seal train` checkpoints): the adversary is an impaired noisy heuristic driver
(`NoisyHeuristicDrivers` with every driver impaired: reaction delay, distractions, 3x noise) that sees its own
observation each step, the other vehicles replay their log. Its (observation, action) per step is one segment of
source ``ego_rollout``; the collisions and near misses of the executed tracks, with who struck them
(`seal.models.skills.events.find_events`), label its windows: only the windows before an event the adversary
struck are used (`seal.models.skills.demos.WindowSpec`; the rest are not clean driving).

`build_ego_demonstrations` runs in parallel processes in resumable chunks (`seal.core.chunked`).
"""

from __future__ import annotations

import shutil
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.chunked import fingerprint, run_chunked
from seal.core.scenario import CURRENT_STEP, Scenario
from seal.envs.behaviors import AdversaryBehavior, BehaviorOutput
from seal.envs.kinematics import AgentState
from seal.envs.multi_agent import COLLISION, HORIZON, OUT_OF_ROAD
from seal.envs.rollout import Rollout
from seal.envs.route import Route
from seal.models.skills.demonstrations import DemoConfig, NoisyHeuristicDrivers
from seal.models.skills.demos import EGO_ROLLOUT, Demonstrations
from seal.models.skills.events import COLLISION_EVENT, find_events

ADVERSARIES = ("cat", "heuristic")
"""Adversaries of the roll-outs: ``cat``: CAT's generator (candidates of the trajectory prior, or the lane-following
source, chosen against the ego's previous roll-outs) followed with the bicycle model (``follow="track"``, so every
step is a real action), K passes per ego; ``heuristic``: the impaired noisy heuristic, one episode per ego."""


class NoisyAdversary(AdversaryBehavior):
    """The impaired noisy heuristic driving the adversary from its own observation."""

    needs_observation = True

    def __init__(self, config: DemoConfig, seed: np.random.SeedSequence) -> None:
        self.config = config
        self.seed = seed
        self._drivers: NoisyHeuristicDrivers | None = None

    def reset(self, scenario: Scenario, rng: np.random.Generator) -> None:
        # Its own stream (not the env's), so the adversary's noise is the same whichever ego it meets first.
        self._drivers = NoisyHeuristicDrivers(self.config, np.random.default_rng(self.seed))

    def step(self, t: int, state: AgentState | None, observation: np.ndarray | None) -> BehaviorOutput:
        if state is None or observation is None:
            return BehaviorOutput.absent()
        assert self._drivers is not None, "reset() first"
        action = self._drivers.act(np.zeros(1, dtype=np.int64), np.asarray(observation, np.float32)[None])[0]
        return BehaviorOutput.act(float(action[0]), float(action[1]))


class Recorder(AdversaryBehavior):
    """Wraps an adversary behaviour and records its observation and applied action ``[steering, acceleration]`` at
    every step it is present (a placement's action is the control it implies, `placement_state`)."""

    needs_observation = True

    def __init__(self, inner: AdversaryBehavior) -> None:
        self.inner = inner
        self.obs: list[np.ndarray] = []
        self.actions: list[np.ndarray] = []
        self.first_step: int | None = None

    def reset(self, scenario: Scenario, rng: np.random.Generator) -> None:
        self.inner.reset(scenario, rng)
        self.obs, self.actions, self.first_step = [], [], None

    def make_route(self, scenario: Scenario) -> Route:
        return self.inner.make_route(scenario)

    def step(self, t: int, state: AgentState | None, observation: np.ndarray | None) -> BehaviorOutput:
        out = self.inner.step(t, state, observation if self.inner.needs_observation else None)
        if state is None or observation is None or (out.action is None and out.state is None):
            return out
        action = out.action if out.action is not None else (out.state.steering, out.state.accel)  # type: ignore[union-attr]
        if self.first_step is None:
            self.first_step = t
        if t != self.first_step + len(self.actions):
            return out  # a gap (the adversary was absent): keep the segment contiguous
        self.obs.append(np.asarray(observation, dtype=np.float32).copy())
        self.actions.append(np.clip(np.asarray(action, dtype=np.float32), -1.0, 1.0))
        return out


def adversary_config(config: DemoConfig) -> DemoConfig:
    """The demonstration config with every driver impaired (the ``heuristic`` adversary of these roll-outs)."""
    return DemoConfig.from_dict({**config.to_dict(), "impaired_share": 1.0, "source": "heuristic"})


def _episodes(scenario: Scenario, ego_spec: str, k: int, adversary: str, cfg: DemoConfig, source: str | None,
              passes: int) -> list[tuple[Recorder, Rollout]]:
    """The recorded episodes of one scenario against one ego (module docstring)."""
    from seal.adversaries.history import RolloutHistory
    from seal.envs.scenario_env import ScenarioEnv
    from seal.experiments.evaluation.episodes import run_episode

    env = ScenarioEnv(scenario)
    ego = _ego(ego_spec)
    seed = np.random.SeedSequence([int(cfg.seed) & 0xFFFFFFFF, zlib.crc32(scenario.scenario_id.encode()), k])
    out = []
    if adversary == "heuristic":
        rec = Recorder(NoisyAdversary(adversary_config(cfg), seed))
        out.append((rec, run_episode(env, scenario, ego, rec, seed=int(cfg.seed))))
    else:
        generator = _generator(source)
        history = RolloutHistory()
        history.append(scenario, run_episode(env, scenario, ego, None, seed=int(cfg.seed)))
        rng = np.random.default_rng(seed)
        for p in range(passes):
            rec = Recorder(generator.generate(scenario, history.queue(scenario), rng).behavior)
            rollout = run_episode(env, scenario, ego, rec, seed=int(cfg.seed) + 1 + p)
            history.append(scenario, rollout)
            out.append((rec, rollout))
    env.close()
    return out


def roll_out_against_egos(scenario: Scenario, egos: Sequence[str], config: DemoConfig, adversary: str = "cat",
                          source: str | None = None, passes: int = 3) -> Demonstrations:
    """``scenario`` against every ego spec (``heuristic`` or a `seal train` run folder,
    `seal.experiments.training.egos.make_ego`); one ``ego_rollout`` segment per recorded episode (module
    docstring). ``source``: the ``cat`` adversary's candidate source (``prior:<file>`` or a built-in name)."""
    if adversary not in ADVERSARIES:
        raise ValueError(f"unknown roll-out adversary {adversary!r}; choose from {ADVERSARIES}")
    obs_parts: list[np.ndarray] = []
    act_parts: list[np.ndarray] = []
    segs: list[tuple[int, ...]] = []
    ev_rows: list[tuple[int, int, int, bool]] = []
    row = 0
    for k, spec in enumerate(egos):
        for rec, rollout in _episodes(scenario, spec, k, adversary, config, source, passes):
            n = len(rec.actions)
            if n < 1 or rec.first_step is None:
                continue
            a = rollout.index_of(rollout.adv_id)
            events = find_events(rollout.tracks.astype(np.float64), config.event_spec())
            mine = (events.agent == a) & (events.step <= rec.first_step + n)
            seg = len(segs)
            ev_rows += [(seg, int(s), int(kd), bool(st)) for s, kd, st in
                        zip(events.step[mine], events.kind[mine], events.striker[mine], strict=True)]
            hit = bool((events.kind[mine] == COLLISION_EVENT).any())
            end = COLLISION if hit else (OUT_OF_ROAD if rollout.outcome == "out_of_road" else HORIZON)
            obs_parts.append(np.stack(rec.obs))
            act_parts.append(np.stack(rec.actions))
            segs.append((row, n, int(rollout.adv_id), rec.first_step, end))
            row += n
    seg_arr = np.array(segs, dtype=np.int64).reshape(-1, 5)
    ev = np.array(ev_rows, dtype=np.int64).reshape(-1, 4)
    return Demonstrations(
        obs=np.concatenate(obs_parts).astype(np.float16) if obs_parts else np.zeros((0, 100), np.float16),
        actions=np.concatenate(act_parts).astype(np.float32) if act_parts else np.zeros((0, 2), np.float32),
        seg_row=seg_arr[:, 0], seg_len=seg_arr[:, 1].astype(np.int32),
        seg_scenario=np.zeros(len(seg_arr), dtype=np.int32), seg_agent=seg_arr[:, 2],
        seg_start_step=seg_arr[:, 3].astype(np.int32), seg_end_reason=seg_arr[:, 4].astype(np.int8),
        seg_impaired=np.zeros(len(seg_arr), dtype=bool), seg_source=np.full(len(seg_arr), EGO_ROLLOUT, np.int8),
        ev_seg=ev[:, 0], ev_step=ev[:, 1].astype(np.int32), ev_kind=ev[:, 2].astype(np.int8),
        ev_striker=ev[:, 3].astype(bool), scenario_ids=np.array([scenario.scenario_id]),
        params=_params(egos, config, adversary, source, passes),
    )


def _params(egos: Sequence[str], config: DemoConfig, adversary: str, source: str | None, passes: int
            ) -> dict[str, Any]:
    return {"egos": list(egos), "adversary": adversary, "candidates": source, "passes": passes,
            "demo": config.to_dict()}


_GEN_CACHE: dict[str | None, Any] = {}


def _generator(source: str | None) -> Any:
    """CAT's generator (bicycle-model tracking of its choice) for candidate source ``source``, once per process."""
    if source not in _GEN_CACHE:
        from seal.adversaries.base import make_generator

        if source is None or not source.startswith("prior:"):
            kwargs: dict[str, Any] = {"candidates": source or "lanes"}
        else:
            kwargs = {"prior": source[len("prior:"):]}
        _GEN_CACHE[source] = make_generator("cat", follow="track", **kwargs)
    return _GEN_CACHE[source]


_EGO_CACHE: dict[str, Any] = {}


def _ego(spec: str) -> Any:
    """The ego of ``spec``, loaded once per process (a checkpoint takes ~0.2 s to load)."""
    if spec not in _EGO_CACHE:
        from seal.experiments.training.egos import make_ego

        _EGO_CACHE[spec] = make_ego(spec)
    return _EGO_CACHE[spec]


def _run_chunk(args: tuple[int, list[Scenario], list[str], dict[str, Any], str, str | None, int]
               ) -> tuple[int, Demonstrations]:
    index, scenarios, egos, cfg, adversary, source, passes = args
    import torch

    torch.set_num_threads(1)  # one thread per worker process (the ego networks are tiny)
    config = DemoConfig.from_dict(cfg)
    parts = [roll_out_against_egos(s, egos, config, adversary, source, passes) for s in scenarios]
    return index, Demonstrations.concat(parts, _params(egos, config, adversary, source, passes))


def build_ego_demonstrations(scenarios: Sequence[Scenario], egos: Sequence[str], out: str | Path,
                             config: DemoConfig, adversary: str = "cat", source: str | None = None, passes: int = 3,
                             workers: int = 2, chunk_size: int = 10, progress: bool = True) -> Demonstrations:
    """Roll out ``scenarios`` against every ego in ``egos`` (`roll_out_against_egos`) and write one
    `Demonstrations` file to ``out`` (resumable: finished chunks are kept in ``out``'s ``.parts`` folder until the
    file is written)."""
    if not scenarios or not egos:
        raise ValueError("build_ego_demonstrations: need scenarios and at least one ego")
    out = Path(out)
    parts = out.with_name(out.name + ".parts")
    ids = [s.scenario_id for s in scenarios]
    egos = [str(e) for e in egos]
    params = _params(egos, config, adversary, source, passes)
    settings = fingerprint({"params": params, "ids": ids, "chunk": chunk_size, "start": CURRENT_STEP})
    paths = run_chunked(
        scenarios, parts, settings, {}, _run_chunk, (egos, config.to_dict(), adversary, source, passes),
        lambda demos, file: demos.save(file, compress=False), workers, chunk_size, progress, "ego roll-outs",
    )
    merged = Demonstrations.concat([Demonstrations.load(p) for p in paths], params)
    merged.save(out)
    shutil.rmtree(parts)
    return merged
