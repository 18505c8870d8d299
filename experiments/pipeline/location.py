"""A run folder that was moved or copied: `seal run` finds where it ran before (`recorded_roots`) and points the
folder's own records at where it is now (`relocate`) before any step, so nothing already done is done again.

What records the folder's path: the step markers (fit and eval parameters name the dataset and model paths; markers
hash them relative to the folder now, `seal.experiments.pipeline.steps.Steps`, older ones are matched against the
previous paths), the results store (episodes, runs and settings are keyed by the run folders' and datasets'
absolute paths, settings' options name model files) and every training run's config.yaml (the dataset, prior and
skills a run resumes with and a ReSkill ego is evaluated with). Only paths inside the folder move; paths outside
it (``data.path``, ``fit.NAME.path``, ``reuse``) are kept as they are.

Where the folder ran is recorded in OUT/steps/location.json (its path, and every earlier one); folders from before
that file are recognised by their summary.json's ``out``, or, without one (a first run that never finished), by
their store's run paths (``<old>/runs/<name>`` for a run folder that is here too).
"""

from __future__ import annotations

import json
import logging
import sqlite3
from dataclasses import dataclass
from pathlib import Path

import yaml

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.paths import rebase_tree

logger = logging.getLogger(__name__)

LOCATION = "location.json"
"""Under OUT/steps: ``{"out": path, "previous": [paths]}``."""
STORE = "results.sqlite"
RUNS = "runs"


@dataclass(frozen=True)
class Relocation:
    """What `relocate` changed for one earlier path of the folder."""

    old: str
    store_rows: int
    run_configs: int


def recorded_roots(out: Path) -> list[str]:
    """The paths the run folder ``out`` was run from before (newest first), ``out`` itself left out (module
    docstring); a location file that cannot be read is an error naming it."""
    here = str(out)
    found: list[str] = []
    location = out / "steps" / LOCATION
    if location.is_file():
        try:
            data = json.loads(location.read_text())
            found += [str(data["out"]), *(str(p) for p in data.get("previous") or [])]
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise ValueError(f"{location}: not a run folder location record ({exc}); delete it to re-create it"
                             ) from None
    summary = out / "summary.json"
    if summary.is_file():
        try:
            recorded = json.loads(summary.read_text()).get("out")
        except (json.JSONDecodeError, AttributeError):
            recorded = None
        if isinstance(recorded, str):
            found.append(recorded)
    if not found:  # a folder from before location.json whose first run never finished: its store's run paths
        found = _store_roots(out)
    return [root for root in dict.fromkeys(found) if root != here]


def relocated(out: Path) -> bool:
    """Whether OUT/steps/location.json records ``out`` itself (`relocate` has run here)."""
    location = out / "steps" / LOCATION
    try:
        return location.is_file() and json.loads(location.read_text()).get("out") == str(out)
    except (json.JSONDecodeError, AttributeError):
        return False


def _store_roots(out: Path) -> list[str]:
    """Folders ``<old>`` whose ``<old>/runs/<name>`` the store of ``out`` names (as an ego's key or run path) while
    ``out/runs/<name>`` exists."""
    store = out / STORE
    if not store.is_file():
        return []
    try:  # read-only sqlite: a `ResultsStore` would create its schema in a file that is not a store
        conn = sqlite3.connect(f"file:{store}?mode=ro", uri=True)
        try:
            paths = [row[0] for row in conn.execute(  # an ego's key is its run folder's path
                "SELECT DISTINCT run FROM episodes UNION SELECT path FROM runs WHERE path IS NOT NULL")]
        finally:
            conn.close()
    except sqlite3.DatabaseError:
        return []  # not a store (yet): the evaluation step says so
    roots = []
    for path in paths:
        run = Path(path)
        if run.parent.name == RUNS and (out / RUNS / run.name).is_dir():
            roots.append(str(run.parent.parent))
    return list(dict.fromkeys(roots))


def relocate(out: Path) -> list[Relocation]:
    """Point the records of run folder ``out`` that name an earlier path of it (`recorded_roots`) at ``out`` (the
    store's keys, run paths, configs and setting options; every run's config.yaml) and record ``out`` as its path.
    Nothing is changed for a folder that has not moved, nor once it has been relocated here (a `Relocation` of
    nothing per earlier path then)."""
    out = Path(out)
    roots = recorded_roots(out)
    if relocated(out):  # done by an earlier run here: the earlier paths only matter to older step markers now
        return [Relocation(old, 0, 0) for old in roots]
    done = []
    for old in roots:
        rows = 0
        if (out / STORE).is_file():
            from seal.experiments.evaluation.results_store import ResultsStore

            with ResultsStore(out / STORE) as store:
                rows = store.rebase_paths(old, str(out))
        configs = _rebase_run_configs(out / RUNS, old, str(out))
        done.append(Relocation(old, rows, configs))
        if rows or configs:
            logger.info(f"[seal run] {out} was run from {old} before: {rows} store rows and {configs} run configs "
                        "now point here")
    if roots or not (out / "steps" / LOCATION).is_file():
        atomic_write_json(out / "steps" / LOCATION, {"out": str(out), "previous": roots})
    return done


def _rebase_run_configs(runs: Path, old: str, new: str) -> int:
    """Rewrite each ``runs/<name>/config.yaml`` whose paths lie in ``old`` (as `seal train` writes it); returns how
    many changed."""
    changed = 0
    for config_path in sorted(runs.glob("*/config.yaml")) if runs.is_dir() else []:
        config = yaml.safe_load(config_path.read_text())
        moved = rebase_tree(config, old, new)
        if moved != config:
            atomic_write_bytes(config_path, yaml.safe_dump(moved, sort_keys=True).encode())
            changed += 1
    return changed
