"""Checking a config mapping against a dataclass before building it: unknown keys are an error that names them."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any


def check_keys(cls: type, d: Mapping[str, Any], where: str) -> None:
    """Raise ``ValueError`` naming ``where`` and every key of ``d`` that is not a field of dataclass ``cls``."""
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(d) - known)
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")
