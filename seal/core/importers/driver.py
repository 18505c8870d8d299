"""`import_files`: import recorded scenario files into a seal dataset, reporting and skipping bad files.

Inputs are files and directories (searched recursively for the format's file suffix, in sorted order). Each
file is imported on its own: a file that fails (malformed, unsupported, a forbidden pickle class, a parked ego, no
usable window, ...) is reported with its reason and skipped, and the others go on. Scenario ids are
``{file stem}-{k:02d}`` (``{stem}~{n}-{k:02d}`` for the n-th later file with an already used stem).

Imports are atomic: the dataset is built in a hidden staging folder next to ``--out`` (`staging_dir`) and renamed
to ``--out`` only when complete, so a failed import leaves no output folder behind. Files are processed in chunks
of `FILES_PER_SHARD`; each chunk is one dataset shard written atomically by `seal.core.dataset.DatasetBuilder`
together with the SHA-256 fingerprints of its files, so an interrupted import resumes at the first missing
chunk when re-run with the same arguments, and a chunk whose files changed since is imported again.

The finished dataset is an ordinary seal dataset: the manifest's provenance records the importer, its options,
the inputs and the per-file outcome, and ``import_report.json`` in the dataset holds the same report: files read
and skipped (with reasons), scenarios, and what was repaired or dropped and why (in total and per file: e.g.
``swapped_boxes``, ``uncertain_states``, ``degenerate_map_features``, ``windows_ego_leaves_mapped_road``).
Every scenario's metadata keeps its ``source_file`` (and `Scenario.source` names the file).
"""

from __future__ import annotations

import hashlib
import shutil
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from seal.core.atomic import atomic_write_json
from seal.core.dataset import MANIFEST, Dataset, DatasetBuilder, DatasetError
from seal.core.importers.build import WINDOWS_EGO_OFF_ROAD, FileImport, scenarios_from_log
from seal.core.importers.errors import ImportFormatError
from seal.core.importers.windows import MIN_FUTURE_STEPS
from seal.core.scenario import N_FUTURE, Scenario

IMPORTER_VERSION = 2
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


def _commonroad(path: Path, prefix: str, opts: ImportOptions) -> FileImport:
    from seal.core.importers.commonroad import describe, read_commonroad

    rec = read_commonroad(path)
    scenarios, off_road = scenarios_from_log(
        rec.log, rec.road, prefix, f"commonroad:{path.name}", describe(rec), opts.max_per_file, opts.min_future_steps
    )
    return FileImport(
        scenarios, {"uncertain_states": rec.uncertain_states}, {**rec.dropped, WINDOWS_EGO_OFF_ROAD: off_road}
    )


def _scenarionet(path: Path, prefix: str, opts: ImportOptions) -> FileImport:
    from seal.core.importers.scenarionet import describe, parked_ego, read_scenarionet

    rec = read_scenarionet(path)
    parked = parked_ego(rec)
    if parked is not None:
        raise ImportFormatError(path, f"tracks[{rec.log.source_ids[rec.sdc_row]!r}]", parked)
    scenarios, off_road = scenarios_from_log(
        rec.log, rec.road, prefix, f"scenarionet:{rec.dataset}:{path.name}", describe(rec), opts.max_per_file,
        opts.min_future_steps, ego_row=rec.sdc_row, adv_rows=rec.interest_rows,
    )
    return FileImport(scenarios, dict(rec.repaired), {**rec.dropped, WINDOWS_EGO_OFF_ROAD: off_road})


@dataclass(frozen=True)
class Format:
    """An import format: file suffix, default scenarios per file and the per-file importer."""

    suffix: str
    default_max_per_file: int
    read: Callable[[Path, str, ImportOptions], FileImport]
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


def _import_one(fmt: str, path: Path, prefix: str, opts: ImportOptions) -> tuple[FileImport, str | None]:
    try:
        got = FORMATS[fmt].read(path, prefix, opts)
    except Exception as exc:  # one bad file must not stop the others: report it and go on
        msg = str(exc)
        return FileImport([]), msg if msg.startswith(str(path)) else f"{path}: {type(exc).__name__}: {msg}"
    if not got.scenarios:
        off = got.dropped.get(WINDOWS_EGO_OFF_ROAD, 0)
        why = f" ({off} window(s) dropped: the logged ego leaves the mapped road)" if off else ""
        return got, (
            f"{path}: no window with an interacting (ego, adversary) pair that both move and are logged for the "
            f"1.1 s history and {opts.min_future_steps} future steps{why}"
        )
    return got, None


def file_fingerprint(path: Path) -> str:
    """SHA-256 of a file's bytes (16 hex digits): an input whose content changed is imported again."""
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()[:16]


def _shard_fingerprints(files: Sequence[Path]) -> list[str]:
    out = []
    for f in files:
        try:
            out.append(file_fingerprint(f))
        except OSError as exc:  # reported as that file's skip reason when the shard is imported
            out.append(f"unreadable: {exc.strerror}")
    return out


