"""Featurisation of the trajectory prior: agent-centric, normalised inputs for a batch of (scenario, agent) targets.

A target is one agent of one scenario. Its frame has the origin at the agent's position at `CURRENT_STEP`
and +x along its heading there. The inputs are

* agent tokens: the 1.1 s history (11 steps) of the target and of its ``n_agents - 1`` nearest other agents
  (distance at their last valid history step), target first;
* lane tokens: the ``n_chunks`` lane-centreline chunks (`seal.models.prior.lanes`) nearest to the segment from the
  target to where constant velocity puts it ``lookahead_s`` later (so a fast agent sees the road ahead).

`build_tables` turns scenarios into world-frame lookup tables plus per-target indices (numpy, once per
scenario); `featurise` gathers a batch and transforms it into the target frame (torch, vectorised), so
training and `TrajectoryPrior.predict` share one code path. Row 0 of every table is padding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import torch

from seal.core.scenario import (
    AGENT_TYPES,
    CURRENT_STEP,
    HEADING,
    LENGTH,
    N_HISTORY,
    VALID,
    VX,
    VY,
    WIDTH,
    Scenario,
    X,
    Y,
)
from seal.models.prior.lanes import CHUNK_ATTRS, ChunkCache

#: History fields per step in the world table: x, y (m), heading (rad), vx, vy (m/s), valid.
HIST_FIELDS = 6
#: Static fields per agent: length, width (m), agent-type one-hot.
STATIC_FIELDS = 2 + len(AGENT_TYPES)
#: Agent token input size: 7 features x 11 steps, the static fields and an is-target flag.
AGENT_FEATURES = 7 * N_HISTORY + STATIC_FIELDS + 1


@dataclass(frozen=True)
class FeatureConfig:
    """What the prior sees.

    Attributes:
        n_agents: agent tokens per target, the target included.
        n_chunks: lane-chunk tokens per target.
        chunk_length_m: arc length of one lane chunk (m).
        chunk_points: points per lane chunk.
        lookahead_s: chunks are ranked by distance to the target's constant-velocity path over this horizon (s).
        pos_scale_m: positions are divided by this (m).
        vel_scale_mps: velocities are divided by this (m/s).
    """

    n_agents: int = 16
    n_chunks: int = 32
    chunk_length_m: float = 20.0
    chunk_points: int = 9
    lookahead_s: float = 4.0
    pos_scale_m: float = 20.0
    vel_scale_mps: float = 10.0

    @property
    def chunk_features(self) -> int:
        return 4 * self.chunk_points + len(CHUNK_ATTRS)

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


@dataclass
class ContextTables:
    """World-frame tables and per-target indices for a set of targets (row 0 of each table is padding).

    Attributes:
        agent_hist: ``[NA + 1, 11, 6]`` float32 histories (x, y, heading, vx, vy, valid), zero where invalid.
        agent_static: ``[NA + 1, 6]`` float32 length (m), width (m), agent-type one-hot.
        chunk_points: ``[NC + 1, P, 2]`` float32 lane chunk points (m).
        chunk_dir: ``[NC + 1, P]`` float32 driving direction (rad).
        chunk_attrs: ``[NC + 1, len(CHUNK_ATTRS)]`` float32.
        agent_idx: ``[S, n_agents]`` int64 rows of `agent_hist` (0 = no agent), the target first.
        chunk_idx: ``[S, n_chunks]`` int64 rows of `chunk_points` (0 = no chunk).
        pose: ``[S, 3]`` float64 target frame: origin x, y (m) and heading (rad), world frame.
        start: ``[S, 2]`` float32 target speed (m/s) and direction of travel relative to its heading (rad).
        road_points: ``[NR + 1, P, 2]`` float32 chunk points of the roads with their map edges opened
            (`seal.models.prior.lanes.open_map_edges`), for the training loss that keeps candidates on the road; None
            unless requested.
        road_idx: ``[S, R]`` int64 rows of `road_points` around the road each target can reach (0 = none).
    """

    agent_hist: torch.Tensor
    agent_static: torch.Tensor
    chunk_points: torch.Tensor
    chunk_dir: torch.Tensor
    chunk_attrs: torch.Tensor
    agent_idx: torch.Tensor
    chunk_idx: torch.Tensor
    pose: np.ndarray
    start: torch.Tensor
    road_points: torch.Tensor | None = None
    road_idx: torch.Tensor | None = None

    @property
    def n_targets(self) -> int:
        return int(self.agent_idx.shape[0])


def history_steps(scenario: Scenario, agent_index: int) -> int:
    """Number of valid history steps (0..11) of one agent."""
    return int(scenario.valid[agent_index, :N_HISTORY].sum())


def _select_agents(hist: np.ndarray, targets: np.ndarray, n_agents: int) -> np.ndarray:
    """Local agent indices ``[len(targets), n_agents]`` (-1 = none), each row starting with its target."""
    valid = hist[:, :, 5] > 0.5  # [A, 11]
    present = valid.any(axis=1)
    last = N_HISTORY - 1 - np.argmax(valid[:, ::-1], axis=1)
    last_xy = hist[np.arange(hist.shape[0]), last, :2]  # [A, 2]
    dist = np.linalg.norm(last_xy[targets][:, None, :] - last_xy[None, :, :], axis=-1)  # [T, A]
    dist[:, ~present] = np.inf
    dist[np.arange(len(targets)), targets] = -1.0  # the target comes first
    order = np.argsort(dist, axis=1, kind="stable")[:, :n_agents]
    chosen = np.take_along_axis(dist, order, axis=1)
    order = np.where(np.isfinite(chosen), order, -1)
    if order.shape[1] < n_agents:
        order = np.pad(order, ((0, 0), (0, n_agents - order.shape[1])), constant_values=-1)
    return order


def _select_chunks(points: np.ndarray, seg_a: np.ndarray, seg_b: np.ndarray, n_chunks: int) -> np.ndarray:
    """Local chunk indices ``[T, n_chunks]`` (-1 = none) nearest to the segments ``seg_a -> seg_b`` ``[T, 2]``."""
    d = seg_b - seg_a  # [T, 2]
    rel = points[None, :, :, :] - seg_a[:, None, None, :]  # [T, C, P, 2]
    denom = np.maximum((d * d).sum(-1), 1e-9)[:, None, None]
    t = np.clip((rel * d[:, None, None, :]).sum(-1) / denom, 0.0, 1.0)
    dist = np.linalg.norm(rel - t[..., None] * d[:, None, None, :], axis=-1).min(axis=2)  # [T, C]
    k = min(n_chunks, dist.shape[1])
    order = np.argsort(dist, axis=1, kind="stable")[:, :k]
    if k < n_chunks:
        order = np.pad(order, ((0, 0), (0, n_chunks - k)), constant_values=-1)
    return order


def scenario_history(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """World-frame history table ``[A, 11, 6]`` and static table ``[A, 6]`` of one scenario."""
    tr = scenario.tracks[:, :N_HISTORY]
    valid = tr[:, :, VALID : VALID + 1]
    hist = np.concatenate([tr[:, :, [X, Y, HEADING, VX, VY]], valid], axis=-1) * valid
    types = np.zeros((scenario.n_agents, len(AGENT_TYPES)), dtype=np.float32)
    types[np.arange(scenario.n_agents), [AGENT_TYPES.index(t) for t in scenario.agent_types]] = 1.0
    cur = scenario.tracks[:, CURRENT_STEP]
    # Size from the current step where valid, else from the last valid history step.
    last = N_HISTORY - 1 - np.argmax(tr[:, ::-1, VALID] > 0.5, axis=1)
    size = tr[np.arange(scenario.n_agents), last][:, [LENGTH, WIDTH]]
    size = np.where(cur[:, VALID : VALID + 1] > 0.5, cur[:, [LENGTH, WIDTH]], size)
    return hist.astype(np.float32), np.concatenate([size, types], axis=1).astype(np.float32)


def _checked_targets(scenario: Scenario, agents: Sequence[int] | np.ndarray) -> np.ndarray:
    """``agents`` as an int64 index array ``[T]``; `ValueError` naming the scenario and agent for an index out of
    range or an agent not valid at `CURRENT_STEP`."""
    tgt = np.asarray(agents, dtype=np.int64).reshape(-1)
    if tgt.size == 0:
        return tgt
    bad = (tgt < 0) | (tgt >= scenario.n_agents)
    if bad.any():
        raise ValueError(
            f"scenario {scenario.scenario_id!r}: agent index {int(tgt[bad][0])} out of range "
            f"(scenario has {scenario.n_agents} agents)"
        )
    not_current = ~scenario.valid[tgt, CURRENT_STEP]
    if not_current.any():
        a = int(tgt[not_current][0])
        raise ValueError(
            f"scenario {scenario.scenario_id!r}: agent {int(scenario.agent_ids[a])} (index {a}) is not valid at "
            f"the current step {CURRENT_STEP}; the prior predicts only agents present now"
        )
    return tgt


def _padded_rows(parts: list[np.ndarray], pad_shape: tuple[int, ...], dtype: type = np.float32) -> torch.Tensor:
    """``parts`` stacked row-wise under one zero padding row (index 0 = "none"), as a tensor of ``dtype``."""
    rows = [np.zeros((1, *pad_shape)), *parts]
    return torch.from_numpy(np.concatenate(rows).astype(dtype))


def build_tables(
    scenarios: Sequence[Scenario], targets: Sequence[Sequence[int] | np.ndarray], cfg: FeatureConfig,
    cache: ChunkCache | None = None, road_chunks: int = 0, road_lookahead_s: float = 8.0,
) -> ContextTables:
    """Tables for the targets ``targets[k]`` (agent indices) of ``scenarios[k]``, in that order.

    Every target must be valid at `CURRENT_STEP` (`ValueError` naming the scenario and agent otherwise). With
    ``road_chunks > 0`` also `ContextTables.road_points` / ``road_idx``: per target the chunks (of the road with
    open map edges) nearest to the constant-velocity path over ``road_lookahead_s`` (s).
    """
    if len(scenarios) != len(targets):
        raise ValueError(f"build_tables: {len(scenarios)} scenarios but {len(targets)} target lists")
    cache = cache or ChunkCache(cfg.chunk_length_m, cfg.chunk_points)
    hists, statics, c_pts, c_dir, c_attr, a_idx, c_idx, poses, starts = [], [], [], [], [], [], [], [], []
    r_pts: list[np.ndarray] = []
    r_idx: list[np.ndarray] = []
    road_cache = ChunkCache(cfg.chunk_length_m, cfg.chunk_points, open_edges=True) if road_chunks > 0 else None
    agent_offset, chunk_offset, road_offset = 1, 1, 1
    for scenario, agents in zip(scenarios, targets, strict=True):
        tgt = _checked_targets(scenario, agents)
        if tgt.size == 0:
            continue
        hist, static = scenario_history(scenario)
        chunks = cache.get(scenario.road)
        cur = hist[tgt, CURRENT_STEP]  # [T, 6]
        pos = cur[:, :2].astype(np.float64)
        vel = cur[:, 3:5].astype(np.float64)
        local_a = _select_agents(hist, tgt, cfg.n_agents)
        local_c = _select_chunks(chunks.points, pos, pos + cfg.lookahead_s * vel, cfg.n_chunks)
        a_idx.append(np.where(local_a >= 0, local_a + agent_offset, 0))
        c_idx.append(np.where(local_c >= 0, local_c + chunk_offset, 0))
        if road_cache is not None:
            open_chunks = road_cache.get(scenario.road)
            local_r = _select_chunks(open_chunks.points, pos, pos + road_lookahead_s * vel, road_chunks)
            r_idx.append(np.where(local_r >= 0, local_r + road_offset, 0))
            r_pts.append(open_chunks.points)
            road_offset += open_chunks.n_chunks
        hists.append(hist)
        statics.append(static)
        c_pts.append(chunks.points)
        c_dir.append(chunks.direction)
        c_attr.append(chunks.attrs)
        agent_offset += hist.shape[0]
        chunk_offset += chunks.n_chunks
        heading = scenario.tracks[tgt, CURRENT_STEP, HEADING].astype(np.float64)
        poses.append(np.stack([pos[:, 0], pos[:, 1], heading], axis=1))
        speed = np.hypot(vel[:, 0], vel[:, 1])
        course = np.where(speed > 0.1, np.arctan2(vel[:, 1], vel[:, 0]) - heading, 0.0)
        starts.append(np.stack([speed, np.arctan2(np.sin(course), np.cos(course))], axis=1))

    p = cfg.chunk_points
    return ContextTables(
        agent_hist=_padded_rows(hists, (N_HISTORY, HIST_FIELDS)),
        agent_static=_padded_rows(statics, (STATIC_FIELDS,)),
        chunk_points=_padded_rows(c_pts, (p, 2)),
        chunk_dir=_padded_rows(c_dir, (p,)),
        chunk_attrs=_padded_rows(c_attr, (len(CHUNK_ATTRS),)),
        agent_idx=torch.from_numpy(np.concatenate(a_idx) if a_idx else np.zeros((0, cfg.n_agents), np.int64)),
        chunk_idx=torch.from_numpy(np.concatenate(c_idx) if c_idx else np.zeros((0, cfg.n_chunks), np.int64)),
        pose=np.concatenate(poses) if poses else np.zeros((0, 3)),
        start=torch.from_numpy(np.concatenate(starts).astype(np.float32) if starts else np.zeros((0, 2), np.float32)),
        road_points=_padded_rows(r_pts, (p, 2)) if r_pts else None,
        road_idx=torch.from_numpy(np.concatenate(r_idx)) if r_idx else None,
    )


def featurise(tables: ContextTables, rows: torch.Tensor | slice, cfg: FeatureConfig) -> dict[str, torch.Tensor]:
    """Normalised target-frame inputs for the targets ``rows`` of ``tables``.

    Returns:
        ``agents`` ``[B, n_agents, AGENT_FEATURES]``, ``agent_mask`` ``[B, n_agents]`` (True = token present),
        ``chunks`` ``[B, n_chunks, cfg.chunk_features]``, ``chunk_mask`` ``[B, n_chunks]``, ``start`` ``[B, 2]``.
    """
    a_idx = tables.agent_idx[rows]
    c_idx = tables.chunk_idx[rows]
    pose = torch.from_numpy(tables.pose[rows.numpy() if isinstance(rows, torch.Tensor) else rows]).float()
    b = a_idx.shape[0]
    ox, oy, oh = pose[:, 0].view(b, 1, 1), pose[:, 1].view(b, 1, 1), pose[:, 2].view(b, 1, 1)
    cos, sin = torch.cos(oh), torch.sin(oh)

    hist = tables.agent_hist[a_idx]  # [B, N, 11, 6]
    valid = hist[..., 5]
    dx, dy = hist[..., 0] - ox, hist[..., 1] - oy
    x = (cos * dx + sin * dy) * valid / cfg.pos_scale_m
    y = (-sin * dx + cos * dy) * valid / cfg.pos_scale_m
    dh = hist[..., 2] - oh
    vx = (cos * hist[..., 3] + sin * hist[..., 4]) / cfg.vel_scale_mps
    vy = (-sin * hist[..., 3] + cos * hist[..., 4]) / cfg.vel_scale_mps
    steps = torch.stack([x, y, torch.cos(dh) * valid, torch.sin(dh) * valid, vx, vy, valid], dim=-1)
    static = tables.agent_static[a_idx].clone()  # [B, N, 6]
    static[..., 0] /= 5.0
    static[..., 1] /= 2.0
    is_target = torch.zeros(b, a_idx.shape[1], 1)  # row 0 is always the target
    is_target[:, 0] = 1.0
    agents = torch.cat([steps.flatten(2), static, is_target], dim=-1)

    pts = tables.chunk_points[c_idx]  # [B, M, P, 2]
    px, py = pts[..., 0] - ox, pts[..., 1] - oy
    cx = (cos * px + sin * py) / cfg.pos_scale_m
    cy = (-sin * px + cos * py) / cfg.pos_scale_m
    cdir = tables.chunk_dir[c_idx] - oh
    attrs = tables.chunk_attrs[c_idx].clone()
    attrs[..., 0] /= 4.0
    attrs[..., 1] /= 20.0
    chunk_mask = c_idx > 0
    chunks = torch.cat([torch.stack([cx, cy, torch.cos(cdir), torch.sin(cdir)], dim=-1).flatten(2), attrs], dim=-1)
    chunks = chunks * chunk_mask[..., None]
    return {
        "agents": agents * (a_idx > 0)[..., None],
        "agent_mask": a_idx > 0,
        "chunks": chunks,
        "chunk_mask": chunk_mask,
        "start": tables.start[rows],
    }


def road_points(tables: ContextTables, rows: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Lane-centreline points ``[B, R * P, 2]`` (m, each target's frame) of `ContextTables.road_idx` and their
    mask ``[B, R * P]`` (True = a real point)."""
    if tables.road_idx is None or tables.road_points is None:
        raise ValueError("road_points: the tables were built without road_chunks")
    idx = tables.road_idx[rows]  # [B, R]
    pose = torch.from_numpy(tables.pose[rows.numpy()]).float()
    pts = tables.road_points[idx].flatten(1, 2)  # [B, R * P, 2]
    d = pts - pose[:, None, :2]
    c, s = torch.cos(pose[:, 2])[:, None], torch.sin(pose[:, 2])[:, None]
    local = torch.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], dim=-1)
    mask = (idx > 0)[..., None].expand(-1, -1, tables.road_points.shape[1]).flatten(1)
    return local, mask
