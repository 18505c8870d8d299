"""`import_files`: import recorded scenario files into a seal dataset, reporting and skipping bad files.

Inputs are files and directories (searched recursively for the format's file suffix, in sorted order). Each
file is imported on its own: a file that fails (malformed, unsupported, a forbidden pickle class, no usable
window, ...) is reported with its reason and skipped, and the others go on. Files are processed in chunks of
`FILES_PER_SHARD`; each chunk is one dataset shard written atomically by `seal.core.dataset.DatasetBuilder`, so an
interrupted import resumes at the first missing chunk when re-run with the same arguments. Scenario ids are
``{file stem}-{k:02d}`` (``{stem}~{n}-{k:02d}`` for the n-th later file with an already used stem).

The finished dataset is an ordinary seal dataset: the manifest's provenance records the importer, its options,
the inputs and the per-file outcome, and ``import_report.json`` in the dataset holds the same report.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from seal.core.atomic import atomic_write_json
from seal.core.dataset import Dataset, DatasetBuilder
from seal.core.importers.build import scenarios_from_log
from seal.core.importers.windows import MIN_FUTURE_STEPS
from seal.core.scenario import N_FUTURE, Scenario

IMPORTER_VERSION = 1
"""Bump when imported content changes for the same files and options (part of the build parameters)."""
FILES_PER_SHARD = 64
REPORT_FILE = "import_report.json"


class ImportFailed(ValueError):
    """No scenario could be imported; the message lists the files and why each was skipped."""


@dataclass(frozen=True)
class ImportOptions:
    """Options of one import.

    Attributes:
        max_per_file: most scenarios cut from one file.
        min_future_steps: logged future steps (10 Hz) the ego and the adversary need in a window (1..80; 80 = the
            whole window).
    """

    max_per_file: int
    min_future_steps: int = MIN_FUTURE_STEPS

    def __post_init__(self) -> None:
        if isinstance(self.max_per_file, bool) or not isinstance(self.max_per_file, int) or self.max_per_file < 1:
            raise ValueError(f"--max-per-file must be a positive integer, got {self.max_per_file!r}")
        if not isinstance(self.min_future_steps, int) or not 1 <= self.min_future_steps <= N_FUTURE:
            raise ValueError(f"--min-future-steps must be in [1, {N_FUTURE}], got {self.min_future_steps!r}")


def _commonroad(path: Path, prefix: str, opts: ImportOptions) -> list[Scenario]:
    from seal.core.importers.commonroad import describe, read_commonroad

    rec = read_commonroad(path)
    return scenarios_from_log(
        rec.log, rec.road, prefix, f"commonroad:{path.name}", describe(rec), opts.max_per_file, opts.min_future_steps
    )


def _scenarionet(path: Path, prefix: str, opts: ImportOptions) -> list[Scenario]:
    from seal.core.importers.scenarionet import describe, read_scenarionet

    rec = read_scenarionet(path)
    return scenarios_from_log(
        rec.log, rec.road, prefix, f"scenarionet:{rec.dataset}:{path.name}", describe(rec), opts.max_per_file,
        opts.min_future_steps, ego_row=rec.sdc_row, adv_rows=rec.interest_rows,
    )


@dataclass(frozen=True)
class Format:
    """An import format: file suffix, default scenarios per file and the per-file importer."""

    suffix: str
    default_max_per_file: int
    read: Callable[[Path, str, ImportOptions], list[Scenario]]
    skip_names: tuple[str, ...] = ()


FORMATS: dict[str, Format] = {
    "commonroad": Format(".xml", 8, _commonroad),
    # ScenarioNet dataset folders also hold summary / mapping pickles that are not scenarios.
    "scenarionet": Format(".pkl", 1, _scenarionet, ("dataset_summary.pkl", "dataset_mapping.pkl")),
}


def collect_files(inputs: Sequence[str | Path], fmt: str) -> list[Path]:
    """The files to import: given files as they are, directories searched recursively (sorted, deduplicated)."""
    spec = FORMATS[fmt]
    out: list[Path] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.rglob(f"*{spec.suffix}") if f.is_file() and f.name not in spec.skip_names)
            if not found:
                raise FileNotFoundError(f"{p}: no {spec.suffix} files in this directory (format {fmt})")
            out.extend(found)
        elif p.is_file():
            out.append(p)
        else:
            raise FileNotFoundError(f"{p}: no such file or directory")
    seen: set[Path] = set()
    unique = []
    for f in out:
        key = f.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(f)
    return unique


def id_prefixes(files: Sequence[Path]) -> list[str]:
    """Unique scenario id prefix per file (module docstring)."""
    used: dict[str, int] = {}
    out = []
    for f in files:
        n = used.get(f.stem, 0)
        used[f.stem] = n + 1
        out.append(f.stem if n == 0 else f"{f.stem}~{n}")
    return out


def _import_one(fmt: str, path: Path, prefix: str, opts: ImportOptions) -> tuple[list[Scenario], str | None]:
    try:
        scenarios = FORMATS[fmt].read(path, prefix, opts)
    except Exception as exc:  # one bad file must not stop the others: report it and go on
        msg = str(exc)
        return [], msg if msg.startswith(str(path)) else f"{path}: {type(exc).__name__}: {msg}"
    if not scenarios:
        return [], (
            f"{path}: no window with an interacting (ego, adversary) pair that both move and are logged for the "
            f"1.1 s history and {opts.min_future_steps} future steps"
        )
    return scenarios, None


def _import_shards(
    builder: DatasetBuilder, fmt: str, files: Sequence[Path], prefixes: Sequence[str], opts: ImportOptions,
    progress: bool,
) -> None:
    """Import ``files`` in shards of `FILES_PER_SHARD` (skipping shards an earlier run finished), each written with
    its scenarios per file and skipped files (with reasons)."""
    bar = tqdm(total=len(files), unit="file", desc=f"import {fmt}", disable=not progress)
    try:
        for chunk, first in enumerate(range(0, len(files), FILES_PER_SHARD)):
            span = range(first, min(first + FILES_PER_SHARD, len(files)))
            if builder.is_done(chunk):
                bar.update(len(span))
                continue
            scenarios: list[Scenario] = []
            per_file: dict[str, int] = {}
            skipped: list[list[str]] = []
            for k in span:
                got, reason = _import_one(fmt, files[k], prefixes[k], opts)
                scenarios.extend(got)
                per_file[str(files[k])] = len(got)
                if reason is not None:
                    skipped.append([str(files[k]), reason])
                bar.update(1)
            builder.write_shard(chunk, scenarios, {"per_file": per_file, "skipped": skipped})
    finally:
        bar.close()


def _report(
    builder: DatasetBuilder, fmt: str, inputs: Sequence[str | Path], opts: ImportOptions, n_files: int,
    seconds: float,
) -> dict[str, Any]:
    """The import report, gathered from every shard's info (those of a resumed run included)."""
    per_file: dict[str, int] = {}
    skipped: list[list[str]] = []
    for chunk in sorted(builder.shards):
        info = builder.shards[chunk]["info"]
        per_file.update(info["per_file"])
        skipped.extend(info["skipped"])
    return {
        "importer": fmt,
        "inputs": [str(p) for p in inputs],
        "options": {"max_per_file": opts.max_per_file, "min_future_steps": opts.min_future_steps},
        "files": n_files,
        "imported_files": sum(1 for n in per_file.values() if n > 0),
        "skipped_files": len(skipped),
        "skipped": [{"file": f, "reason": r} for f, r in skipped],
        "scenarios": sum(per_file.values()),
        "scenarios_per_file": per_file,
        "seconds": round(seconds, 2),
    }


