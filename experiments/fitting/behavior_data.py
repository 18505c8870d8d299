"""Samples of ``seal fit behavior``: everyday behaviours with SafeShift labels, and the crash set.

* Everyday behaviours (thesis 7.3.2): every agent of a split's scenarios that is valid at `CURRENT_STEP` and on at
  least ``min_valid_rows`` sub-sampled rows; its label comes from ``diff = traj_gt - traj_fe`` of the dataset's
  SafeShift scores (`seal.scoring.store`, ``seal data score``), discretised with ``delta`` (eq. 7.1) chosen on the
  training samples for even classes and reused for the held-out ones.
* Crash set (thesis 7.2 analogue, `seal.models.behavior.crash_set`): the logged pairs of the training split that
  collide or nearly do, plus those of any extra datasets (imported recordings), labelled by cause and reaction.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.dataset import load_split
from seal.core.scenario import Scenario
from seal.models.behavior.crash_set import CrashSetConfig, crash_samples
from seal.models.behavior.features import BehaviorFeatureConfig, BehaviorInputs, scene_inputs, scene_targets
from seal.models.behavior.labels import SAFETY_CLASSES, class_shares, even_delta, safety_labels


@dataclass
class SampleSet:
    """Inputs, labels and where each sample comes from."""

    inputs: BehaviorInputs
    labels: np.ndarray
    diff: np.ndarray
    scenario_ids: list[str]

    def __len__(self) -> int:
        return len(self.inputs)

    def take(self, rows: np.ndarray) -> SampleSet:
        return SampleSet(self.inputs.take(rows), self.labels[rows], self.diff[rows],
                         [self.scenario_ids[i] for i in rows])

    def summary(self) -> dict[str, Any]:
        shares = class_shares(self.labels)
        return {"samples": len(self), "scenarios": len(set(self.scenario_ids)),
                **{f"share_{name}": round(float(s), 4) for name, s in zip(SAFETY_CLASSES, shares, strict=True)}}


def score_diffs(dataset: str | Path, scenarios: Sequence[Scenario]) -> dict[str, np.ndarray]:
    """``{scenario_id: diff [A]}`` per agent (scenario row order) from the dataset's SafeShift scores."""
    from seal.scoring.store import load_scores

    table = load_scores(dataset)
    row_of = {sid: k for k, sid in enumerate(table.scenario_ids)}
    out = {}
    for s in scenarios:
        if s.scenario_id not in row_of:
            raise ValueError(f"{dataset}: scenario {s.scenario_id!r} has no SafeShift scores; run "
                             f"`seal data score {dataset}` again")
        rows = table.agents(row_of[s.scenario_id])
        ids = table.arrays["agent_ids"][rows]
        if not np.array_equal(ids, s.agent_ids):
            raise ValueError(f"{dataset}: the scores of scenario {s.scenario_id!r} list other agents than its shard")
        out[s.scenario_id] = (table.arrays["traj_gt"][rows] - table.arrays["traj_fe"][rows]).astype(np.float64)
    return out


def everyday_samples(dataset: str | Path, split: str, limit: int | None, cfg: BehaviorFeatureConfig,
                     min_valid_rows: int, max_samples: int | None, seed: int) -> tuple[SampleSet, list[Scenario]]:
    """Unlabelled-yet samples (labels -1, ``diff`` set) of ``split`` (at most ``max_samples``, a seeded draw)."""
    scenarios = load_split(dataset, split, limit, what="behaviour")
    diffs = score_diffs(dataset, scenarios)
    parts, diff, ids = [], [], []
    for s in scenarios:
        targets = scene_targets(s.tracks, min_valid_rows, cfg)
        if targets.size == 0:
            continue
        parts.append(scene_inputs(s.tracks, targets, cfg))
        diff.append(diffs[s.scenario_id][targets])
        ids.extend([s.scenario_id] * targets.size)
    if not parts:
        raise ValueError(f"dataset {dataset}: no usable agents in split {split!r}")
    samples = SampleSet(BehaviorInputs.concat(parts), np.full(len(ids), -1), np.concatenate(diff), ids)
    if max_samples is not None and len(samples) > max_samples:
        rows = np.sort(np.random.default_rng(seed).choice(len(samples), max_samples, replace=False))
        samples = samples.take(rows)
    return samples, scenarios


def label_everyday(train: SampleSet, held_out: SampleSet) -> float:
    """Label both sets in place with the ``delta`` that makes the training classes even; returns ``delta``."""
    delta = even_delta(train.diff)
    train.labels = safety_labels(train.diff, delta)
    held_out.labels = safety_labels(held_out.diff, delta)
    return delta


def crash_set(scenarios: Sequence[Scenario], extra: Sequence[str | Path], cfg: BehaviorFeatureConfig,
              crash_cfg: CrashSetConfig) -> tuple[SampleSet, dict[str, Any]]:
    """The crash set of ``scenarios`` and of every scenario of the ``extra`` datasets, and its summary (per source:
    pairs, class counts, the reasons for the cause)."""
    sources: list[tuple[str, Sequence[Scenario]]] = [("training split", scenarios)]
    sources += [(str(d), load_split(d, None, what="crash-set")) for d in extra]
    parts, labels, ids, summary = [], [], [], {}
    for name, group in sources:
        by_id = {s.scenario_id: s for s in group}
        samples = crash_samples(list(group), crash_cfg)
        for smp in samples:
            s = by_id[smp.scenario_id]
            parts.append(scene_inputs(s.tracks, np.array([smp.agent]), cfg))
            labels.append(smp.label)
            ids.append(smp.scenario_id)
        summary[name] = {
            "pairs": len(samples) // 2,
            "labels": {SAFETY_CLASSES[k]: v for k, v in sorted(Counter(x.label for x in samples).items())},
            "cause": dict(Counter(x.basis for x in samples if x.role == "aggressor")),
            "recipient": dict(Counter(x.basis for x in samples if x.role == "recipient")),
        }
    if not parts:
        raise ValueError("the crash set is empty: no logged pair collides or comes within near_miss_m "
                         f"({crash_cfg.near_miss_m} m); raise crash.near_miss_m or add --crash-dataset")
    out = SampleSet(BehaviorInputs.concat(parts), np.asarray(labels, dtype=np.int64), np.zeros(len(ids)), ids)
    return out, summary
