"""`RapidBackground`: the learned background controller of ``ScenarioEnv(config={"background": "rapid"})``.

Per env step, for all background agents at once: `agent_input_tables` (compiled) -> agent encoder reading the scenario's
cached global map latents -> ``ddim_steps`` DDIM steps of the denoiser with physics guidance (eq. 7) -> the
next-step acceleration, integrated by `SimulatedBackground` (the log's lifetime, `integrate_rows`).

The map context (`MapGeometry` and the encoder's ``z_global``) is computed once per road and cached
(`map_builds` counts the builds), so the per-step cost does not depend on the map's size.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.errors import SealError
from seal.core.road import RoadDescription
from seal.core.scenario import HEADING, VALID, VX, VY, Scenario
from seal.envs.background import SimulatedBackground
from seal.models.rapid.fast import FastAgentEncoder, FastDenoiser
from seal.models.rapid.features import (
    ACC_SCALE_MPS2,
    MapGeometry,
    agent_input_tables,
    build_map_geometry,
    scan_pairs,
)
from seal.models.rapid.network import Denoiser, RapidNet, anchor_encoding
from seal.models.rapid.sampler import Guidance, ddim_sample, physics_targets, schedule, social_constants
from seal.models.rapid.train import load_rapid_net

MapEntry = tuple[RoadDescription, MapGeometry, torch.Tensor, tuple[torch.Tensor, torch.Tensor]]
"""A map cache entry: the road, its `MapGeometry`, ``z_global`` and the read-out keys / values."""
MAP_CACHE_SIZE = 256
"""Roads whose map context is kept (least recently built dropped first)."""


class RapidBackground(SimulatedBackground):
    """RAPID background agents (module docstring).

    Args:
        net: the trained network (`seal.models.rapid.train.load_rapid_net`).
        guidance: eq. 7 weights and social-force constants (`Guidance`; all weights 0 = unguided).
        ddim_steps: DDIM steps per env step (few: the latency budget).
        temperature: scale of the sampler's starting noise (1 = the trained distribution).
    """

    name = "rapid"

    def __init__(self, net: RapidNet, guidance: Guidance | None = None, ddim_steps: int = 5,
                 temperature: float = 1.0) -> None:
        self.net = net.eval()
        # the per-step path of the network (`seal.models.rapid.fast`); a denoiser of another kind is called as is
        self._agent = FastAgentEncoder(net.agent)
        self._denoiser: torch.nn.Module | FastDenoiser = (
            FastDenoiser(net.denoiser) if isinstance(net.denoiser, Denoiser) else net.denoiser)
        self.guidance = guidance or Guidance()
        self.ddim_steps = int(ddim_steps)
        self.temperature = float(temperature)
        self.alpha_bar = schedule()
        self._maps: dict[int, MapEntry] = {}
        self.map_builds = 0
        """How many map contexts were built (one per road seen, while cached)."""

    def with_guidance(self, guidance: Guidance) -> RapidBackground:
        """The same network (and map cache) with other guidance options."""
        other = RapidBackground(self.net, guidance, self.ddim_steps, self.temperature)
        other._maps = self._maps
        other._agent, other._denoiser = self._agent, self._denoiser
        return other

    def map_context(self, road: RoadDescription) -> tuple[MapGeometry, torch.Tensor]:
        """(`MapGeometry`, ``z_global [1, N_LATENTS, D]``) of ``road``, built on first use and cached."""
        entry = self._map_entry(road)
        return entry[1], entry[2]

    def _map_entry(self, road: RoadDescription) -> MapEntry:
        """The cached (road, `MapGeometry`, ``z_global``, read-out keys and values) of ``road``."""
        hit = self._maps.get(id(road))
        if hit is None or hit[0] is not road:
            if len(self._maps) >= MAP_CACHE_SIZE:
                self._maps.pop(next(iter(self._maps)))
            geo = build_map_geometry(road)
            with torch.inference_mode():
                tokens = torch.from_numpy(geo.tokens)[None]
                z = self.net.map(tokens, torch.from_numpy(anchor_encoding(geo.tokens))[None])
                kv = self.net.agent.latent_kv(z)
            hit = (road, geo, z, kv)
            self._maps[id(road)] = hit
            self.map_builds += 1
        return hit

    def reset(self, scenario: Scenario, rng: np.random.Generator, driven: np.ndarray) -> None:
        super().reset(scenario, rng, driven)
        _, self._geo, self._z, self._kv = self._map_entry(scenario.road)
        self._gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
        self._prev: np.ndarray | None = None

    def accelerations(self, t: int, cur: np.ndarray, rows: np.ndarray) -> np.ndarray:
        prev = self._prev
        prev_ok = np.zeros(rows.size, dtype=bool) if prev is None else prev[rows, VALID] > 0.5
        prev_vel = cur[rows][:, [VX, VY]] if prev is None else np.where(
            prev_ok[:, None], prev[rows][:, [VX, VY]], cur[rows][:, [VX, VY]])
        desired = self.intent.desired_at(t, rows)
        dest = self.intent.destination_xy[rows]
        logged = self.log[:, t]
        # the logged tracks as routes: the safety bound's obstacles are `safety_obstacles` (issue 22 follow-up)
        scan = scan_pairs(cur, rows, logged, social_constants(self.guidance), self.log, t)
        tab = agent_input_tables(self._geo, cur, rows, prev_vel, prev_ok, desired, dest, scan)
        targets = physics_targets(self._geo, cur, rows, desired, dest, self.guidance, logged, scan, tab.edge_xy)
        with torch.inference_mode():
            as_t = torch.from_numpy  # no copy
            ctx = self._agent.tables(as_t(tab.own), as_t(tab.opt), as_t(tab.masks), as_t(tab.neighbors),
                                     as_t(tab.neighbor_mask), self._kv)
            acc = ddim_sample(self._denoiser, ctx, self.alpha_bar, self.ddim_steps, self._gen,
                              {k: torch.from_numpy(v.astype(np.float32)) for k, v in targets.items()},
                              self.guidance, self.temperature).numpy().astype(np.float64) * ACC_SCALE_MPS2
        self._prev = cur.copy()
        c, s = np.cos(cur[rows, HEADING]), np.sin(cur[rows, HEADING])
        return np.column_stack([c * acc[:, 0] - s * acc[:, 1], s * acc[:, 0] + c * acc[:, 1]])


def load_rapid(path: str | Path, guidance: dict[str, Any] | None = None, ddim_steps: int = 5,
               temperature: float = 1.0) -> RapidBackground:
    """A `RapidBackground` from a `seal fit background` model file; ``guidance`` overrides `Guidance` fields
    (unknown names raise `SealError` naming them)."""
    net, _ = load_rapid_net(Path(path))
    g = Guidance()
    if guidance:
        known = set(vars(g))
        unknown = sorted(set(guidance) - known)
        if unknown:
            raise SealError(f"RAPID guidance: unknown option(s) {unknown}; known: {sorted(known)}")
        g = replace(g, **{k: float(v) for k, v in guidance.items()})
    return RapidBackground(net, g, ddim_steps, temperature)
