"""Score a whole dataset and keep the scores in it: ``DIR/scores.npz`` (atomic) + a ``"scores"`` manifest entry.

``scores.npz`` (numpy only, loads with ``allow_pickle=False``) is columnar like the shards:

* per scene ``[N]``: ``scenario_ids``, ``scene_<variant>`` for every variant in `seal.scoring.scores.VARIANTS`;
* per agent ``[M]`` (scene k owns rows ``agent_offsets[k]:agent_offsets[k+1]``): ``agent_ids``, ``focal``,
  ``traj_<variant>``, ``weight_<variant>``, ``ind_score_<gt|fe>``, ``ind_features_<gt|fe>`` ``[M, F]``;
* per pair ``[Q]`` (rows ``pair_offsets[k]:pair_offsets[k+1]``, only pairs active in some variant): ``pair_i``,
  ``pair_j`` (agent rows within the scene), ``pair_score_<gt|fe|as_ij|as_ji>``, ``pair_active_<...>``,
  ``soc_features_<gt|fe>`` ``[Q, F]``;
* the fitted motion primitives (``prim_*``) and ``meta_json`` (version, feature names, parameters).
"""

from __future__ import annotations

import hashlib
import io
import json
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.atomic import atomic_write
from seal.core.dataset import Dataset, DatasetError
from seal.core.scenario import HEADING, VALID, Scenario, X, Y
from seal.core.workers import initializer
from seal.scoring.individual import INDIVIDUAL_FEATURES
from seal.scoring.primitives import Primitives, fit_primitives
from seal.scoring.scores import VARIANTS, ScenarioScores, score_scenario
from seal.scoring.social import SOCIAL_FEATURES

SCORES_FILE = "scores.npz"
SCORES_VERSION = 2
"""Bump when scores change for the same scenarios (2: route-following, stopping counterfactuals)."""
PAIR_KEYS = ("gt", "fe", "as_ij", "as_ji")
FIT_SCENARIOS = 300
"""Scenarios (a seeded sample) whose logged tracks fit the motion primitives; more adds time, not accuracy."""
CHUNK = 25


def _missing(root: Path) -> DatasetError:
    return DatasetError(f"{root} has no SafeShift scores; run `seal data score {root}` first")


@dataclass
class ScoreTable:
    """All scores of a dataset (see the module docstring for the arrays in ``arrays``)."""

    arrays: dict[str, np.ndarray]
    meta: dict[str, Any]

    @property
    def scenario_ids(self) -> list[str]:
        return [str(s) for s in self.arrays["scenario_ids"]]

    def __len__(self) -> int:
        return int(self.arrays["scenario_ids"].shape[0])

    def scene(self, variant: str = "ac") -> np.ndarray:
        """``[N]`` scene scores of one variant (``gt``, ``fe``, ``as`` or ``ac``)."""
        if variant not in VARIANTS:
            raise ValueError(f"unknown score variant {variant!r}; choose one of {VARIANTS}")
        return self.arrays[f"scene_{variant}"]

    def focal_min(self, variant: str = "ac") -> np.ndarray:
        """``[N]`` the smaller of the ego's and the adversary's trajectory scores per scene (thesis 6.4 selects
        SafeShift-Hard by the interacting agents' trajectory scores)."""
        self.scene(variant)  # validates the name
        traj = self.arrays[f"traj_{variant}"][self.arrays["focal"]].astype(np.float64)
        return traj.reshape(len(self), 2).min(axis=1)

    def agents(self, k: int) -> slice:
        """Agent rows of scene ``k``."""
        off = self.arrays["agent_offsets"]
        return slice(int(off[k]), int(off[k + 1]))

    def pairs(self, k: int) -> slice:
        """Pair rows of scene ``k``."""
        off = self.arrays["pair_offsets"]
        return slice(int(off[k]), int(off[k + 1]))

    @property
    def primitives(self) -> Primitives:
        return Primitives.from_arrays(self.arrays)


# ------------------------------------------------------------------------------------------------- compute
def scenario_track_arrays(s: Scenario) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(pos [A, T, 2], heading [A, T], valid [A, T])`` of a scenario's logged tracks (for primitive fitting)."""
    tr = s.tracks.astype(np.float64)
    return tr[..., [X, Y]], tr[..., HEADING], tr[..., VALID] > 0.5


def fit_dataset_primitives(scenarios: Sequence[Scenario], n_fit: int = FIT_SCENARIOS, seed: int = 0) -> Primitives:
    """Primitives fitted on the logged tracks of a seeded sample of at most ``n_fit`` scenarios."""
    rng = np.random.default_rng(seed)
    pick = np.sort(rng.choice(len(scenarios), min(n_fit, len(scenarios)), replace=False))
    return fit_primitives([scenario_track_arrays(scenarios[int(i)]) for i in pick], seed=seed)


