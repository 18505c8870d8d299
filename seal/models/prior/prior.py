"""`TrajectoryPrior`: the trained prior pi_gen behind one object — load / save, candidates, per-agent latents."""

from __future__ import annotations

import io
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.atomic import atomic_write_bytes
from seal.core.road import RoadDescription
from seal.core.scenario import CURRENT_STEP, Scenario
from seal.core.weights_file import check_header, read_weights_file
from seal.models.prior.baseline import constant_velocity_candidates
from seal.models.prior.candidates import Candidates
from seal.models.prior.features import ContextTables, build_tables, featurise, history_steps
from seal.models.prior.lanes import ChunkCache
from seal.models.prior.network import PriorConfig, PriorNet
from seal.models.prior.road_projection import GridCache, RoadProjection, project_to_road

FORMAT = "seal-trajectory-prior"
FORMAT_VERSION = 1
MIN_HISTORY_STEPS = 2


class PriorFileError(ValueError):
    """A model file cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class Encoding:
    """Encoder output for a batch of targets (see `TrajectoryPrior.encode`).

    Attributes:
        tokens: ``[B, n_agents + n_chunks, d_model]`` scene tokens after the encoder; ``tokens[:, :n_agents]``
            are the per-agent latents in each target's frame, the target's own latent at index 0.
        mask: ``[B, n_agents + n_chunks]`` True where a token is present.
        start: ``[B, 2]`` each target's speed (m/s) and direction of travel relative to its heading (rad).
        pose: ``[B, 3]`` each target's frame in the world: origin x, y (m), heading (rad).
        agent_index: ``[B, n_agents]`` scenario agent index of each agent token (-1 = padding).
        n_agents: number of agent tokens.
    """

    tokens: torch.Tensor
    mask: torch.Tensor
    start: torch.Tensor
    pose: np.ndarray
    agent_index: np.ndarray
    n_agents: int

    @property
    def agent_latents(self) -> torch.Tensor:
        """``[B, n_agents, d_model]`` per-agent latents (padding rows are meaningless; see `mask`)."""
        return self.tokens[:, : self.n_agents]

    @property
    def target_latent(self) -> torch.Tensor:
        """``[B, d_model]`` the latent of each target agent."""
        return self.tokens[:, 0]

    def with_target_offset(self, offset: torch.Tensor) -> Encoding:
        """A copy with ``offset`` (``[d_model]`` or ``[B, d_model]``) added to each target's latent: the hook for
        latent steering / control vectors."""
        tokens = self.tokens.clone()
        tokens[:, 0] = tokens[:, 0] + offset
        return Encoding(tokens, self.mask, self.start, self.pose, self.agent_index, self.n_agents)


class TrajectoryPrior:
    """A trained multimodal trajectory prior (CPU, inference mode).

    Args:
        net: the network.
        training: JSON-serialisable summary of how it was trained (recorded in the saved file).

    Attributes:
        road_projection: when set, `predict` projects its candidates on the road
            (`seal.models.prior.road_projection`; `default_road_projection`). None by default, so CAT, SEAL and
            ``seal eval prior`` see the decoder's own candidates; it is a setting of the caller, not of the file.
    """

    def __init__(self, net: PriorNet, training: dict[str, Any] | None = None) -> None:
        self.net = net.eval()
        self.config: PriorConfig = net.cfg
        # JSON round trip: the summary must hold only types torch.load(weights_only=True) accepts.
        self.training: dict[str, Any] = json.loads(json.dumps(training or {}, default=_jsonable))
        self._cache = ChunkCache(self.config.features.chunk_length_m, self.config.features.chunk_points)
        self.road_projection: RoadProjection | None = None
        self._grids = GridCache()

    @classmethod
    def untrained(cls, config: PriorConfig | None = None, seed: int = 0) -> TrajectoryPrior:
        """A randomly initialised prior (for benchmarks of latency and for tests)."""
        torch.manual_seed(seed)
        return cls(PriorNet(config or PriorConfig()), training={"trained": False, "seed": seed})

    @property
    def n_candidates(self) -> int:
        return self.config.n_modes

    # ---------------------------------------------------------------------------------------------- files
    def state(self) -> dict[str, Any]:
        """What `save` writes: format tag, config, weights and training summary (torch.load-safe types only)."""
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "config": self.config.to_dict(),
            "state_dict": {k: v.detach().clone() for k, v in self.net.state_dict().items()},
            "training": self.training,
        }

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the model atomically (a reader sees the old file or the new one, never half of it)."""
        buf = io.BytesIO()
        torch.save(self.state(), buf)
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def from_state(cls, state: dict[str, Any], where: str = "model") -> TrajectoryPrior:
        check_header(state, where, FORMAT, FORMAT_VERSION, ("config", "state_dict"), PriorFileError,
                     " (not a seal trajectory prior)")
        try:
            cfg = PriorConfig.from_dict(state["config"])
        except (TypeError, ValueError) as exc:
            raise PriorFileError(f"{where}: field 'config' is invalid ({exc})") from None
        net = PriorNet(cfg)
        try:
            net.load_state_dict(state["state_dict"])
        except RuntimeError as exc:
            raise PriorFileError(f"{where}: field 'state_dict' does not match the config ({exc})") from None
        return cls(net, training=state.get("training", {}))

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> TrajectoryPrior:
        """Load a model written by `save` (``torch.load(weights_only=True)``: no arbitrary unpickling)."""
        path = Path(path)
        state = read_weights_file(path, "model file", "seal fit prior", PriorFileError)
        return cls.from_state(state, where=f"model file {path}")

    # ---------------------------------------------------------------------------------------------- inference
    def tables(self, scenarios: Sequence[Scenario], agent_indices: Sequence[int]) -> ContextTables:
        """Featurisation tables for one target per scenario."""
        return build_tables(scenarios, [[int(a)] for a in agent_indices], self.config.features, self._cache)

    def _targets(self, scenarios: Sequence[Scenario], agent_indices: Sequence[int] | None) -> list[int]:
        if agent_indices is None:
            return [s.adv_index for s in scenarios]
        if len(agent_indices) != len(scenarios):
            raise ValueError(f"predict: {len(scenarios)} scenarios but {len(agent_indices)} agent indices")
        return [int(a) for a in agent_indices]

    @torch.no_grad()
    def encode(self, scenarios: Sequence[Scenario], agent_indices: Sequence[int] | None = None) -> Encoding:
        """Encoder output (per-agent latents) for one target per scenario (default: each adversary).

        Targets need `MIN_HISTORY_STEPS` valid history steps (`ValueError` otherwise; `predict` falls back).
        """
        targets = self._targets(scenarios, agent_indices)
        for s, a in zip(scenarios, targets, strict=True):
            self._check_history(s, a)
        tables = self.tables(scenarios, targets)
        feats = featurise(tables, slice(None), self.config.features)
        tokens, mask = self.net.encode(feats)
        agent_rows = tables.agent_idx.numpy()
        # Table rows -> scenario agent indices: row r of scenario k's block is agent r - offset_k.
        offsets = np.cumsum([0] + [s.n_agents for s in scenarios[:-1]]) + 1
        agent_index = np.where(agent_rows > 0, agent_rows - offsets[:, None], -1)
        return Encoding(tokens, mask, feats["start"], tables.pose, agent_index, self.config.features.n_agents)

    @torch.no_grad()
    def decode(self, encoding: Encoding) -> tuple[np.ndarray, np.ndarray]:
        """Candidates of an `Encoding`: world-frame positions ``[B, K, 80, 2]`` (m) and probabilities ``[B, K]``."""
        xy, logits = self.net.decode(encoding.tokens, encoding.mask, encoding.start)
        return to_world(xy.double().numpy(), encoding.pose), torch.softmax(logits.double(), dim=1).numpy()

    def default_road_projection(self) -> RoadProjection:
        """`RoadProjection` with this prior's yaw-rate limit (re-driven candidates stay within its limits)."""
        return RoadProjection(yaw_rate_limit_rps=self.config.yaw_rate_limit_rps)

    def project(self, xy: np.ndarray, pose: np.ndarray, start: np.ndarray, scenarios: Sequence[Scenario],
                cfg: RoadProjection | None = None) -> np.ndarray:
        """World-frame candidates ``xy [B, K, T, 2]`` (m) of targets with frames ``pose [B, 3]`` and ``start
        [B, 2]`` (speed m/s, direction of travel relative to the heading, rad) projected on the roads of
        ``scenarios`` (`project_agent` per target)."""
        out = np.empty(np.shape(xy), np.float64)
        for b, scenario in enumerate(scenarios):
            out[b] = self.project_agent(xy[b], pose[b], start[b], scenario.road, cfg)
        return out

    def project_agent(self, xy: np.ndarray, pose: np.ndarray, start: np.ndarray, road: RoadDescription,
                      cfg: RoadProjection | None = None) -> np.ndarray:
        """Candidates ``xy [K, T, 2]`` (world, m) of one target with frame ``pose [3]`` and ``start [2]`` projected
        on ``road`` (`seal.models.prior.road_projection.project_to_road`; ``cfg`` None: `road_projection`, else
        `default_road_projection`)."""
        cfg = cfg or self.road_projection or self.default_road_projection()
        course = float(pose[2]) + float(start[1])
        return project_to_road(xy, np.asarray(pose[:2], np.float64), course, self._grids.get(road), cfg)[0]

    @staticmethod
    def _check_present(scenario: Scenario, agent_index: int) -> None:
        if not 0 <= agent_index < scenario.n_agents:
            raise ValueError(
                f"scenario {scenario.scenario_id!r}: agent index {agent_index} out of range "
                f"({scenario.n_agents} agents)"
            )
        if not scenario.valid[agent_index, CURRENT_STEP]:
            raise ValueError(
                f"scenario {scenario.scenario_id!r}: agent {int(scenario.agent_ids[agent_index])} (index "
                f"{agent_index}) is not valid at the current step {CURRENT_STEP}; nothing to predict from"
            )

    @classmethod
    def _check_history(cls, scenario: Scenario, agent_index: int) -> None:
        cls._check_present(scenario, agent_index)
        n = history_steps(scenario, agent_index)
        if n < MIN_HISTORY_STEPS:
            raise ValueError(
                f"scenario {scenario.scenario_id!r}: agent {int(scenario.agent_ids[agent_index])} (index "
                f"{agent_index}) has {n} valid history step(s); the prior needs at least {MIN_HISTORY_STEPS}"
            )

    def predict(
        self, scenarios: Sequence[Scenario], agent_indices: Sequence[int] | None = None, fallback: bool = True
    ) -> list[Candidates]:
        """Candidate futures, one `Candidates` per scenario, in the scenario's world frame.

        Args:
            scenarios: the scenarios (one batch; no gradient, CPU).
            agent_indices: the agent to predict in each scenario (default: each scenario's adversary).
            fallback: an agent with fewer than `MIN_HISTORY_STEPS` valid history steps gets constant-velocity
                candidates (a fan of 32, see `constant_velocity_candidates`; `Candidates.fallback` says why)
                when True, and a `ValueError` naming scenario and agent when False. An agent that is not valid
                at the current step, or an index out of range, always raises `ValueError`.

        Returns:
            ``Candidates`` with ``n_modes`` (32) candidates x 80 steps, most probable first (projected on the road
            when `road_projection` is set).
        """
        targets = self._targets(scenarios, agent_indices)
        out: list[Candidates | None] = [None] * len(scenarios)
        net_rows: list[int] = []
        for k, (s, a) in enumerate(zip(scenarios, targets, strict=True)):
            self._check_present(s, a)
            try:
                self._check_history(s, a)
            except ValueError as exc:
                if not fallback:
                    raise
                out[k] = constant_velocity_candidates(s, a, self.n_candidates, fallback=str(exc))
                continue
            net_rows.append(k)
        if net_rows:
            enc = self.encode([scenarios[k] for k in net_rows], [targets[k] for k in net_rows])
            xy, probs = self.decode(enc)
            if self.road_projection is not None:
                xy = self.project(xy, enc.pose, enc.start.numpy(), [scenarios[k] for k in net_rows])
            for j, k in enumerate(net_rows):
                out[k] = Candidates.from_positions(
                    xy[j], probs[j], enc.pose[j, :2], float(enc.pose[j, 2]), targets[k]
                )
        return [c for c in out if c is not None]


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    return str(value)


def to_world(xy_local: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Target-frame positions ``[B, ..., 2]`` to the world frame with poses ``[B, 3]`` (x, y, heading)."""
    c = np.cos(pose[:, 2]).reshape(-1, *([1] * (xy_local.ndim - 2)))
    s = np.sin(pose[:, 2]).reshape(c.shape)
    x, y = xy_local[..., 0], xy_local[..., 1]
    ox = pose[:, 0].reshape(c.shape)
    oy = pose[:, 1].reshape(c.shape)
    return np.stack([ox + c * x - s * y, oy + s * x + c * y], axis=-1)
