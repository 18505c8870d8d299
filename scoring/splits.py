"""Normal / Hard splits from the SafeShift scene scores (thesis 3.4.1 and 6.4: hold out the top 20 %).

Hard = a seeded random sample of ``n_hard`` scenes whose scene score (AC variant by default) is above the
``hard_quantile`` quantile of the pool; Normal train / eval = disjoint seeded samples of the remaining scenes.
``by="focal"`` ranks scenes by the smaller of the ego's and the adversary's trajectory scores instead (the
thesis' SEAL chapter selects WOMD-SafeShift-Hard by the interacting agents' trajectory scores).
The splits go to the manifest's ``"splits"`` (``{"train": [...], "eval": [...], "hard": [...]}``, ids in dataset
order) and the parameters with the threshold to ``"split_params"``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from seal.core.dataset import Dataset, DatasetError
from seal.scoring.proximity import pair_proximity
from seal.scoring.store import load_scores


class SplitError(DatasetError):
    """The pool cannot provide the requested splits; the message names the option to change."""


def make_splits(
    dataset_dir: str | Path,
    hard_quantile: float = 0.8,
    n_train: int = 400,
    n_eval: int = 100,
    n_hard: int = 100,
    seed: int = 42,
    variant: str = "ac",
    by: str = "scene",
) -> dict[str, Any]:
    """Draw and record the splits (see the module docstring); return sizes, threshold and mean scores per split."""
    root = Path(dataset_dir)
    if not 0.0 < hard_quantile < 1.0:
        raise SplitError(f"--hard-quantile must be in (0, 1), got {hard_quantile}")
    for name, value in (("--n-train", n_train), ("--n-eval", n_eval), ("--n-hard", n_hard)):
        if value < 0:
            raise SplitError(f"{name} must be >= 0, got {value}")
    ds = Dataset.open(root)
    table = load_scores(root)
    ids = np.array(table.scenario_ids)
    if by not in ("scene", "focal"):
        raise SplitError(f"--by must be 'scene' or 'focal', got {by!r}")
    scores = table.scene(variant) if by == "scene" else table.focal_min(variant)
    order = {sid: k for k, sid in enumerate(ids)}
    if len(ids) != len(ds):  # scores of another build of this directory
        raise SplitError(
            f"{root}: the scores cover {len(ids)} scenes but the dataset has {len(ds)}; "
            f"run `seal data score {root}` again"
        )
    threshold = float(np.quantile(scores, hard_quantile))
    hard_pool = np.flatnonzero(scores > threshold)
    normal_pool = np.flatnonzero(scores <= threshold)
    if hard_pool.size < n_hard:
        raise SplitError(
            f"only {hard_pool.size} scenes score above the {hard_quantile:g} quantile ({threshold:.3f}) of the "
            f"{variant.upper()} {by} score, --n-hard asks for {n_hard}: lower --n-hard or --hard-quantile, "
            "or generate a larger pool"
        )
    if normal_pool.size < n_train + n_eval:
        raise SplitError(
            f"only {normal_pool.size} scenes score at or below the {hard_quantile:g} quantile, --n-train + --n-eval "
            f"ask for {n_train + n_eval}: lower --n-train / --n-eval, raise --hard-quantile, or generate a larger pool"
        )
    rng = np.random.default_rng(seed)
    hard = rng.choice(hard_pool, n_hard, replace=False)
    normal = rng.permutation(normal_pool)[: n_train + n_eval]
    splits = {
        "train": sorted(ids[normal[:n_train]].tolist(), key=order.__getitem__),
        "eval": sorted(ids[normal[n_train:]].tolist(), key=order.__getitem__),
        "hard": sorted(ids[hard].tolist(), key=order.__getitem__),
    }
    params = {
        "method": "safeshift",
        "variant": variant,
        "by": by,
        "hard_quantile": hard_quantile,
        "threshold": threshold,
        "n_train": n_train,
        "n_eval": n_eval,
        "n_hard": n_hard,
        "seed": seed,
        "scores_sha256": ds.manifest["scores"]["sha256"],
    }
    ds.update_manifest(splits=splits, split_params=params)
    close_calls = {}
    for name, members in splits.items():
        prox = [pair_proximity(sc) for sc in ds.load(ids=members)] if members else []
        close_calls[name] = {
            "pair_within_2m_or_collision": float(np.mean([p.min_gap_m <= 2.0 or p.collision for p in prox]))
            if prox else float("nan"),
            "pair_collision": float(np.mean([p.collision for p in prox])) if prox else float("nan"),
        }
    return {
        "logged_close_calls": close_calls,
        **{name: len(v) for name, v in splits.items()},
        "threshold": threshold,
        "mean_score": {name: float(np.mean(scores[[order[s] for s in v]])) if v else float("nan")
                       for name, v in splits.items()},
        "params": params,
    }
