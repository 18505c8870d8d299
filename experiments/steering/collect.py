"""Targets of a scenario set with their latents at every site and the labels of their logged futures.

Targets: every agent with 2 valid history steps, the full 8 s future logged and at least 1 m of travel
(`seal.models.prior.samples.select_targets`), at most ``max_targets`` of them (a seeded draw keeps whole scenes
out of nothing: rows are drawn uniformly). Labels (`seal.models.steering.labels`) are computed on the logged
future: activity risk, proximity risk to the ego (nan for the ego itself), and the motion classes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from seal.core.scenario import CURRENT_STEP, HEADING, N_HISTORY, VALID, VX, VY, Scenario, X, Y
from seal.models.prior.prior import TrajectoryPrior
from seal.models.prior.samples import TargetFilter, select_targets
from seal.models.steering.labels import RiskConfig, activity_risk, motion_classes, proximity_risk
from seal.models.steering.latents import hidden_states, prepare

BATCH = 64


@dataclass(frozen=True)
class Target:
    """One (scenario, agent) target; ``scene`` indexes the scenario list."""

    scene: int
    agent: int


def find_targets(scenarios: Sequence[Scenario], max_targets: int | None = None, seed: int = 0,
                 adversary_only: bool = False) -> list[Target]:
    """The targets of ``scenarios`` (module docstring), in scenario order."""
    filt = TargetFilter(min_history_steps=2, min_future_steps=80, adversary_only=adversary_only)
    targets = [Target(k, int(a)) for k, s in enumerate(scenarios) for a in select_targets(s, filt)]
    if max_targets is not None and len(targets) > max_targets:
        keep = np.sort(np.random.default_rng(seed).choice(len(targets), size=max_targets, replace=False))
        targets = [targets[i] for i in keep]
    return targets


@dataclass(frozen=True)
class TargetState:
    """What the labels of a target's future need: its current position, speed, heading, and the ego's logged
    future (``[80, 2]`` m and validity ``[80]``)."""

    start_xy: np.ndarray
    start_speed_mps: float
    start_heading: float
    ego_xy: np.ndarray
    ego_valid: np.ndarray
    is_ego: bool


def target_state(scenario: Scenario, agent: int) -> TargetState:
    now = scenario.tracks[agent, CURRENT_STEP].astype(np.float64)
    ego = scenario.tracks[scenario.ego_index, N_HISTORY:]
    return TargetState(now[[X, Y]], float(np.hypot(now[VX], now[VY])), float(now[HEADING]),
                       ego[:, [X, Y]].astype(np.float64), ego[:, VALID] > 0.5, agent == scenario.ego_index)


def future_labels(xy: np.ndarray, st: TargetState, risk: RiskConfig) -> dict[str, np.ndarray]:
    """Labels of futures ``xy [..., 80, 2]`` of one target: ``activity``, ``proximity`` (nan for the ego) and the
    motion classes, each ``[...]``."""
    shape = xy.shape[:-2]
    out: dict[str, np.ndarray] = {
        "activity": activity_risk(xy, st.start_xy, risk),
        "proximity": np.full(shape, np.nan) if st.is_ego else proximity_risk(xy, st.ego_xy, st.ego_valid, risk),
    }
    out.update(motion_classes(xy, st.start_xy, np.full(shape, st.start_speed_mps), np.full(shape, st.start_heading)))
    return out


@dataclass(frozen=True)
class Samples:
    """Latents and labels of targets (`collect`).

    Attributes:
        targets: the targets.
        groups: ``[N]`` scene index of each row (for held-out splits by scene).
        latents: site -> ``[N, d_model]``.
        labels: name -> ``[N]`` (`future_labels` of the logged futures).
    """

    targets: list[Target]
    groups: np.ndarray
    latents: dict[str, np.ndarray]
    labels: dict[str, np.ndarray]


def logged_future(scenario: Scenario, agent: int) -> np.ndarray:
    """``[80, 2]`` the agent's logged future (m)."""
    return scenario.tracks[agent, N_HISTORY:][:, [X, Y]].astype(np.float64)


def collect(prior: TrajectoryPrior, scenarios: Sequence[Scenario], targets: Sequence[Target],
            risk: RiskConfig | None = None, progress: bool = False) -> Samples:
    """Latents at every site and logged-future labels of ``targets``."""
    risk = risk or RiskConfig()
    latents: dict[str, list[np.ndarray]] = {}
    labels: dict[str, list[np.ndarray]] = {}
    for lo in tqdm(range(0, len(targets), BATCH), desc="latents", unit="batch", disable=not progress):
        chunk = targets[lo : lo + BATCH]
        batch = prepare(prior, [scenarios[t.scene] for t in chunk], [t.agent for t in chunk])
        for site, z in hidden_states(prior, batch).items():
            latents.setdefault(site, []).append(z)
        for t in chunk:
            s = scenarios[t.scene]
            for name, v in future_labels(logged_future(s, t.agent), target_state(s, t.agent), risk).items():
                labels.setdefault(name, []).append(np.asarray(v)[None])
    if not targets:
        raise ValueError("no targets with 2 history steps and a full 8 s future in the given scenarios")
    return Samples(list(targets), np.array([t.scene for t in targets]),
                   {k: np.concatenate(v) for k, v in latents.items()},
                   {k: np.concatenate(v) for k, v in labels.items()})
