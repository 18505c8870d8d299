"""Reading a model file written with ``torch.save`` without unpickling anything (``weights_only=True``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch


def read_weights_file(path: Path, what: str, fit_command: str, error: type[Exception]) -> Any:
    """The object stored in ``path``, loaded on the CPU with ``torch.load(weights_only=True)``.

    Args:
        path: the file.
        what: how errors name the file (e.g. ``"skill model file"``).
        fit_command: the command that writes such files, suggested when the file is missing.
        error: exception class raised (naming the file) when the file cannot be read.
    """
    if not path.is_file():
        raise FileNotFoundError(f"{what} {path} not found (train one with `{fit_command}`)")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types for truncated / foreign files
        raise error(f"{what} {path} cannot be read ({type(exc).__name__}: {exc})") from None


def check_header(
    state: Any, where: str, fmt: str, version: int, required: tuple[str, ...], error: type[Exception], hint: str = "",
) -> dict[str, Any]:
    """``state`` (a loaded model file) after checking its ``format``, ``format_version`` and ``required`` fields;
    errors name the file (``where``) and the field; ``hint`` follows the wrong-format message."""
    if not isinstance(state, dict) or state.get("format") != fmt:
        raise error(f"{where}: field 'format' is not {fmt!r}{hint}")
    if state.get("format_version") != version:
        raise error(f"{where}: field 'format_version' is {state.get('format_version')!r}; this seal reads {version}")
    for key in required:
        if key not in state:
            raise error(f"{where}: missing field {key!r}")
    return state
