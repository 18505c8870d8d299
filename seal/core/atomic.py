"""Atomic file writes: write a temporary file next to the target, fsync it, then rename over the target.

A reader never sees a half-written file: it sees either the old content or the new one.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

_UMASK = os.umask(0)
os.umask(_UMASK)


def atomic_write(path: str | os.PathLike[str], write: Callable[[IO[bytes]], object]) -> None:
    """Call ``write(fileobj)`` on a temporary file and atomically move it to ``path`` (what ``write`` returns,
    e.g. a byte count, is ignored)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp creates 0600; give the file the usual permissions
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        named = naming_the_file(exc, path, "nothing was changed")
        if named is exc:
            raise
        raise named from exc


def naming_the_file(exc: BaseException, target: str | os.PathLike[str], note: str) -> BaseException:
    """``exc``, or, for an `OSError` that names no file (a failed ``write`` / ``fsync``: a full disk), an
    `OSError` with the same errno whose message names ``target`` and adds ``note`` (what state the data is in)."""
    if isinstance(exc, OSError) and exc.filename is None:
        return OSError(exc.errno, f"{exc.strerror or exc} (writing {target}; {note})")
    return exc


def atomic_write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    atomic_write(path, lambda f: f.write(data))


def atomic_write_json(path: str | os.PathLike[str], obj: Any) -> None:
    text = json.dumps(obj, indent=2, sort_keys=True) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))