_WORKER_PRIM: Primitives | None = None


def _init_worker(prim: Primitives | None) -> None:
    global _WORKER_PRIM
    _WORKER_PRIM = prim


def _score_chunk(chunk: list[Scenario]) -> list[ScenarioScores]:
    return _score_chunk_with(chunk, _WORKER_PRIM)


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def score_scenarios(
    scenarios: Sequence[Scenario], prim: Primitives | None, workers: int | None = None, progress: bool = False
) -> list[ScenarioScores]:
    """`score_scenario` for every scenario, in order; ``workers > 1`` uses a process pool (chunks of 25)."""
    workers = default_workers() if workers is None else max(1, int(workers))
    chunks = [list(scenarios[i : i + CHUNK]) for i in range(0, len(scenarios), CHUNK)]
    bar = _progress(len(scenarios), progress)
    out: list[ScenarioScores] = []
    if workers == 1 or len(chunks) <= 1:
        for chunk in chunks:
            out.extend(_score_chunk_with(chunk, prim))
            bar(len(chunk))
        return out
    # Fork where available: workers start instantly and share the imported modules.
    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else mp.get_context("spawn")
    init, init_args = initializer(_init_worker, prim)  # workers die with this process (no orphans after a kill)
    with ProcessPoolExecutor(max_workers=min(workers, len(chunks)), mp_context=ctx, initializer=init,
                             initargs=init_args) as pool:
        for result in pool.map(_score_chunk, chunks):
            out.extend(result)
            bar(len(result))
    return out


def _score_chunk_with(chunk: list[Scenario], prim: Primitives | None) -> list[ScenarioScores]:
    return [score_scenario(s, prim) for s in chunk]


def _progress(total: int, enabled: bool):
    if not enabled:
        return lambda n: None
    from tqdm import tqdm

    bar = tqdm(total=total, desc="scoring", unit="scn", file=sys.stderr, leave=False)
    return bar.update


def build_table(results: Sequence[ScenarioScores], prim: Primitives | None, meta: dict[str, Any]) -> ScoreTable:
    """Columnar `ScoreTable` of per-scenario results (see the module docstring)."""
    a: dict[str, np.ndarray] = {"scenario_ids": np.array([r.scenario_id for r in results])}
    n_agents = [r.agent_ids.size for r in results]
    a["agent_offsets"] = np.concatenate([[0], np.cumsum(n_agents)]).astype(np.int64)
    a["agent_ids"] = np.concatenate([r.agent_ids for r in results]).astype(np.int64)
    a["focal"] = np.concatenate([r.focal for r in results])
    for v in VARIANTS:
        a[f"scene_{v}"] = np.array([r.scene[v] for r in results], dtype=np.float64)
        a[f"traj_{v}"] = np.concatenate([r.traj[v] for r in results]).astype(np.float32)
        a[f"weight_{v}"] = np.concatenate([r.weights[v] for r in results]).astype(np.float32)
    for v in ("gt", "fe"):
        a[f"ind_score_{v}"] = np.concatenate([r.ind_score[v] for r in results]).astype(np.float32)
        a[f"ind_features_{v}"] = np.concatenate([r.ind_features[v] for r in results]).astype(np.float32)
    keep = [np.logical_or.reduce([r.pair_active[k] for k in PAIR_KEYS]) for r in results]
    a["pair_offsets"] = np.concatenate([[0], np.cumsum([int(k.sum()) for k in keep])]).astype(np.int64)
    a["pair_i"] = np.concatenate([r.pair_i[k] for r, k in zip(results, keep, strict=True)]).astype(np.int32)
    a["pair_j"] = np.concatenate([r.pair_j[k] for r, k in zip(results, keep, strict=True)]).astype(np.int32)
    for key in PAIR_KEYS:
        a[f"pair_score_{key}"] = np.concatenate(
            [r.pair_score[key][k] for r, k in zip(results, keep, strict=True)]
        ).astype(np.float32)
        a[f"pair_active_{key}"] = np.concatenate([r.pair_active[key][k] for r, k in zip(results, keep, strict=True)])
    for v in ("gt", "fe"):
        a[f"soc_features_{v}"] = np.concatenate(
            [r.soc_features[v][k] for r, k in zip(results, keep, strict=True)]
        ).reshape(-1, len(SOCIAL_FEATURES)).astype(np.float32)
    if prim is not None:
        a.update(prim.to_arrays())
    meta = {
        "version": SCORES_VERSION,
        "variants": list(VARIANTS),
        "individual_features": list(INDIVIDUAL_FEATURES),
        "social_features": list(SOCIAL_FEATURES),
        "has_primitives": prim is not None,
        **meta,
    }
    a["meta_json"] = np.array(json.dumps(meta, sort_keys=True))
    return ScoreTable(a, meta)


