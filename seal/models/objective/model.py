"""`ObjectiveModel`: the learned objective pi_score (thesis 6.3.1) for inference, saving and loading.

``predict`` gives the predicted ``[f_coll, f_diff]`` of every (previous ego roll-out, candidate) pair; ``rank``
the SEAL selection score of every candidate: the mean over the K roll-outs of ``f_coll + f_diff``. Both run all
``K x N`` pairs in one forward pass.

Alignment (the caller's job): row ``t`` of the candidate arrays and of the ego arrays is the same scenario step.
Candidates from the trajectory prior have row ``j`` = scenario step ``CURRENT_STEP + 1 + j``; cut ego roll-outs
indexed by scenario step with `seal.models.objective.features.align_ego_rollouts`.

File format: ``torch.save`` of a dict (format tag, version, config, state dict, JSON-safe info) read back with
``torch.load(weights_only=True)`` (nothing is unpickled), plus a readable JSON copy of config and info next to it
(``<name>.json``; informational, loading does not need it).
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.weights_file import check_header, read_weights_file
from seal.models.objective.features import candidate_prior_features
from seal.models.objective.network import ObjectiveConfig, ObjectiveNet

RANK_HEADS = {"coll+diff": (0, 1), "coll": (0,), "diff": (1,)}
"""Which predicted terms `ObjectiveModel.rank` sums: the thesis's ``f_coll + f_diff`` (`DEFAULT_RANK_HEADS`), or one
head alone (an ablation of the ranking rule)."""
DEFAULT_RANK_HEADS = "coll+diff"
FORMAT = "seal-objective-model"
FORMAT_VERSION = 2
"""2: closest-approach inputs, dropout, learned closeness gains (version-1 files: retrain with seal fit objective)."""


class ObjectiveFileError(ValueError):
    """An objective model file is unreadable or not an objective model; the message names the file."""


def _tensor(a: np.ndarray, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)


class ObjectiveModel:
    """pi_score: predicted f_coll and f_diff of candidate adversary futures against previous ego roll-outs.

    Args:
        config: network architecture.
        net: trained network (a fresh, untrained one when None).
        info: JSON-serialisable metadata (training data, metrics) saved with the model.
    """

    def __init__(self, config: ObjectiveConfig | None = None, net: ObjectiveNet | None = None,
                 info: dict[str, Any] | None = None) -> None:
        self.config = config or ObjectiveConfig()
        self.net = net if net is not None else ObjectiveNet(self.config)
        self.net.eval()
        self.info = dict(info or {})

    # ------------------------------------------------------------------------------------------------ inference
    def _check(self, cand_xy: np.ndarray, cand_heading: np.ndarray, ego_xy: np.ndarray, ego_heading: np.ndarray,
               ego_valid: np.ndarray, adv_xy: np.ndarray | None, adv_valid: np.ndarray | None) -> None:
        n, t = cand_heading.shape[:2] if cand_heading.ndim == 2 else (-1, -1)
        k = ego_valid.shape[0] if ego_valid.ndim == 2 else -1
        ok = (
            n >= 0 and k >= 0 and cand_xy.shape == (n, t, 2) and ego_xy.shape == (k, t, 2)
            and ego_heading.shape == (k, t) and ego_valid.shape == (k, t)
        )
        if not ok:
            raise ValueError(
                "objective: expected cand_xy [N, T, 2], cand_heading [N, T], ego_xy [K, T, 2], ego_heading [K, T], "
                f"ego_valid [K, T]; got {cand_xy.shape}, {cand_heading.shape}, {ego_xy.shape}, {ego_heading.shape}, "
                f"{ego_valid.shape}"
            )
        if adv_xy is not None and (adv_xy.shape != (k, t, 2) or adv_valid is None or adv_valid.shape != (k, t)):
            raise ValueError(f"objective: expected adv_xy [K, T, 2] and adv_valid [K, T] like the ego's "
                             f"{ego_xy.shape}; got {adv_xy.shape}, {None if adv_valid is None else adv_valid.shape}")
        if t != self.config.n_steps:
            raise ValueError(
                f"objective: tracks have {t} steps, the model was trained on {self.config.n_steps} (candidate row j = "
                "scenario step CURRENT_STEP + 1 + j; cut ego roll-outs with seal.models.objective.align_ego_rollouts)"
            )

    def predict(self, cand_xy: np.ndarray, cand_heading: np.ndarray, ego_xy: np.ndarray, ego_heading: np.ndarray,
                ego_valid: np.ndarray, adv_xy: np.ndarray | None = None, adv_valid: np.ndarray | None = None,
                cand_probs: np.ndarray | None = None) -> np.ndarray:
        """Predicted ``[K, N, 2]`` (f_coll, f_diff), each in [0, 1].

        Args:
            cand_xy: ``[N, T, 2]`` candidate adversary positions (m, world frame).
            cand_heading: ``[N, T]`` candidate headings (rad).
            ego_xy: ``[K, T, 2]`` previous ego roll-outs (m); row ``t`` = the candidates' row ``t`` (same step).
            ego_heading: ``[K, T]`` ego headings (rad).
            ego_valid: ``[K, T]`` bool, False after a roll-out ended.
            adv_xy: ``[K, T, 2]`` the adversary of each previous roll-out (m), same steps; needed by a model
                trained with ``prev_adversary`` (`ObjectiveConfig`), ignored by others.
            adv_valid: ``[K, T]`` bool, False where that adversary was not on the road.
            cand_probs: ``[N]`` the candidates' prior probabilities; needed by a model trained with
                ``candidate_prior``, ignored by others.
        """
        arrays = [np.asarray(a) for a in (cand_xy, cand_heading, ego_xy, ego_heading, ego_valid)]
        adv = None if adv_xy is None else np.asarray(adv_xy)
        adv_v = None if adv_valid is None else np.asarray(adv_valid)
        cx, ch, ex, eh, ev = arrays
        self._check(cx, ch, ex, eh, ev, adv, adv_v)
        prior = None
        if cand_probs is not None:
            probs = np.asarray(cand_probs, dtype=np.float64)
            if probs.shape != (cx.shape[0],):
                raise ValueError(f"objective: expected cand_probs [N] = [{cx.shape[0]}], got {probs.shape}")
            if self.config.candidate_prior:  # other models ignore them: no work on SEAL's ranking path
                prior = candidate_prior_features(_tensor(probs))[None]
        with torch.inference_mode():
            out = self.net.score_pairs(
                _tensor(cx)[None], _tensor(ch)[None], _tensor(ex)[:, None], _tensor(eh)[:, None],
                _tensor(ev, torch.bool)[:, None],
                adv_xy=None if adv is None else _tensor(adv)[:, None],
                adv_valid=None if adv_v is None else _tensor(adv_v, torch.bool)[:, None], cand_prior=prior,
            )
        return out.numpy().astype(np.float64)

    def rank(self, cand_xy: np.ndarray, cand_heading: np.ndarray, ego_xy: np.ndarray, ego_heading: np.ndarray,
             ego_valid: np.ndarray, heads: str = DEFAULT_RANK_HEADS, adv_xy: np.ndarray | None = None,
             adv_valid: np.ndarray | None = None, cand_probs: np.ndarray | None = None) -> np.ndarray:
        """SEAL's selection score ``[N]``: mean over the K roll-outs of predicted ``f_coll + f_diff`` (in [0, 2];
        higher = more critical), or of one head alone (``heads``, a key of `RANK_HEADS`). Other arguments as in
        `predict`."""
        if heads not in RANK_HEADS:
            raise ValueError(f"objective heads must be one of {', '.join(RANK_HEADS)}, got {heads!r}")
        pred = self.predict(cand_xy, cand_heading, ego_xy, ego_heading, ego_valid, adv_xy, adv_valid, cand_probs)
        return pred[..., list(RANK_HEADS[heads])].sum(axis=-1).mean(axis=0)

    # ------------------------------------------------------------------------------------------------------ I/O
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the model to ``path`` (atomic) and its config + info to ``path`` with suffix ``.json``."""
        path = Path(path)
        info = json.loads(json.dumps(self.info, default=str))
        state = {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "config": self.config.to_dict(),
            "state_dict": {k: v.detach().clone() for k, v in self.net.state_dict().items()},
            "info_json": json.dumps(info),
        }
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write_bytes(path, buf.getvalue())
        atomic_write_json(path.with_suffix(".json"), {"format": FORMAT, "format_version": FORMAT_VERSION,
                                                      "config": self.config.to_dict(), "info": info})

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> ObjectiveModel:
        """Load a model written by `save` (``torch.load(weights_only=True)``)."""
        path = Path(path)
        state = read_weights_file(path, "objective model file", "seal fit objective", ObjectiveFileError)
        where = f"objective model file {path}"
        check_header(state, where, FORMAT, FORMAT_VERSION, ("config", "state_dict", "info_json"), ObjectiveFileError,
                     " (is this a pi_score model?)")
        try:
            config = ObjectiveConfig.from_dict(dict(state["config"]), where=f"{where}, field 'config'")
            net = ObjectiveNet(config)
            net.load_state_dict(state["state_dict"])
            info = json.loads(state["info_json"])
        except (ValueError, TypeError, RuntimeError) as exc:
            raise ObjectiveFileError(f"{where}: {exc}") from None
        return cls(config, net, info)
