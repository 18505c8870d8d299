"""`seal eval prior`: accuracy and drivability of a prior against constant velocity, measured in the same run.

Two target sets, each through the public `TrajectoryPrior.predict` (world frame, fallback included):

* ``adversary``: each scenario's adversary — the agent the generators ask the prior about;
* ``moving``: every agent with >= 2 valid history steps that moves (>= 1 m over its valid steps).

Only targets with the full 8 s future logged count, so every FDE is at 8 s. Metric definitions are in
`seal.models.prior.metrics`; the miss threshold applies to minFDE@6 (and to the CV FDE for the baseline).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from seal.core.scenario import CURRENT_STEP, HEADING, N_HISTORY, Scenario, X, Y
from seal.models.prior.baseline import constant_velocity_candidates
from seal.models.prior.candidates import Candidates
from seal.models.prior.metrics import drivability, kinematic_limits
from seal.models.prior.prior import TrajectoryPrior
from seal.models.prior.samples import TargetFilter, select_targets

KS = (1, 6, 32)
TARGET_RATIO = 0.5  # minADE@6 / CV ADE


def _targets(scenarios: Sequence[Scenario], kind: str) -> list[tuple[int, int]]:
    filt = TargetFilter(min_future_steps=80, adversary_only=kind == "adversary")
    return [(k, int(a)) for k, s in enumerate(scenarios) for a in select_targets(s, filt)]


@dataclass
class _Tally:
    """Per-target values collected by `evaluate_targets` (one entry per target, in order)."""

    ade_k: dict[int, list[float]] = field(default_factory=lambda: {k: [] for k in KS})
    fde_k: dict[int, list[float]] = field(default_factory=lambda: {k: [] for k in KS})
    cv_ade: list[float] = field(default_factory=list)
    cv_fde: list[float] = field(default_factory=list)
    layouts: list[str] = field(default_factory=list)
    n_fallback: int = 0
    acc_ok: list[np.ndarray] = field(default_factory=list)
    yaw_ok: list[np.ndarray] = field(default_factory=list)
    road_ok: list[np.ndarray] = field(default_factory=list)
    strict_ok: list[np.ndarray] = field(default_factory=list)
    top6_ok: list[np.ndarray] = field(default_factory=list)
    gt_acc: list[bool] = field(default_factory=list)
    gt_yaw: list[bool] = field(default_factory=list)
    gt_road: list[bool] = field(default_factory=list)

    def add(self, s: Scenario, a: int, c: Candidates, check_road: bool) -> None:
        """Errors of candidates ``c`` of agent ``a`` and of constant velocity against the logged future, and the
        candidates' drivability (with the logged future's for reference when ``check_road``)."""
        gt = s.tracks[a, N_HISTORY:, :][:, [X, Y]].astype(np.float64)
        d = np.linalg.norm(c.xy - gt[None], axis=-1)  # [K, T] (candidates most probable first)
        for k in KS:
            self.ade_k[k].append(d[:k].mean(axis=1).min())
            self.fde_k[k].append(d[:k, -1].min())
        cv = constant_velocity_candidates(s, a)
        dcv = np.linalg.norm(cv.xy[0] - gt, axis=-1)
        self.cv_ade.append(dcv.mean())
        self.cv_fde.append(dcv[-1])
        self.layouts.append(s.layout)
        self.n_fallback += c.fallback is not None
        start_xy = s.tracks[a, CURRENT_STEP, [X, Y]].astype(np.float64)
        heading = float(s.tracks[a, CURRENT_STEP, HEADING])
        if check_road:
            dv = drivability(c.xy, start_xy, heading, s.road)
            self.acc_ok.append(dv.within_acc)
            self.yaw_ok.append(dv.within_yaw)
            self.road_ok.append(dv.on_road)
            self.strict_ok.append(dv.on_road_strict)
            self.top6_ok.append(dv.drivable[:6])
            g = drivability(gt[None], start_xy, heading, s.road)
            self.gt_acc.append(g.within_acc[0])
            self.gt_yaw.append(g.within_yaw[0])
            self.gt_road.append(g.on_road[0])
        else:
            acc, yaw = kinematic_limits(c.xy, start_xy, heading)
            self.acc_ok.append(acc <= 8.0)
            self.yaw_ok.append(yaw <= 1.0)

    def accuracy(self, miss_threshold_m: float) -> dict[str, Any]:
        """minADE / minFDE @k, miss rates and the constant-velocity baseline."""
        res: dict[str, Any] = {"targets": len(self.cv_ade), "fallbacks": self.n_fallback}
        for k in KS:
            res[f"min_ade_{k}"] = float(np.mean(self.ade_k[k]))
            res[f"min_fde_{k}"] = float(np.mean(self.fde_k[k]))
        res["miss_rate_6"] = float(np.mean(np.array(self.fde_k[6]) > miss_threshold_m))
        res["cv_ade"] = float(np.mean(self.cv_ade))
        res["cv_fde"] = float(np.mean(self.cv_fde))
        res["cv_miss_rate"] = float(np.mean(np.array(self.cv_fde) > miss_threshold_m))
        res["ratio_min_ade_6_to_cv_ade"] = res["min_ade_6"] / res["cv_ade"]
        res["meets_target"] = bool(res["ratio_min_ade_6_to_cv_ade"] <= TARGET_RATIO)
        return res

    def drivability(self, check_road: bool) -> dict[str, float]:
        """Shares of candidates within the kinematic limits (and on the road, drivable, when ``check_road``)."""
        res: dict[str, float] = {}
        acc_all, yaw_all = np.concatenate(self.acc_ok), np.concatenate(self.yaw_ok)
        res["share_within_acc"] = float(acc_all.mean())
        res["share_within_yaw_rate"] = float(yaw_all.mean())
        if check_road:
            road_all = np.concatenate(self.road_ok)
            res["share_on_road"] = float(road_all.mean())
            res["share_drivable"] = float((acc_all & yaw_all & road_all).mean())
            strict_all = np.concatenate(self.strict_ok)
            res["share_on_road_strict"] = float(strict_all.mean())
            res["share_drivable_strict"] = float((acc_all & yaw_all & strict_all).mean())
            res["share_drivable_top6"] = float(np.concatenate(self.top6_ok).mean())
            res["logged_share_within_acc"] = float(np.mean(self.gt_acc))
            res["logged_share_within_yaw_rate"] = float(np.mean(self.gt_yaw))
            res["logged_share_on_road"] = float(np.mean(self.gt_road))
        return res

    def per_layout(self) -> dict[str, dict[str, float]]:
        """Target count, minADE@6 and CV ADE per road layout."""
        per_layout: dict[str, dict[str, float]] = defaultdict(dict)
        lay = np.array(self.layouts)
        for name in sorted(set(self.layouts)):
            m = lay == name
            per_layout[name] = {
                "targets": int(m.sum()),
                "min_ade_6": float(np.mean(np.array(self.ade_k[6])[m])),
                "cv_ade": float(np.mean(np.array(self.cv_ade)[m])),
            }
        return dict(per_layout)


def evaluate_targets(
    prior: TrajectoryPrior, scenarios: Sequence[Scenario], pairs: Sequence[tuple[int, int]],
    miss_threshold_m: float = 2.0, batch_size: int = 64, check_road: bool = True, progress: bool = False,
    desc: str = "eval",
) -> dict[str, Any]:
    """Metrics of ``prior`` and of constant velocity on the (scenario index, agent index) ``pairs``."""
    from tqdm import tqdm

    if not pairs:
        raise ValueError("no targets to evaluate (none with a full 8 s future?)")
    tally = _Tally()
    for start in tqdm(range(0, len(pairs), batch_size), desc=desc, unit="batch", disable=not progress):
        chunk = pairs[start : start + batch_size]
        batch = [scenarios[k] for k, _ in chunk]
        cands = prior.predict(batch, [a for _, a in chunk])
        for s, (_, a), c in zip(batch, chunk, cands, strict=True):
            tally.add(s, a, c, check_road)
    return {**tally.accuracy(miss_threshold_m), **tally.drivability(check_road), "per_layout": tally.per_layout()}


def evaluate_prior(
    prior: TrajectoryPrior, scenarios: Sequence[Scenario], kinds: Sequence[str] = ("adversary", "moving"),
    miss_threshold_m: float = 2.0, check_road: bool = True, progress: bool = True,
) -> dict[str, Any]:
    """Metrics per target set (see the module docstring), plus how many scenarios the prior was trained on."""
    seen = set(prior.training.get("train_scenario_ids", [])) | set(prior.training.get("val_scenario_ids", []))
    out: dict[str, Any] = {
        "scenarios": len(scenarios),
        "scenarios_seen_in_training": sum(s.scenario_id in seen for s in scenarios),
        "miss_threshold_m": miss_threshold_m,
    }
    for kind in kinds:
        if kind not in ("adversary", "moving"):
            raise ValueError(f"unknown target set {kind!r}; use 'adversary' or 'moving'")
        out[kind] = evaluate_targets(
            prior, scenarios, _targets(scenarios, kind), miss_threshold_m, check_road=check_road,
            progress=progress, desc=kind,
        )
    return out
