"""The demonstrations of ``seal fit skills``: one file per source, built (resumably) or reused, then merged.

* ``demos_log.npz``: the logged traffic's own drivers (clean, the benign windows; `DemoConfig.source` ``log``);
* ``demos_heuristic.npz``: the noisy, partly impaired heuristic drivers (their struck collisions and near misses
  give adversarial windows; their other windows are unused);
* ``demos_ego.npz``: an adversary in closed loop against egos (the heuristic driver and `seal train`
  checkpoints, `seal.experiments.fitting.skill_rollouts`; adversarial windows only), when egos are configured.

A file is reused when it was built from the same scenarios and settings (its recorded parameters).
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.config import check_keys
from seal.models.skills.demonstrations import DEMO_SOURCES, DemoConfig
from seal.models.skills.demos import ADVERSARIAL, BENIGN, Demonstrations, WindowSpec, split_by_scenario

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class EgoRolloutConfig:
    """Closed-loop roll-outs against egos (`seal.experiments.fitting.skill_rollouts`).

    Attributes:
        egos: ego specs: ``heuristic`` or `seal train` run folders (their checkpoints); empty: no roll-outs.
        adversary: ``cat`` (CAT's choice, tracked with the bicycle model, ``passes`` per ego) or ``heuristic``
            (the impaired noisy heuristic, one episode per ego).
        candidates: the ``cat`` adversary's candidate source: a trajectory prior file, or a built-in source name
            (``lanes``); None: ``lanes``.
        passes: CAT passes per (scenario, ego), each against the queue of the previous roll-outs.
        limit: roll out only the first N scenarios of the split (None: as many as the demonstrations).
    """

    egos: tuple[str, ...] = ()
    adversary: str = "cat"
    candidates: str | None = None
    passes: int = 3
    limit: int | None = None

    def __post_init__(self) -> None:
        from seal.experiments.fitting.skill_rollouts import ADVERSARIES

        if self.adversary not in ADVERSARIES:
            raise ValueError(f"ego_rollouts.adversary must be one of {ADVERSARIES}, got {self.adversary!r}")
        if int(self.passes) < 1:
            raise ValueError(f"ego_rollouts.passes must be >= 1, got {self.passes}")
        if self.limit is not None and int(self.limit) < 1:
            raise ValueError(f"ego_rollouts.limit must be >= 1 or null, got {self.limit}")

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "config key 'ego_rollouts'") -> EgoRolloutConfig:
        check_keys(cls, d, where)
        values: dict[str, Any] = {k: tuple(str(e) for e in v) if k == "egos" else v for k, v in d.items()}
        return cls(**values)

    def source_spec(self) -> str | None:
        """The candidate source as `seal.experiments.fitting.skill_rollouts` takes it (``prior:<abs path>``)."""
        c = self.candidates
        if c is None or not (c.endswith(".pt") or Path(c).is_file()):
            return c  # a built-in source name (checked by the generator)
        if not Path(c).is_file():
            raise FileNotFoundError(f"ego_rollouts.candidates: trajectory prior file {c} does not exist")
        return f"prior:{Path(c).resolve()}"

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "egos": list(self.egos)}


def _source_identity(params: dict[str, Any]) -> dict[str, Any]:
    """A source file's stored settings as `DemoConfig.to_dict` writes them now: files written when every source
    recorded every setting stay reusable (other parameters, e.g. the ego roll-outs', are returned as they are)."""
    if params.get("source") not in DEMO_SOURCES:
        return params
    try:
        return DemoConfig.from_dict(params).to_dict()
    except (TypeError, ValueError):
        return params


def _reuse(path: Path, params: dict[str, Any], ids: list[str]) -> Demonstrations | None:
    if not path.exists():
        return None
    try:
        demos = Demonstrations.load(path)
    except ValueError as exc:
        logger.info(f"demonstrations: {path} cannot be reused ({exc}); rebuilding")
        return None
    if _source_identity(demos.params) == params and list(dict.fromkeys(demos.scenario_ids.tolist())) == ids:
        logger.info(f"demonstrations: reusing {path} ({demos.n_segments} segments, {demos.n_rows} steps)")
        return demos
    logger.info(f"demonstrations: {path} was built from other scenarios or settings")
    return None


def _find(name: str, params: dict[str, Any], ids: list[str], folder: Path, own: Path | None
          ) -> tuple[Path, Demonstrations | None]:
    """A reusable demonstrations file ``name`` in ``folder`` (or else in ``own``), or the path to build it at: in
    ``folder``, unless a file there was built with other settings for another fit (``own``, the fit's output
    folder, differs from ``folder``): that file is left as it is and this fit builds its own in ``own``."""
    path = folder / name
    demos = _reuse(path, params, ids)
    if demos is not None or own is None or own.resolve() == folder.resolve() or not path.exists():
        return path, demos
    mine = own / name
    demos = _reuse(mine, params, ids)
    if demos is None:
        logger.info(f"demonstrations: {path} is left as it is (another fit's); building {mine}")
    return mine, demos


def get_demonstrations(dataset: str | Path, config: Any, folder: Path, progress: bool, own: Path | None = None
                       ) -> tuple[Demonstrations, list[str]]:
    """All configured sources' demonstrations of ``config.split`` (a `SkillsFitConfig`), merged, and the names of
    the files reused (module docstring). Files are reused from or built in ``folder``; a file there that another
    fit built with other settings is not overwritten when the fit's own folder ``own`` is given: this fit's
    version is built (or reused) there (`_find`)."""
    from seal.core.dataset import load_split
    from seal.experiments.fitting.skill_rollouts import _params, build_ego_demonstrations
    from seal.models.skills.demonstrations import build_demonstrations

    scenarios = load_split(dataset, config.split, config.limit)
    if len(scenarios) < 2:
        raise ValueError(f"dataset {dataset}: split {config.split!r} has {len(scenarios)} scenario(s); need at least 2")
    folder.mkdir(parents=True, exist_ok=True)
    parts, reused = [], []
    for source in config.sources:
        if source not in DEMO_SOURCES:
            raise ValueError(f"config key 'sources': unknown source {source!r}; choose from {DEMO_SOURCES}")
        cfg = DemoConfig.from_dict({"seed": config.seed, **config.demos, "source": source}, "config key 'demos'")
        path, demos = _find(f"demos_{source}.npz", cfg.to_dict(), [s.scenario_id for s in scenarios], folder, own)
        if demos is None:
            logger.info(f"demonstrations ({source}): simulating {len(scenarios)} scenarios with {config.workers} "
                        "processes")
            demos = build_demonstrations(scenarios, path, cfg, workers=config.workers, chunk_size=config.chunk_size,
                                         progress=progress)
        else:
            reused.append(path.name)
        parts.append(demos)
    ego_cfg = EgoRolloutConfig.from_dict(config.ego_rollouts)
    if ego_cfg.egos:
        chosen = scenarios[: ego_cfg.limit] if ego_cfg.limit else scenarios
        cfg = DemoConfig.from_dict({"seed": config.seed, **config.demos, "source": "heuristic"}, "config key 'demos'")
        spec = ego_cfg.source_spec()
        params = _params(ego_cfg.egos, cfg, ego_cfg.adversary, spec, ego_cfg.passes)
        path, demos = _find("demos_ego.npz", params, [s.scenario_id for s in chosen], folder, own)
        if demos is None:
            logger.info(f"demonstrations (ego roll-outs): {len(chosen)} scenarios x {len(ego_cfg.egos)} egos")
            demos = build_ego_demonstrations(chosen, ego_cfg.egos, path, cfg, ego_cfg.adversary, spec,
                                             ego_cfg.passes, config.workers, config.chunk_size, progress)
        else:
            reused.append(path.name)
        parts.append(demos)
    if not parts:
        raise ValueError("config key 'sources' is empty and no ego roll-outs are configured: nothing to learn from")
    merged = Demonstrations.concat(parts, {"sources": [p.params for p in parts]})
    return _renumber_scenarios(merged), reused


def _renumber_scenarios(demos: Demonstrations) -> Demonstrations:
    """One scenario index per scenario id (sources repeat the ids), so held-out splits keep a scenario's windows
    of every source together."""
    ids, inverse = np.unique(np.asarray(demos.scenario_ids, dtype=str), return_inverse=True)
    demos.seg_scenario = inverse[demos.seg_scenario].astype(np.int32)
    demos.scenario_ids = ids
    return demos


Rows = dict[tuple[str, str], np.ndarray]
"""Window start rows per (``train`` | ``val``, ``benign`` | ``adversarial``)."""

CLASSES = ((BENIGN, "benign"), (ADVERSARIAL, "adversarial"))


def cap(rows: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``n`` of ``rows`` (drawn at random, kept sorted)."""
    return rows if rows.size <= n else np.sort(rng.choice(rows, n, replace=False))


def window_rows(demos: Demonstrations, spec: WindowSpec, config: Any) -> tuple[Rows, dict[str, int]]:
    """Windows held out by scenario; per class capped for training (benign) and validation (both); the counts."""
    seed = config.seed
    rng = np.random.default_rng(seed)
    windows = demos.windows(spec)
    train_w, val_w = split_by_scenario(windows, demos.seg_scenario, len(demos.scenario_ids),
                                       float(config.val_fraction), seed)
    rows = {("train", name): train_w.row[train_w.label == label] for label, name in CLASSES}
    rows.update({("val", name): val_w.row[val_w.label == label] for label, name in CLASSES})
    rows["train", "benign"] = cap(rows["train", "benign"], config.max_benign_windows, rng)
    for name in ("benign", "adversarial"):
        rows["val", name] = cap(rows["val", name], config.max_val_windows, rng)
    counts = {f"{split}_{name}": int(r.size) for (split, name), r in rows.items()}
    logger.info("windows used: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    for key, n in counts.items():
        if n == 0:
            raise ValueError(f"no {key.replace('_', ' ')} windows: simulate more scenarios (--limit), add ego "
                             "roll-outs (config key 'ego_rollouts') or count near misses (windows.near_misses)")
    return rows, counts
