"""Training samples of the RAPID background model from logged scenarios (teacher forcing on the logs).

One sample per (scenario, agent, step ``t``) where the agent is logged at ``t`` and ``t + 1`` (every agent of the
scenario, the ego and the adversary included: they are logged drivers too). Target: the acceleration that moves
the agent from its logged row at ``t`` to its logged position at ``t + 1`` with the update the simulation uses
(`seal.envs.background.integrate_rows`: ``v' = v + a dt``, ``p' = p + v' dt``), in the agent frame, divided by
`ACC_SCALE_MPS2` and clipped to +-3. Intent inputs: desired speed = mean logged speed over the next
`SPEED_WINDOW` steps, destination = the last logged position; each is dropped (set missing) with probability
``drop_intent`` so the model also learns the "missing" embedding a user-free agent gets.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from seal.core.scenario import DT_S, HEADING, N_STEPS, VALID, VX, VY, Scenario, X, Y
from seal.envs.background import INTENT_SPEED_WINDOW, logged_desired_speed
from seal.models.rapid.features import ACC_SCALE_MPS2, MAX_TOKENS, MapGeometry, agent_inputs, build_map_geometry
from seal.models.rapid.network import anchor_encoding

SPEED_WINDOW = INTENT_SPEED_WINDOW
"""Steps over which the training desired speed is averaged (3 s; `seal.envs.background.logged_desired_speed`,
the same intent `RapidBackground` reads from the log at run time)."""


@dataclass
class RapidSamples:
    """Stacked samples: ``inputs`` (`AgentInputs` fields, each ``[N, ...]``), ``target [N, 2]``, ``scene [N]``
    (index into the per-scenario ``tokens [S, MAX_TOKENS, F]``, ``token_pad [S, MAX_TOKENS]`` True = padding,
    ``anchors [S, N_LATENTS, POS_DIM]``)."""

    inputs: dict[str, np.ndarray]
    target: np.ndarray
    scene: np.ndarray
    tokens: np.ndarray
    token_pad: np.ndarray
    anchors: np.ndarray

    def __len__(self) -> int:
        return len(self.target)


def scenario_samples(scenario: Scenario, geo: MapGeometry, rng: np.random.Generator, drop_intent: float,
                     stride: int) -> tuple[dict[str, np.ndarray], np.ndarray] | None:
    """Inputs and targets of one scenario on its map ``geo`` (module docstring); None when it has no sample."""
    log = scenario.tracks.astype(np.float64)
    valid = log[:, :, VALID] > 0.5
    last = valid.shape[1] - 1 - np.argmax(valid[:, ::-1], axis=1)
    dest_all = log[np.arange(len(log)), last][:, [X, Y]]
    parts: list[dict[str, np.ndarray]] = []
    targets = []
    for t in range(1, N_STEPS - 1, stride):
        rows = np.flatnonzero(valid[:, t] & valid[:, t + 1])
        if not rows.size:
            continue
        cur = np.where(valid[:, t, None], log[:, t], 0.0)
        desired = logged_desired_speed(log, valid, t, rows)
        desired[rng.random(rows.size) < drop_intent] = np.nan
        dest = dest_all[rows].copy()
        dest[rng.random(rows.size) < drop_intent] = np.nan
        inp = agent_inputs(geo, cur, rows, log[rows, t - 1][:, [VX, VY]], valid[rows, t - 1], desired, dest)
        parts.append(vars(inp))
        v_next = (log[rows, t + 1][:, [X, Y]] - log[rows, t][:, [X, Y]]) / DT_S
        acc = (v_next - log[rows, t][:, [VX, VY]]) / DT_S
        c, s = np.cos(log[rows, t, HEADING]), np.sin(log[rows, t, HEADING])
        local = np.column_stack([c * acc[:, 0] + s * acc[:, 1], -s * acc[:, 0] + c * acc[:, 1]])
        targets.append(np.clip(local / ACC_SCALE_MPS2, -3.0, 3.0))
    if not parts:
        return None
    stacked = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return stacked, np.concatenate(targets).astype(np.float32)


def build_samples(scenarios: Iterable[Scenario], seed: int, drop_intent: float = 0.15, stride: int = 1
                  ) -> RapidSamples:
    """`RapidSamples` of ``scenarios`` (every ``stride``-th step)."""
    rng = np.random.default_rng(seed)
    inputs: list[dict[str, np.ndarray]] = []
    targets: list[np.ndarray] = []
    scenes: list[np.ndarray] = []
    tokens: list[np.ndarray] = []
    pads: list[np.ndarray] = []
    anchors: list[np.ndarray] = []
    for scenario in scenarios:
        geo = build_map_geometry(scenario.road)
        got = scenario_samples(scenario, geo, rng, drop_intent, stride)
        if got is None:
            continue
        inp, tgt = got
        geo_tokens = geo.tokens
        padded = np.zeros((MAX_TOKENS, geo_tokens.shape[1]), dtype=np.float32)
        padded[: len(geo_tokens)] = geo_tokens
        pad = np.ones(MAX_TOKENS, dtype=bool)
        pad[: len(geo_tokens)] = False
        scenes.append(np.full(len(tgt), len(tokens)))
        tokens.append(padded)
        pads.append(pad)
        anchors.append(anchor_encoding(geo_tokens))
        inputs.append(inp)
        targets.append(tgt)
    if not targets:
        raise ValueError("no RAPID training sample: no agent is logged on two consecutive steps")
    return RapidSamples(
        {k: np.concatenate([p[k] for p in inputs]) for k in inputs[0]}, np.concatenate(targets),
        np.concatenate(scenes), np.stack(tokens), np.stack(pads), np.stack(anchors),
    )