def summarize_scores(table: ScoreTable, top_share: float = 0.2) -> dict[str, Any]:
    """Mean, spread and quantiles of every variant's scene score, plus how the counterfactual changes the tail:
    ``ac_only_top_share`` = share of the AC top ``top_share`` scenes that are not in the GT top ``top_share``."""
    out: dict[str, Any] = {}
    for v in VARIANTS:
        x = table.scene(v)
        q = np.quantile(x, [0.25, 0.5, 0.75, 0.8, 0.95, 0.99]) if x.size else [np.nan] * 6
        out[v] = {
            "mean": float(np.mean(x)) if x.size else float("nan"),
            "std": float(np.std(x)) if x.size else float("nan"),
            "iqr": float(q[2] - q[0]),
            "p50": float(q[1]), "p80": float(q[3]), "p95": float(q[4]), "p99": float(q[5]),
            "max": float(np.max(x)) if x.size else float("nan"),
        }
    gt, ac = table.scene("gt"), table.scene("ac")
    if gt.size:
        k = max(1, int(round(top_share * gt.size)))
        top_gt = set(np.argsort(-gt, kind="stable")[:k].tolist())
        top_ac = np.argsort(-ac, kind="stable")[:k].tolist()
        out["ac_only_top_share"] = float(np.mean([i not in top_gt for i in top_ac]))
        out["ac_over_gt_std"] = float(np.std(ac) / max(np.std(gt), 1e-12))
    return out


# ------------------------------------------------------------------------------------------------- store
def score_dataset(dataset_dir: str | Path, workers: int | None = None, progress: bool = True) -> dict[str, Any]:
    """Score every scenario of a dataset (all variants), store ``scores.npz`` + the manifest entry; return a
    summary: counts, timings (s), the file and per-variant scene-score statistics."""
    root = Path(dataset_dir)
    t0 = time.perf_counter()
    ds = Dataset.open(root)
    scenarios = ds.load()
    if not scenarios:
        raise DatasetError(f"{root} holds no scenarios to score")
    t_load = time.perf_counter()
    prim = fit_dataset_primitives(scenarios)
    t_fit = time.perf_counter()
    results = score_scenarios(scenarios, prim, workers=workers, progress=progress)
    t_score = time.perf_counter()
    table = build_table(results, prim, {"n_fit_scenarios": min(FIT_SCENARIOS, len(scenarios)), "fit_seed": 0})
    entry = write_scores(root, table)
    ds.update_manifest(scores=entry)
    return {
        "n_scenarios": len(table),
        "file": str(root / SCORES_FILE),
        "workers": default_workers() if workers is None else int(workers),
        "load_s": t_load - t0,
        "fit_s": t_fit - t_load,
        "score_s": t_score - t_fit,
        "total_s": time.perf_counter() - t0,
        "summary": entry["summary"],
    }


def write_scores(root: Path, table: ScoreTable) -> dict[str, Any]:
    """Atomically write ``root/scores.npz``; return its manifest entry."""
    buf = io.BytesIO()
    arrays: dict[str, Any] = dict(table.arrays)  # typed loosely: numpy's stub reads ** as its allow_pickle flag
    np.savez_compressed(buf, **arrays)
    data = buf.getvalue()
    atomic_write(root / SCORES_FILE, lambda f: f.write(data))
    return {
        "file": SCORES_FILE,
        "version": SCORES_VERSION,
        "bytes": len(data),
        "sha256": hashlib.sha256(data).hexdigest(),
        "n_scenarios": len(table),
        "variants": list(VARIANTS),
        "primary": "ac",
        "created": datetime.now(UTC).isoformat(timespec="seconds"),
        "summary": summarize_scores(table),
    }


def load_scores(dataset_dir: str | Path) -> ScoreTable:
    """The `ScoreTable` stored in a dataset; fails naming the file and what to run if missing or corrupt."""
    root = Path(dataset_dir)
    entry = Dataset.open(root).manifest.get("scores")
    if not entry:
        raise _missing(root)
    path = root / entry["file"]
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise DatasetError(f"score file {path} is missing; run `seal data score {root}` again") from None
    if len(data) != entry["bytes"] or hashlib.sha256(data).hexdigest() != entry["sha256"]:
        raise DatasetError(f"score file {path} is truncated or corrupt; run `seal data score {root}` again")
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta_json"]))
    if meta.get("version") != SCORES_VERSION:
        raise DatasetError(
            f"score file {path} has version {meta.get('version')}; this seal reads {SCORES_VERSION}: "
            f"run `seal data score {root}` again"
        )
    return ScoreTable(arrays, meta)
