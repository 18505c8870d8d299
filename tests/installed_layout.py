"""Lay the source tree out as ``pip install`` does (``envs/`` as ``seal/envs/``, ...) for static tools.

`package_sources` reads ``[tool.setuptools]`` of ``pyproject.toml`` (installed package -> source folder); `build`
copies every package's ``.py`` files into ``OUT/seal/...`` plus ``pyproject.toml``: a scratch tree the
architecture tests may edit (e.g. add an upward import) without touching the checkout.
``python tests/installed_layout.py OUT`` does it from the shell.
"""

from __future__ import annotations

import shutil
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def package_sources(root: Path = ROOT) -> dict[str, Path]:
    """Installed package name -> its source folder, from pyproject's packages and package-dir."""
    cfg = tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]
    remap: dict[str, str] = cfg.get("package-dir", {})
    out = {}
    for pkg in cfg["packages"]:
        parts = pkg.split(".")
        for k in range(len(parts), 0, -1):
            prefix = ".".join(parts[:k])
            if prefix in remap:
                out[pkg] = root / remap[prefix] / Path(*parts[k:])
                break
        else:
            out[pkg] = root / Path(*parts)
    return out


def build(out: Path, root: Path = ROOT) -> dict[str, Path]:
    """Write the installed layout into ``out`` (replaced); returns installed file -> source file."""
    if out.exists():
        shutil.rmtree(out)
    files = {}
    for pkg, src in package_sources(root).items():
        dst = out.joinpath(*pkg.split("."))
        dst.mkdir(parents=True, exist_ok=True)
        for f in sorted(src.glob("*.py")):
            shutil.copy2(f, dst / f.name)
            files[dst / f.name] = f
    shutil.copy2(root / "pyproject.toml", out / "pyproject.toml")
    return files


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tests/installed_layout.py OUT_DIR")
    build(Path(sys.argv[1]))
