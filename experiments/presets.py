"""Where the YAML presets live (``experiments/configs/``) and how a preset name becomes a file.

The files are read by `seal.core.config.load_config` (defaults < preset < file < options < ``--set``)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from seal.core.config import ConfigError

CONFIG_DIR = Path(__file__).resolve().parent / "configs"

SKILLS_PRESETS = ("quick", "standard", "ego")
"""``seal fit skills --preset``: ``ego`` is the ReSkill ego's skills (a decoder blind to the previous action)."""


def preset_file(prefix: str, name: str, presets: Sequence[str]) -> Path:
    """The preset ``experiments/configs/<prefix>_<name>.yaml``; ``name`` must be one of ``presets``."""
    if name not in presets:
        raise ConfigError(f"--preset must be one of {tuple(presets)}, got {name!r}")
    return CONFIG_DIR / f"{prefix}_{name}.yaml"
