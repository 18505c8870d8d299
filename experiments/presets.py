"""YAML presets and config files for the ``seal fit ...`` jobs: read, check the options against the defaults."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

CONFIG_DIR = Path(__file__).resolve().parent / "configs"


def read_options(path: Path, defaults: Mapping[str, Any]) -> dict[str, Any]:
    """Options in the YAML file ``path``; an error names the file and any option not in ``defaults``."""
    loaded = yaml.safe_load(Path(path).read_text()) or {}
    if not isinstance(loaded, dict):
        raise ValueError(f"{path}: expected a mapping of options")
    unknown = sorted(set(loaded) - set(defaults))
    if unknown:
        raise ValueError(f"{path}: unknown option(s) {unknown}; known: {sorted(defaults)}")
    return loaded


def load_preset(prefix: str, name: str, presets: Sequence[str], defaults: Mapping[str, Any]) -> dict[str, Any]:
    """The preset ``experiments/configs/<prefix>_<name>.yaml``; ``name`` must be one of ``presets``."""
    if name not in presets:
        raise ValueError(f"--preset must be one of {tuple(presets)}, got {name!r}")
    return read_options(CONFIG_DIR / f"{prefix}_{name}.yaml", defaults)
