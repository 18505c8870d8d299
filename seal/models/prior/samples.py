"""Training and evaluation samples of the prior: (scenario, agent) targets with their futures in the target frame."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from seal.core.scenario import CURRENT_STEP, N_HISTORY, VALID, Scenario, X, Y
from seal.models.prior.features import ContextTables, FeatureConfig, build_tables
from seal.models.prior.lanes import ChunkCache


@dataclass(frozen=True)
class TargetFilter:
    """Which agents are targets.

    Attributes:
        min_history_steps: valid history steps needed (the current one included).
        min_future_steps: valid future steps needed (1..80); 80 = the full 8 s.
        min_path_m: path length over all valid steps needed, so parked agents do not dominate (m).
        adversary_only: only each scenario's adversary (still subject to the thresholds above).
    """

    min_history_steps: int = 2
    min_future_steps: int = 10
    min_path_m: float = 1.0
    adversary_only: bool = False


def select_targets(scenario: Scenario, filt: TargetFilter) -> np.ndarray:
    """Agent indices of ``scenario`` that pass ``filt``."""
    valid = scenario.valid
    xy = scenario.tracks[:, :, [X, Y]].astype(np.float64)
    step = np.linalg.norm(np.diff(xy, axis=1), axis=-1) * (valid[:, 1:] & valid[:, :-1])
    ok = (
        valid[:, CURRENT_STEP]
        & (valid[:, :N_HISTORY].sum(axis=1) >= filt.min_history_steps)
        & (valid[:, N_HISTORY:].sum(axis=1) >= filt.min_future_steps)
        & (step.sum(axis=1) >= filt.min_path_m)
    )
    if filt.adversary_only:
        keep = np.zeros_like(ok)
        keep[scenario.adv_index] = True
        ok &= keep
    return np.flatnonzero(ok)


def future_in_frame(scenario: Scenario, agents: np.ndarray, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Futures ``[T, 80, 2]`` (m, each target's frame, zero where invalid) and validity ``[T, 80]``."""
    fut = scenario.tracks[agents, N_HISTORY:]
    valid = fut[:, :, VALID] > 0.5
    d = fut[:, :, [X, Y]].astype(np.float64) - pose[:, None, :2]
    c, s = np.cos(pose[:, 2])[:, None], np.sin(pose[:, 2])[:, None]
    local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
    return np.where(valid[..., None], local, 0.0), valid


@dataclass
class SampleSet:
    """Targets with inputs (``tables``) and ground-truth futures.

    Attributes:
        tables: featurisation tables, one row per target.
        future: ``[S, 80, 2]`` float32 future positions in each target's frame (m), zero where invalid.
        future_valid: ``[S, 80]`` bool.
        scenario_index: ``[S]`` index into the scenario list the set was built from.
        agent_index: ``[S]`` agent index within its scenario.
    """

    tables: ContextTables
    future: torch.Tensor
    future_valid: torch.Tensor
    scenario_index: np.ndarray
    agent_index: np.ndarray

    def __len__(self) -> int:
        return int(self.future.shape[0])


def build_samples(
    scenarios: Sequence[Scenario], cfg: FeatureConfig, filt: TargetFilter | None = None,
    cache: ChunkCache | None = None, road_chunks: int = 0,
) -> SampleSet:
    """Every target (per ``filt``) of ``scenarios`` with its inputs and future (and ``road_chunks`` road chunks
    per target for the on-road loss, see `build_tables`)."""
    filt = filt or TargetFilter()
    targets = [select_targets(s, filt) for s in scenarios]
    tables = build_tables(scenarios, targets, cfg, cache, road_chunks=road_chunks)
    futures, valids, s_idx = [], [], []
    offset = 0
    for k, (scenario, tgt) in enumerate(zip(scenarios, targets, strict=True)):
        fut, valid = future_in_frame(scenario, tgt, tables.pose[offset : offset + len(tgt)])
        futures.append(fut)
        valids.append(valid)
        s_idx.append(np.full(len(tgt), k))
        offset += len(tgt)
    if offset == 0:
        raise ValueError(f"no targets pass {filt} in {len(scenarios)} scenarios")
    return SampleSet(
        tables=tables,
        future=torch.from_numpy(np.concatenate(futures).astype(np.float32)),
        future_valid=torch.from_numpy(np.concatenate(valids)),
        scenario_index=np.concatenate(s_idx),
        agent_index=np.concatenate(targets),
    )
