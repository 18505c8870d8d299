"""Which egos the report compares with which: one row per training pipeline, or per pipeline and ego algorithm
when the store holds egos of several algorithms (a ``seal run`` plan with ``algos: [reskill, td3]``).

An ego trained with another algorithm answers another question (does the adversary help *this* learner?), so its
rows are labelled ``<pipeline> (<algo>)`` and compared only with egos of the same algorithm
(`seal.experiments.report.stats`). The built-in egos (``replay``, ``heuristic``) keep their names and enter the
tables but no comparison.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

BUILTIN_EGOS = ("replay", "heuristic")


def run_algos(runs: Sequence[Mapping[str, Any]]) -> dict[str, str]:
    """``{run: algo}`` of the trained runs in the store's runs table (``config`` is the run's JSON config)."""
    out = {}
    for r in runs:
        cfg = r.get("config")
        cfg = json.loads(cfg) if isinstance(cfg, str) else (cfg or {})
        if r.get("pipeline") not in BUILTIN_EGOS and isinstance(cfg, Mapping) and cfg.get("algo"):
            out[str(r["run"])] = str(cfg["algo"])
    return out


def label_by_algo(rows: Sequence[Mapping[str, Any]], runs: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` with ``pipeline`` relabelled ``<pipeline> (<algo>)`` when the evaluated trained egos use more than
    one algorithm; otherwise the rows unchanged (as new dicts)."""
    algos = run_algos(runs)
    used = {algos[r["run"]] for r in rows if r["run"] in algos}
    if len(used) < 2:
        return [dict(r) for r in rows]
    return [{**r, "pipeline": f"{r['pipeline']} ({algos[r['run']]})"} if r["run"] in algos else dict(r) for r in rows]


def algo_of(label: str) -> str:
    """The algorithm part of a label (``""`` for a plain pipeline name)."""
    return label[label.rindex("(") + 1:-1] if label.endswith(")") and " (" in label else ""


def base_pipeline(label: str) -> str:
    """The pipeline part of a label: ``seal (td3)`` -> ``seal``."""
    return label[:label.rindex(" (")] if algo_of(label) else label


def is_trained(label: str) -> bool:
    return base_pipeline(label) not in BUILTIN_EGOS


def comparable(a: str, b: str) -> bool:
    """Two trained egos' rows are compared when they share the ego algorithm."""
    return is_trained(a) and is_trained(b) and algo_of(a) == algo_of(b)