def import_files(
    inputs: Sequence[str | Path],
    out: str | Path,
    fmt: str,
    max_per_file: int | None = None,
    min_future_steps: int = MIN_FUTURE_STEPS,
    overwrite: bool = False,
    progress: bool = True,
) -> tuple[Dataset, dict[str, Any]]:
    """Import ``inputs`` (files / directories) of format ``fmt`` into the dataset directory ``out``.

    Args:
        inputs: files and directories.
        out: dataset directory to create (an unfinished import with the same arguments is resumed).
        fmt: ``"commonroad"`` or ``"scenarionet"``.
        max_per_file: most scenarios per file (default: 8 for CommonRoad, 1 for ScenarioNet).
        min_future_steps: see `ImportOptions`.
        overwrite: replace a finished dataset or an unfinished build with other arguments.
        progress: show a progress bar over the files.

    Returns:
        The dataset and the report (files, imported / skipped counts, the reason for every skipped file,
        scenarios per file, seconds).

    Raises:
        ImportFailed: no file gave a scenario.
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown import format {fmt!r}; choose from {', '.join(FORMATS)}")
    opts = ImportOptions(FORMATS[fmt].default_max_per_file if max_per_file is None else max_per_file,
                         min_future_steps)
    files = collect_files(inputs, fmt)
    prefixes = id_prefixes(files)
    listing = "\n".join(str(f.resolve()) for f in files)
    params = {
        "importer": fmt,
        "version": IMPORTER_VERSION,
        "n_files": len(files),
        "files_sha256": hashlib.sha256(listing.encode()).hexdigest(),
        "max_per_file": opts.max_per_file,
        "min_future_steps": opts.min_future_steps,
    }
    builder = DatasetBuilder(out, params, overwrite=overwrite)
    start = time.perf_counter()
    _import_shards(builder, fmt, files, prefixes, opts, progress)
    report = _report(builder, fmt, inputs, opts, len(files), time.perf_counter() - start)
    if report["scenarios"] == 0:
        reasons = "\n".join(f"  {s['reason']}" for s in report["skipped"][:20])
        raise ImportFailed(f"no scenario imported from {len(files)} {fmt} file(s):\n{reasons}")
    ds = builder.finalize(provenance={**report, "importer": f"seal.core.importers.{fmt}"})
    atomic_write_json(Path(out) / REPORT_FILE, report)
    return ds, report
