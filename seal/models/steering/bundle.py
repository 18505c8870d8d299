"""Fitted steering vectors of one trajectory prior, in one file (written by ``seal fit probes``).

A `SteeringVector` is a unit direction at a latent site (`seal.models.steering.latents`) and a unit length
(m in latent space): steering by ``value`` adds ``value * unit * direction`` to the target's state there.

* risk vectors (paper 000): ``unit`` is the RMS standard deviation of the latents at the site, so ``value`` is
  paper 000's alpha in standard deviations (the paper's unit-norm vector on latents of unit scale);
* control vectors (paper 002): ``unit`` is the class gap along the direction, so ``value = tau / 100`` and
  ``tau = 100 %`` moves a latent from the negative to the positive class mean.

Vectors are named ``FEATURE@SITE`` (e.g. ``risk_proximity@output``, ``speed_sae128@layer2``).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.atomic import atomic_write_bytes
from seal.core.errors import SealError
from seal.core.weights_file import check_header, read_weights_file

FORMAT = "seal-steering-vectors"
FORMAT_VERSION = 1
FILE_NAME = "steering.pt"
"""The bundle's file name inside the folder ``seal fit probes --out DIR`` writes."""


class SteeringFileError(SealError):
    """A steering file cannot be used; the message names the file and the problem."""


@dataclass(frozen=True)
class SteeringVector:
    """One steering direction (module docstring).

    Attributes:
        name: ``FEATURE@SITE``.
        site: latent site the offset is added at.
        direction: ``[d_model]`` unit vector.
        unit: latent-space length of ``value = 1``.
        kind: ``risk`` (alpha in standard deviations) or ``control`` (tau / 100 in class gaps).
    """

    name: str
    site: str
    direction: np.ndarray
    unit: float
    kind: str

    def offset(self, value: float) -> np.ndarray:
        """``[d_model]`` the latent offset of steering by ``value``."""
        return float(value) * self.unit * self.direction


@dataclass
class SteeringBundle:
    """The vectors fitted for one prior, and a summary of how (JSON-serialisable)."""

    vectors: dict[str, SteeringVector]
    info: dict[str, Any] = field(default_factory=dict)

    def get(self, name: str) -> SteeringVector:
        """The vector ``name``; an error listing the known names otherwise."""
        if name not in self.vectors:
            raise SteeringFileError(f"no steering vector {name!r}; this file has {', '.join(sorted(self.vectors))}")
        return self.vectors[name]

    def save(self, path: str | os.PathLike[str]) -> None:
        """Write atomically (torch.load(weights_only=True)-safe types only)."""
        state = {
            "format": FORMAT, "format_version": FORMAT_VERSION, "info": self.info,
            "vectors": {n: {"site": v.site, "direction": torch.as_tensor(v.direction, dtype=torch.float64),
                            "unit": float(v.unit), "kind": v.kind} for n, v in self.vectors.items()},
        }
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> SteeringBundle:
        """Load a file written by `save`, or the `FILE_NAME` in a folder written by ``seal fit probes``."""
        path = Path(path)
        if path.is_dir():
            path = path / FILE_NAME
        state = read_weights_file(path, "steering file", "seal fit probes", SteeringFileError)
        where = f"steering file {path}"
        check_header(state, where, FORMAT, FORMAT_VERSION, ("vectors",), SteeringFileError,
                     " (not written by seal fit probes)")
        vectors = {}
        try:
            for name, v in state["vectors"].items():
                direction = np.asarray(v["direction"].numpy(), dtype=np.float64)
                vectors[name] = SteeringVector(name, str(v["site"]), direction, float(v["unit"]), str(v["kind"]))
        except (KeyError, AttributeError, TypeError) as exc:
            raise SteeringFileError(f"{where}: field 'vectors' is malformed ({exc})") from None
        return cls(vectors, dict(state.get("info", {})))
