"""`LabelSet`: simulated outcomes pi_score learns from, one row per base scenario (built by
``seal.experiments.fitting.objective_labels``; this module only holds, checks, saves and loads them).

For every scenario, N candidate adversary futures were each rolled out against the reactive heuristic ego, and so
was the logged adversary. That gives M = N + 1 ego roll-outs: row 0 is the logged-adversary episode, row
``1 + j`` the episode against candidate ``j``. Because the heuristic ego is deterministic given the adversary, any
of the M roll-outs can serve as the "previous roll-out" input of any candidate ``j``, so one scenario yields
``M x N`` training pairs with labels ``f_coll[j]`` (ego vs adversary in episode j; does not depend on the previous
roll-out) and ``f_diff[i, j]`` (ego of episode j vs the previous roll-out i).

All tracks are cut to the candidates' steps: row ``t`` = scenario step ``CURRENT_STEP + 1 + t``.
Stored as ``.npz`` without pickle (``np.load(allow_pickle=False)``).
"""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.atomic import atomic_write_bytes

LOGGED_ROW = 0
"""Row of the ego roll-out against the logged adversary in `LabelSet.ego_xy` etc."""


@dataclass(frozen=True)
class LabelSet:
    """Simulated labels of S scenarios with N candidates and M = N + 1 ego roll-outs each, T steps.

    Attributes:
        scenario_ids: ``[S]`` str.
        cand_xy: ``[S, N, T, 2]`` float32 candidate positions (m, world frame).
        cand_heading: ``[S, N, T]`` float32 candidate headings (rad).
        probs: ``[S, N]`` float32 prior probabilities of the candidates.
        ego_xy: ``[S, M, T, 2]`` float32 executed ego positions (row 0: logged adversary; 1 + j: candidate j).
        ego_heading: ``[S, M, T]`` float32 ego headings (rad).
        ego_valid: ``[S, M, T]`` bool, False after the episode ended.
        f_coll: ``[S, N]`` float32 label of candidate j (its own episode; 1 when the ego hit the adversary).
        f_diff: ``[S, M, N]`` float32 label of candidate j given previous roll-out i.
        crashed: ``[S, N]`` bool: the ego hit the adversary in candidate j's episode.
        cat_score: ``[S, N]`` float32 CAT's heuristic score of candidate j against the logged-adversary
            roll-out (the baseline of the report).
        adv_xy: ``[S, M, T, 2]`` float32 executed adversary positions of each roll-out (m; row 0 the logged
            adversary, 1 + j what the adversary drove for candidate j: the candidate, then the skills after SEAL's
            switch): the previous roll-out's adversary, an input of pi_score (`seal.models.objective.features.
            prev_adversary_features`).
        adv_valid: ``[S, M, T]`` bool, False where the adversary was not on the road.
        sizes_m: ``[S, 2, 2]`` float32 (length, width) of the ego (row 0) and the adversary (row 1) (m): what CAT's
            box test needs to score candidates against other previous roll-outs than the logged one.
    """

    scenario_ids: np.ndarray
    cand_xy: np.ndarray
    cand_heading: np.ndarray
    probs: np.ndarray
    ego_xy: np.ndarray
    ego_heading: np.ndarray
    ego_valid: np.ndarray
    f_coll: np.ndarray
    f_diff: np.ndarray
    crashed: np.ndarray
    cat_score: np.ndarray
    adv_xy: np.ndarray
    adv_valid: np.ndarray
    sizes_m: np.ndarray

    def __post_init__(self) -> None:
        s, n, t, _ = np.shape(self.cand_xy)
        m = n + 1
        expected = {
            "scenario_ids": (s,), "cand_xy": (s, n, t, 2), "cand_heading": (s, n, t), "probs": (s, n),
            "ego_xy": (s, m, t, 2), "ego_heading": (s, m, t), "ego_valid": (s, m, t), "f_coll": (s, n),
            "f_diff": (s, m, n), "crashed": (s, n), "cat_score": (s, n),
            "adv_xy": (s, m, t, 2), "adv_valid": (s, m, t), "sizes_m": (s, 2, 2),
        }
        for name, shape in expected.items():
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(
                    f"LabelSet: field {name!r} has shape {np.shape(getattr(self, name))}, expected {shape}"
                )

    @property
    def n_scenarios(self) -> int:
        return int(self.cand_xy.shape[0])

    @property
    def n_candidates(self) -> int:
        return int(self.cand_xy.shape[1])

    @property
    def n_steps(self) -> int:
        return int(self.cand_xy.shape[2])

    def subset(self, rows: np.ndarray | Sequence[int]) -> LabelSet:
        """The scenarios at ``rows``."""
        rows = np.asarray(rows, dtype=np.int64)
        return LabelSet(**{f.name: getattr(self, f.name)[rows] for f in fields(self)})

    @classmethod
    def concat(cls, parts: Sequence[LabelSet]) -> LabelSet:
        if not parts:
            raise ValueError("LabelSet.concat: no parts")
        shapes = {p.cand_xy.shape[1:] for p in parts}
        if len(shapes) > 1:
            raise ValueError(f"LabelSet.concat: parts differ in candidates / steps: {sorted(shapes)}")
        return cls(**{f.name: np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)})

    def save(self, path: str | os.PathLike[str]) -> None:
        """Atomic ``.npz`` write (compressed)."""
        buf = io.BytesIO()
        # Any: numpy's stubs let a ``**dict`` of arrays collide with the ``allow_pickle: bool`` keyword.
        arrays: dict[str, Any] = {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}
        np.savez_compressed(buf, **arrays)
        atomic_write_bytes(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> LabelSet:
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {f.name: z[f.name] for f in fields(cls)}
        except KeyError as exc:
            raise ValueError(f"label file {path}: missing array {exc}; rebuild it (delete the file and re-run)"
                             ) from None
        except (OSError, ValueError, EOFError) as exc:
            raise ValueError(f"label file {path} cannot be read ({type(exc).__name__}: {exc}); delete it and re-run "
                             "to rebuild it") from None
        return cls(**arrays)
