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


def merge_options(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated with ``over``; an option whose value is a mapping in both is merged one level deep (a
    sub-config such as ``train: {lr: ...}`` keeps the keys ``over`` does not set)."""
    out = dict(base)
    for k, v in over.items():
        out[k] = {**out[k], **v} if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def layered_options(
    prefix: str, presets: Sequence[str], defaults: Mapping[str, Any], preset: str | None,
    config_file: str | Path | None, overrides: Mapping[str, Any],
) -> dict[str, Any]:
    """Defaults < preset ``<prefix>_<preset>.yaml`` < YAML ``config_file`` < ``overrides`` (None values ignored),
    merged with `merge_options`; unknown option names are an error naming them."""
    config = dict(defaults)
    if preset is not None:
        config = merge_options(config, load_preset(prefix, preset, presets, defaults))
    if config_file is not None:
        config = merge_options(config, read_options(Path(config_file), defaults))
    unknown = sorted(set(overrides) - set(defaults))
    if unknown:
        raise ValueError(f"unknown option(s) {unknown}; known: {sorted(defaults)}")
    return merge_options(config, {k: v for k, v in overrides.items() if v is not None})
