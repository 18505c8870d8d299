"""What code a run trained with: ``provenance.json`` in the run folder, one entry per training session.

``config.yaml`` records the options a run was given, not the defaults it got. A default can change between
versions (e.g. SEAL's ``prior_weight``), and a resumed run may continue under other code than it started with, so
each session (`seal train`, each ``--resume``) appends:

* ``started``: UTC time (ISO 8601);
* ``seal_version`` and, when seal is imported from a git checkout, ``git_commit`` and ``git_dirty`` (tracked files
  changed; untracked ones are ignored); None where unknown (an installed wheel, no ``git`` on the machine);
* ``python`` and the versions of the libraries that decide the numbers (torch, stable-baselines3, gymnasium,
  numpy, highway-env);
* ``generator``: the adversary's name and every constructor option with the value it got, the given ones from the
  config and the rest at the constructor's defaults (None where the generator picks a value itself, see its
  docstring; an option that is not plain data is written as its type name).
"""

from __future__ import annotations

import inspect
import json
import platform
import subprocess
from collections.abc import Mapping
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

from seal.core.atomic import atomic_write_json

PROVENANCE = "provenance.json"
LIBRARIES = ("torch", "stable-baselines3", "gymnasium", "numpy", "highway-env")
_GIT_TIMEOUT_S = 5.0


def code_version(root: Path | None = None) -> dict[str, Any]:
    """``seal_version``, ``git_commit`` and ``git_dirty`` of the seal package (its checkout at ``root``, default the
    folder above the package)."""
    import seal

    root = Path(seal.__file__).resolve().parent.parent if root is None else Path(root)
    commit, dirty = None, None
    try:
        commit = _git(root, "rev-parse", "HEAD") or None
        if commit is not None:
            dirty = bool(_git(root, "status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):  # no git, not a checkout, or it hung
        commit, dirty = None, None
    return {"seal_version": seal.__version__, "git_commit": commit, "git_dirty": dirty}


def _git(root: Path, *args: str) -> str:
    done = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=_GIT_TIMEOUT_S,
                          check=True)
    return done.stdout.strip()


def library_versions() -> dict[str, str | None]:
    """Installed version of each of `LIBRARIES` (None when not installed)."""
    versions: dict[str, str | None] = {}
    for name in LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def generator_options(name: str, given: Mapping[str, Any]) -> dict[str, Any]:
    """Every constructor option of generator ``name`` with its value: ``given`` where set, else the default."""
    from seal.adversaries.base import generator_class

    cls = generator_class(name)
    options: dict[str, Any] = {}
    for param in inspect.signature(cls).parameters.values():
        if param.kind in (param.VAR_POSITIONAL, param.VAR_KEYWORD):
            continue
        value = given.get(param.name, None if param.default is param.empty else param.default)
        options[param.name] = _plain(value)
    for key, value in given.items():  # options the signature does not name (passed on through **kwargs)
        options.setdefault(key, _plain(value))
    return options


def _plain(value: Any) -> Any:
    """``value`` as JSON data: str subclasses (enums) as str, sequences as lists, other objects as their type."""
    if value is None or isinstance(value, bool | int | float):
        return value
    if isinstance(value, str | Path):
        return str(value)
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    return f"<{type(value).__name__}>"


def session_record(config: Mapping[str, Any]) -> dict[str, Any]:
    """This session's entry (see the module docstring) for a resolved train config."""
    generator = config.get("generator") or {}
    name = generator.get("name")
    return {
        "started": datetime.now(UTC).isoformat(timespec="seconds"),
        **code_version(),
        "python": platform.python_version(),
        "libraries": library_versions(),
        "generator": None if not name else {"name": name,
                                            "options": generator_options(name, generator.get("kwargs") or {})},
    }


def append_session(out: Path, config: Mapping[str, Any]) -> dict[str, Any]:
    """Append this session's record to ``out/provenance.json`` (atomic rewrite; an unreadable file is started
    again, the run's own files are never touched); returns the record."""
    path = Path(out) / PROVENANCE
    sessions: list[Any] = []
    if path.is_file():
        try:
            sessions = list(json.loads(path.read_text()).get("sessions", []))
        except (ValueError, AttributeError, TypeError):
            sessions = []
    record = session_record(config)
    atomic_write_json(path, {"sessions": [*sessions, record]})
    return record
