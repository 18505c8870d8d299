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
from typing import Any

import numpy as np
import torch

from seal.core.scenario import CURRENT_STEP, HEADING, N_HISTORY, Scenario, X, Y
from seal.models.prior.baseline import constant_velocity_candidates
from seal.models.prior.metrics import drivability, kinematic_limits
from seal.models.prior.prior import TrajectoryPrior
from seal.models.prior.samples import TargetFilter, select_targets

KS = (1, 6, 32)
TARGET_RATIO = 0.5  # minADE@6 / CV ADE


def _targets(scenarios: Sequence[Scenario], kind: str) -> list[tuple[int, int]]:
    filt = TargetFilter(min_future_steps=80, adversary_only=kind == "adversary")
    return [(k, int(a)) for k, s in enumerate(scenarios) for a in select_targets(s, filt)]


def evaluate_targets(
    prior: TrajectoryPrior, scenarios: Sequence[Scenario], pairs: Sequence[tuple[int, int]],
    miss_threshold_m: float = 2.0, batch_size: int = 64, check_road: bool = True, progress: bool = False,
    desc: str = "eval",
) -> dict[str, Any]:
    """Metrics of ``prior`` and of constant velocity on the (scenario index, agent index) ``pairs``."""
    from tqdm import tqdm

    if not pairs:
        raise ValueError("no targets to evaluate (none with a full 8 s future?)")
    ade_k = {k: [] for k in KS}
    fde_k = {k: [] for k in KS}
    cv_ade, cv_fde, layouts, n_fallback = [], [], [], 0
    acc_ok, yaw_ok, road_ok, strict_ok, top6_ok, gt_acc, gt_yaw, gt_road = [], [], [], [], [], [], [], []
    for start in tqdm(range(0, len(pairs), batch_size), desc=desc, unit="batch", disable=not progress):
        chunk = pairs[start : start + batch_size]
        batch = [scenarios[k] for k, _ in chunk]
        cands = prior.predict(batch, [a for _, a in chunk])
        for s, (_, a), c in zip(batch, chunk, cands, strict=True):
            gt = s.tracks[a, N_HISTORY:, :][:, [X, Y]].astype(np.float64)
            d = np.linalg.norm(c.xy - gt[None], axis=-1)  # [K, T] (candidates most probable first)
            for k in KS:
                ade_k[k].append(d[:k].mean(axis=1).min())
                fde_k[k].append(d[:k, -1].min())
            cv = constant_velocity_candidates(s, a)
            dcv = np.linalg.norm(cv.xy[0] - gt, axis=-1)
            cv_ade.append(dcv.mean())
            cv_fde.append(dcv[-1])
            layouts.append(s.layout)
            n_fallback += c.fallback is not None
            start_xy = s.tracks[a, CURRENT_STEP, [X, Y]].astype(np.float64)
            heading = float(s.tracks[a, CURRENT_STEP, HEADING])
            if check_road:
                dv = drivability(c.xy, start_xy, heading, s.road)
                acc_ok.append(dv.within_acc)
                yaw_ok.append(dv.within_yaw)
                road_ok.append(dv.on_road)
                strict_ok.append(dv.on_road_strict)
                top6_ok.append(dv.drivable[:6])
                g = drivability(gt[None], start_xy, heading, s.road)
                gt_acc.append(g.within_acc[0])
                gt_yaw.append(g.within_yaw[0])
                gt_road.append(g.on_road[0])
            else:
                acc, yaw = kinematic_limits(c.xy, start_xy, heading)
                acc_ok.append(acc <= 8.0)
                yaw_ok.append(yaw <= 1.0)
    res: dict[str, Any] = {"targets": len(pairs), "fallbacks": n_fallback}
    for k in KS:
        res[f"min_ade_{k}"] = float(np.mean(ade_k[k]))
        res[f"min_fde_{k}"] = float(np.mean(fde_k[k]))
    res["miss_rate_6"] = float(np.mean(np.array(fde_k[6]) > miss_threshold_m))
    res["cv_ade"] = float(np.mean(cv_ade))
    res["cv_fde"] = float(np.mean(cv_fde))
    res["cv_miss_rate"] = float(np.mean(np.array(cv_fde) > miss_threshold_m))
    res["ratio_min_ade_6_to_cv_ade"] = res["min_ade_6"] / res["cv_ade"]
    res["meets_target"] = bool(res["ratio_min_ade_6_to_cv_ade"] <= TARGET_RATIO)
    acc_all, yaw_all = np.concatenate(acc_ok), np.concatenate(yaw_ok)
    res["share_within_acc"] = float(acc_all.mean())
    res["share_within_yaw_rate"] = float(yaw_all.mean())
    if check_road:
        road_all = np.concatenate(road_ok)
        res["share_on_road"] = float(road_all.mean())
        res["share_drivable"] = float((acc_all & yaw_all & road_all).mean())
        strict_all = np.concatenate(strict_ok)
        res["share_on_road_strict"] = float(strict_all.mean())
        res["share_drivable_strict"] = float((acc_all & yaw_all & strict_all).mean())
        res["share_drivable_top6"] = float(np.concatenate(top6_ok).mean())
        res["logged_share_within_acc"] = float(np.mean(gt_acc))
        res["logged_share_within_yaw_rate"] = float(np.mean(gt_yaw))
        res["logged_share_on_road"] = float(np.mean(gt_road))
    per_layout: dict[str, dict[str, float]] = defaultdict(dict)
    lay = np.array(layouts)
    for name in sorted(set(layouts)):
        m = lay == name
        per_layout[name] = {
            "targets": int(m.sum()),
            "min_ade_6": float(np.mean(np.array(ade_k[6])[m])),
            "cv_ade": float(np.mean(np.array(cv_ade)[m])),
        }
    res["per_layout"] = dict(per_layout)
    return res


def evaluate_prior(
    prior: TrajectoryPrior, scenarios: Sequence[Scenario], kinds: Sequence[str] = ("adversary", "moving"),
    miss_threshold_m: float = 2.0, check_road: bool = True, progress: bool = True, threads: int = 1,
) -> dict[str, Any]:
    """Metrics per target set (see the module docstring), plus how many scenarios the prior was trained on."""
    torch.set_num_threads(threads)
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
