"""What the report keeps apart: datasets and egos that are not seeds of one pipeline.

The tables group episodes by (pipeline, setting). Two datasets evaluated under the same setting name (``normal``
of a generated pool and ``normal`` of another pool) would be averaged into one cell, and runs whose config
recorded no pipeline (older stores say ``unknown``) would be reported as seeds of one. `separate` relabels rows
before any table is built: with more than one dataset in the rows, every setting but ``real:DIR`` (already
distinct) becomes ``setting@dataset``; an ``unknown`` pipeline becomes ``unknown:<run folder name>``.
`filter_datasets` is ``seal compare --dataset``.

Egos of several algorithms (a ``seal run`` plan with ``algos: [reskill, td3]``) answer another question each (does
the adversary help *this* learner?): `label_by_algo` labels their rows ``<pipeline> (<algo>)`` when the store
holds more than one, and the statistics compare only egos of the same algorithm (`comparable`). The built-in egos
(``replay``, ``heuristic``) keep their names and enter the tables but no comparison. The generator tables (realism,
collision speed) are given over all egos and, with several algorithms, against each algorithm's egos apart
(`ego_groups`): a generator perturbs the scenario against the ego's own roll-outs, so what its adversary does
depends on the ego (the fifth decisive run: CAT's adversaries brake at -0.49 m/s^2 on average against the ReSkill
egos, -0.10 against the TD3 egos), and a table over both mixes two populations that no claim is about.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from seal.experiments.evaluation.evaluate import REAL_PREFIX

DATASET_SEP = "@"
"""Separates a setting from its dataset's name in a relabelled setting (``normal@pool``)."""
UNKNOWN_PIPELINE = "unknown"


def dataset_names(datasets: Iterable[str]) -> dict[str, str]:
    """Dataset path -> the shortest trailing part of its path that tells it from the others (``pool``, or
    ``a/data`` and ``b/data``)."""
    paths = sorted(set(datasets))
    for depth in range(1, 1 + max((len(Path(p).parts) for p in paths), default=1)):
        names = {p: "/".join(Path(p).parts[-depth:]) for p in paths}
        if len(set(names.values())) == len(paths):
            return names
    return {p: p for p in paths}


def separate(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """Copies of ``rows`` relabelled so that no table cell mixes datasets or unrelated egos (module docstring);
    each row keeps its ``dataset`` path and gains ``dataset_name`` and ``setting_name`` (the stored setting)."""
    names = dataset_names(r["dataset"] for r in rows)
    several = len({r["dataset"] for r in rows if not str(r["setting"]).startswith(REAL_PREFIX)}) > 1
    out = []
    for r in rows:
        row = dict(r, dataset_name=names[r["dataset"]], setting_name=r["setting"])
        if several and not str(r["setting"]).startswith(REAL_PREFIX):
            row["setting"] = f"{r['setting']}{DATASET_SEP}{names[r['dataset']]}"
        if r["pipeline"] == UNKNOWN_PIPELINE:
            row["pipeline"] = f"{UNKNOWN_PIPELINE}:{Path(str(r['run'])).name}"
        out.append(row)
    return out


def base_setting(setting: str) -> str:
    """The setting without its ``@dataset`` label."""
    return setting if setting.startswith(REAL_PREFIX) else setting.split(DATASET_SEP, 1)[0]


def filter_datasets(rows: Sequence[dict[str, Any]], datasets: Sequence[str]) -> list[dict[str, Any]]:
    """Rows whose dataset is one of ``datasets``, each given as a path or as the folder's name."""
    wanted = {str(Path(d).expanduser().resolve()) for d in datasets} | set(datasets)
    return [r for r in rows if r["dataset"] in wanted or Path(r["dataset"]).name in wanted]


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


ALL_EGOS = "all"
"""The `ego_groups` label of the group of every ego."""


def ego_groups(rows: Sequence[Mapping[str, Any]]) -> list[tuple[str, list[Mapping[str, Any]]]]:
    """``[(ALL_EGOS, rows)]`` and, when the rows are labelled with more than one algorithm (`label_by_algo`), one
    ``(algo, rows of that algorithm's trained egos)`` per algorithm, in order of appearance."""
    algos = list(dict.fromkeys(a for r in rows if is_trained(r["pipeline"]) and (a := algo_of(r["pipeline"]))))
    groups: list[tuple[str, list[Mapping[str, Any]]]] = [(ALL_EGOS, list(rows))]
    if len(algos) > 1:
        groups += [(a, [r for r in rows if is_trained(r["pipeline"]) and algo_of(r["pipeline"]) == a]) for a in algos]
    return groups


def tag_by_group(groups: Sequence[tuple[str, Sequence[Mapping[str, Any]]]],
                 table_of: Callable[[Sequence[Mapping[str, Any]]], list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """``table_of(rows)`` of every `ego_groups` group, each row tagged with its group in ``ego_group``."""
    return [{"ego_group": g, **r} for g, rows in groups for r in table_of(rows)]


def groups_in(table: Sequence[Mapping[str, Any]]) -> list[str]:
    """The ego groups of a table built per group (`tag_by_group`), in order; `ALL_EGOS` for an untagged one."""
    return list(dict.fromkeys(r.get("ego_group", ALL_EGOS) for r in table))


def in_group(table: Sequence[Mapping[str, Any]], group: str) -> list[Mapping[str, Any]]:
    """The rows of a table built per `ego_groups` group (key ``ego_group``) that belong to ``group``."""
    return [r for r in table if r.get("ego_group", ALL_EGOS) == group]


def group_name(group: str) -> str:
    """``all egos`` / ``the <algo> egos``."""
    return "all egos" if group == ALL_EGOS else f"the {group} egos"


def group_heading(group: str, n_groups: int) -> str:
    """A line that says which egos the tables below are against (empty with one group)."""
    return "" if n_groups < 2 else f"**Against {group_name(group)}**\n"