def _import_shards(
    builder: DatasetBuilder, fmt: str, files: Sequence[Path], prefixes: Sequence[str], opts: ImportOptions,
    progress: bool,
) -> None:
    """Import ``files`` in shards of `FILES_PER_SHARD`, each written with its scenarios, its files' fingerprints,
    per-file counts (scenarios, repaired, dropped) and skipped files (with reasons). A shard an earlier run
    finished is kept when its files are unchanged (same fingerprints), else imported again."""
    bar = tqdm(total=len(files), unit="file", desc=f"import {fmt}", disable=not progress)
    try:
        for chunk, first in enumerate(range(0, len(files), FILES_PER_SHARD)):
            span = range(first, min(first + FILES_PER_SHARD, len(files)))
            prints = _shard_fingerprints([files[k] for k in span])
            if builder.is_done(chunk) and builder.shards[chunk]["info"].get("fingerprints") == prints:
                bar.update(len(span))
                continue
            scenarios: list[Scenario] = []
            per_file: dict[str, dict[str, Any]] = {}
            skipped: list[list[str]] = []
            for k in span:
                got, reason = _import_one(fmt, files[k], prefixes[k], opts)
                scenarios.extend(got.scenarios)
                per_file[str(files[k])] = {
                    "scenarios": len(got.scenarios),
                    "repaired": {k: v for k, v in got.repaired.items() if v},
                    "dropped": {k: v for k, v in got.dropped.items() if v},
                }
                if reason is not None:
                    skipped.append([str(files[k]), reason])
                bar.update(1)
            info = {"fingerprints": prints, "per_file": per_file, "skipped": skipped}
            builder.write_shard(chunk, scenarios, info)
    finally:
        bar.close()


def _report(
    builder: DatasetBuilder, fmt: str, inputs: Sequence[str | Path], opts: ImportOptions, n_files: int,
    seconds: float,
) -> dict[str, Any]:
    """The import report, gathered from every shard's info (those of a resumed run included)."""
    per_file: dict[str, dict[str, Any]] = {}
    skipped: list[list[str]] = []
    for chunk in sorted(builder.shards):
        info = builder.shards[chunk]["info"]
        per_file.update(info["per_file"])
        skipped.extend(info["skipped"])
    totals: dict[str, Counter[str]] = {"repaired": Counter(), "dropped": Counter()}
    for row in per_file.values():
        for key, counts in totals.items():
            counts.update(row[key])
    return {
        "importer": fmt,
        "inputs": [str(p) for p in inputs],
        "options": {"max_per_file": opts.max_per_file, "min_future_steps": opts.min_future_steps},
        "files": n_files,
        "imported_files": sum(1 for row in per_file.values() if row["scenarios"] > 0),
        "skipped_files": len(skipped),
        "skipped": [{"file": f, "reason": r} for f, r in skipped],
        "scenarios": sum(row["scenarios"] for row in per_file.values()),
        "repaired": dict(sorted(totals["repaired"].items())),
        "dropped": dict(sorted(totals["dropped"].items())),
        "scenarios_per_file": {f: row["scenarios"] for f, row in per_file.items()},
        "per_file": per_file,
        "seconds": round(seconds, 2),
    }


def staging_dir(out: Path) -> Path:
    """Where an import into ``out`` is built before it is renamed to ``out`` (a hidden sibling folder)."""
    out = out.resolve() if out.name in ("", "..") else out  # "." or "dir/..": name the folder itself
    return out.with_name(f".{out.name}.importing")


def _check_out(out: Path, overwrite: bool) -> None:
    if overwrite or not out.exists():
        return
    if (out / MANIFEST).exists():
        raise DatasetError(f"{out} already holds a finished dataset; choose another --out or pass --overwrite")
    if not out.is_dir() or any(out.iterdir()):
        raise DatasetError(f"{out} exists and is not a seal dataset; choose another --out or pass --overwrite")


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

    The dataset is built in `staging_dir` and renamed to ``out`` when complete: a failed import (no scenario, or
    an error) leaves neither; an interrupted one (Ctrl-C) leaves the staging folder, and the same command resumes
    it, importing again the shards whose input files changed since.

    Args:
        inputs: files and directories.
        out: dataset directory to create.
        fmt: ``"commonroad"`` or ``"scenarionet"``.
        max_per_file: most scenarios per file (default: 8 for CommonRoad, 1 for ScenarioNet).
        min_future_steps: see `ImportOptions`.
        overwrite: replace a finished dataset (only once the new one is complete) or an unfinished build with
            other arguments.
        progress: show a progress bar over the files.

    Returns:
        The dataset and the report (files, imported / skipped counts, the reason for every skipped file,
        scenarios per file, what was repaired or dropped and why, in total and per file, seconds).

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
    out = Path(out)
    _check_out(out, overwrite)
    staging = staging_dir(out)
    builder = DatasetBuilder(staging, params, overwrite=overwrite)
    start = time.perf_counter()
    try:
        _import_shards(builder, fmt, files, prefixes, opts, progress)
        report = _report(builder, fmt, inputs, opts, len(files), time.perf_counter() - start)
        if report["scenarios"] == 0:
            reasons = "\n".join(f"  {s['reason']}" for s in report["skipped"][:20])
            raise ImportFailed(f"no scenario imported from {len(files)} {fmt} file(s):\n{reasons}")
        builder.finalize(provenance={**report, "importer": f"seal.core.importers.{fmt}"})
        atomic_write_json(staging / REPORT_FILE, report)
    except Exception:  # a failed import leaves nothing behind (an interruption is no Exception: it resumes)
        shutil.rmtree(staging, ignore_errors=True)
        raise
    if out.is_dir():  # --overwrite, or an empty folder (`_check_out`)
        shutil.rmtree(out)
    elif out.exists():
        out.unlink()
    staging.rename(out)
    return Dataset.open(out), report
