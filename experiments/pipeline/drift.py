"""Which settings of a finished fit the code now resolves differently (``seal run`` and ``--status``).

A fit step's marker (`seal.experiments.pipeline.steps.Steps`) hashes the preset's options of the fit, not the
settings the fit resolved from them: when a default of the code changes (say SEAL's label behaviour hands over to
benign skills after the contact), a run folder's finished fit stays done with the settings it was made with. That is
what a run carried over many sessions wants (its trained egos were made against that model), but the user must be
told, or a table mixes models of two settings without anyone knowing.

`fit_drift` re-resolves a finished fit's settings from its options with the code of now and compares them with the
``config.yaml`` the fit recorded: every setting present in both whose value differs. Paths are left out (where a
folder is does not change what was fitted, and the marker already hashes the paths the preset gives), and so are
the settings of how a fit runs (workers, threads: `EXECUTION_KEYS`). The fits
without a settings file of their own (prior, probes) have no drift to report.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from seal.core.config import to_dict
from seal.experiments.pipeline.steps import StepJob

EXECUTION_KEYS = frozenset({"workers", "threads", "chunk_size", "no_progress"})
"""Settings of how a fit runs, not of what it fits (they may differ between machines): never reported."""
Change = tuple[str, Any, Any]
"""A drifted setting: dotted key, value recorded by the fit, value the code resolves now."""


def recorded_settings_file(kind: str, out: str | Path, options: Mapping[str, Any]) -> Path:
    """The ``config.yaml`` a fit of ``kind`` writing to ``out`` records its resolved settings in."""
    if kind == "goose":
        from seal.experiments.fitting.goose import default_run_dir

        return Path(options["run_dir"]) / "config.yaml" if options.get("run_dir") else default_run_dir(out) / (
            "config.yaml")
    return Path(out) / "config.yaml"


def _flat(value: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(value, Mapping) and value:
        flat: dict[str, Any] = {}
        for key, item in value.items():
            flat.update(_flat(item, f"{prefix}{key}."))
        return flat
    return {prefix[:-1]: value}


def _pathlike(value: Any) -> bool:
    if isinstance(value, str):
        return "/" in value
    return isinstance(value, list) and bool(value) and all(isinstance(v, str) and "/" in v for v in value)


def settings_drift(recorded: Mapping[str, Any], resolved: Mapping[str, Any]) -> list[Change]:
    """Settings present in both (dotted keys) whose values differ, paths and `EXECUTION_KEYS` left out, in
    ``resolved``'s order."""
    old, new = _flat(recorded), _flat(resolved)
    return [(key, old[key], value) for key, value in new.items()
            if key in old and old[key] != value and key.rsplit(".", 1)[-1] not in EXECUTION_KEYS
            and not (_pathlike(old[key]) and _pathlike(value))]


def fit_drift(step: StepJob) -> list[Change]:
    """How a fit step's recorded settings differ from what its options resolve to now (module docstring); empty
    for a fit without a settings file, one not run yet, or options that no longer resolve (the plan check says
    why)."""
    from seal.experiments.pipeline.tasks import FIT_CONFIGS

    job = step.job
    if job.get("task") != "fit" or job.get("model") not in FIT_CONFIGS:
        return []
    kind, options = job["model"], dict(job.get("options") or {})
    path = recorded_settings_file(kind, job["out"], options)
    if not path.is_file():
        return []
    try:
        config = FIT_CONFIGS[kind](options)
    except (ValueError, OSError):
        return []
    resolved = config.to_dict() if hasattr(config, "to_dict") else to_dict(config)
    # through YAML as the fit wrote it, so tuples and lists, or an int and a float of one value, compare alike
    resolved = yaml.safe_load(yaml.safe_dump(resolved))
    return settings_drift(yaml.safe_load(path.read_text()) or {}, resolved)


def describe_drift(changes: list[Change]) -> str:
    """``key: old -> new`` for each change, joined."""
    return "; ".join(f"{key}: {old!r} -> {new!r}" for key, old, new in changes)
