"""Compare two dataset folders array by array: every array of every shard (exact, NaN equal to NaN) and the
manifests less their ``created`` time. A dev tool for changes that must not change generated data (issue 23):

    .venv/bin/python tools/compare_datasets.py DATASET_A DATASET_B

Exits 0 when they are identical, 1 otherwise (and names each difference).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

VOLATILE = ("created",)
"""Manifest keys that differ between two builds of the same data (the build time)."""


def _strip(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _strip(v) for k, v in d.items() if k not in VOLATILE}
    if isinstance(d, list):
        return [_strip(v) for v in d]
    return d


def compare(a: Path, b: Path) -> list[str]:
    """The differences between datasets ``a`` and ``b`` (empty when identical)."""
    files_a = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    if files_a != files_b:
        return [f"other files: {sorted(set(files_a) ^ set(files_b))}"]
    diffs = []
    n_arrays = 0
    for rel in files_a:
        if rel.suffix == ".npz":
            with np.load(a / rel, allow_pickle=False) as za, np.load(b / rel, allow_pickle=False) as zb:
                if sorted(za.files) != sorted(zb.files):
                    diffs.append(f"{rel}: other arrays")
                    continue
                for key in za.files:
                    x, y = za[key], zb[key]
                    n_arrays += 1
                    nan = x.dtype.kind in "fc"
                    if x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y, equal_nan=nan):
                        diffs.append(f"{rel}[{key}]: {x.dtype}{x.shape} vs {y.dtype}{y.shape} differ")
        elif rel.suffix == ".json":
            if _strip(json.loads((a / rel).read_text())) != _strip(json.loads((b / rel).read_text())):
                diffs.append(f"{rel}: other content")
        elif (a / rel).read_bytes() != (b / rel).read_bytes():
            diffs.append(f"{rel}: other bytes")
    print(f"{len(files_a)} files, {n_arrays} arrays compared, {len(diffs)} differences")
    return diffs


def main() -> int:
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    diffs = compare(Path(sys.argv[1]), Path(sys.argv[2]))
    for d in diffs:
        print("DIFF", d)
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
