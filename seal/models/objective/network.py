"""The pi_score network: per-step features of an (ego roll-out, candidate) pair -> [f_coll, f_diff] in [0, 1].

A small polyline encoder in the spirit of VectorNet's sub-graph: a per-step MLP, a residual 1-D convolution over
time (local motion context: braking, closing in), a second per-step layer that sees the max-pooled polyline
feature next to its own, then masked max + mean pooling over the valid steps and an MLP head with a sigmoid. The
head also sees explicit per-pair scalars: the maxima of the raw features over the valid steps and the raw
features at the step of closest approach (its time, relative position and velocity there), and with
``candidate_prior`` the candidate's prior probability relative to the scenario's other candidates.
Both outputs are corrections in logit space of closeness ``exp(-min_t d / 8)`` (see `ObjectiveNet.forward`).
No normalisation layer couples the pairs of a batch, so a pair's output does not depend on its batch-mates.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, fields
from typing import Any, Literal, overload

import torch
from torch import nn

from seal.core.config import check_keys
from seal.core.scenario import N_FUTURE
from seal.models.objective.features import (
    EGO_FEATURE_NAMES,
    FEATURE_NAMES,
    N_CAND_PRIOR_FEATURES,
    N_EGO_FEATURES,
    N_FEATURES,
    N_PREV_ADV_FEATURES,
    ego_features,
    pair_features,
    prev_adversary_features,
)

N_OUTPUTS = 2
"""Heads: f_coll, f_diff."""
VALID_FEATURE = FEATURE_NAMES.index("valid")
DISTANCE_FEATURE = FEATURE_NAMES.index("distance")
CLOSENESS_FEATURE = FEATURE_NAMES.index("closeness")
EGO_VALID_FEATURE = EGO_FEATURE_NAMES.index("valid")


@dataclass(frozen=True)
class ObjectiveConfig:
    """Architecture of the pi_score network.

    Attributes:
        n_steps: timesteps per input track (candidate rows; 80 = the 8 s future).
        stride: every ``stride``-th step is fed to the encoder (2 = 0.2 s).
        hidden: width of the per-step and pooled features.
        kernel: temporal convolution width (steps after striding, odd).
        dropout: dropout probability before the head's layers (training only).
        diff_on_closeness: f_diff starts as a logit correction of closeness too (its learned weight starts at 1,
            else at 0).
        zero_init: the head's last layer starts at zero, so the untrained network's logits are exactly the
            weighted closeness logits (its ranking is closeness's) and training moves away from that only as far as
            the labels pull it.
        ego_branch: add a per-roll-out logit offset from the previous ego roll-out alone (`EgoBranch`): the level
            of f_diff / f_coll of a scenario, which does not depend on the candidate and so leaves the ranking of
            one roll-out's candidates to the pair network.
        prev_adversary: the per-step features also describe the previous roll-out's adversary
            (`seal.models.objective.features.prev_adversary_features`): inference then needs its track.
        candidate_prior: the head also sees the candidate's prior probability relative to the scenario's other
            candidates (`seal.models.objective.features.candidate_prior_features`): inference then needs the
            candidates' probabilities.
    """

    n_steps: int = N_FUTURE
    stride: int = 2
    hidden: int = 32
    kernel: int = 5
    dropout: float = 0.1
    diff_on_closeness: bool = True
    zero_init: bool = False
    ego_branch: bool = False
    prev_adversary: bool = False
    candidate_prior: bool = False

    @property
    def n_inputs(self) -> int:
        """Per-step input features of the pair network."""
        return N_FEATURES + (N_PREV_ADV_FEATURES if self.prev_adversary else 0)

    @property
    def n_pair_scalars(self) -> int:
        """Per-pair scalar inputs of the head besides the pooled features (the candidate's prior features)."""
        return N_CAND_PRIOR_FEATURES if self.candidate_prior else 0

    def __post_init__(self) -> None:
        for name in ("n_steps", "stride", "hidden", "kernel"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"objective config: {name} must be >= 1, got {getattr(self, name)}")
        if self.kernel % 2 != 1:
            raise ValueError(f"objective config: kernel must be odd, got {self.kernel}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"objective config: dropout must be in [0, 1), got {self.dropout}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], where: str = "objective config") -> ObjectiveConfig:
        check_keys(cls, d, where)
        types = {f.name: str(f.type) for f in fields(cls)}
        converters: dict[str, Callable[[Any], Any]] = {"float": float, "bool": bool}
        values: dict[str, Any] = {k: converters.get(types[k], int)(v) for k, v in d.items()}
        return cls(**values)


def stride_pool(feats: torch.Tensor, stride: int) -> torch.Tensor:
    """Keep every ``stride``-th step of ``feats [B, T, F]``, except that distance and closeness summarise their
    whole window of ``stride`` steps (smallest valid distance, largest closeness): a close pass between two kept
    steps must not vanish, since f_coll is about the closest approach."""
    if stride == 1:
        return feats
    b, t, f = feats.shape
    n = -(-t // stride)
    pad = n * stride - t
    if pad:
        feats = torch.cat([feats, torch.zeros(b, pad, f, dtype=feats.dtype, device=feats.device)], dim=1)
    win = feats.reshape(b, n, stride, f)
    out = win[:, :, 0].clone()
    valid = win[..., VALID_FEATURE] > 0.5
    dist = torch.where(valid, win[..., DISTANCE_FEATURE], torch.full_like(valid, 1e9, dtype=feats.dtype)).min(dim=2)
    any_valid = valid.any(dim=2)
    out[..., DISTANCE_FEATURE] = torch.where(any_valid, dist.values, torch.zeros_like(dist.values))
    out[..., CLOSENESS_FEATURE] = win[..., CLOSENESS_FEATURE].max(dim=2).values
    out[..., VALID_FEATURE] = any_valid.to(feats.dtype)
    return out


def closest_step(feats: torch.Tensor) -> torch.Tensor:
    """The features ``[B, F]`` of ``feats [B, T, F]`` at each pair's step of smallest valid distance (the closest
    approach; zeros for a pair with no valid step, as the features of invalid steps are)."""
    valid = feats[..., VALID_FEATURE] > 0.5
    dist = torch.where(valid, feats[..., DISTANCE_FEATURE], torch.full_like(feats[..., 0], 1e9))
    at = dist.argmin(dim=1)
    return torch.gather(feats, 1, at[:, None, None].expand(-1, 1, feats.shape[-1]))[:, 0]


def _masked_pool(h: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Max and mean of ``h [B, T, H]`` over steps where ``mask [B, T]``; zeros for rows with no valid step."""
    m = mask[..., None]
    any_valid = mask.any(dim=1, keepdim=True)
    mx = torch.where(m, h, torch.full_like(h, -1e4)).max(dim=1).values
    mx = torch.where(any_valid, mx, torch.zeros_like(mx))
    mean = (h * m).sum(dim=1) / m.sum(dim=1).clamp(min=1)
    return mx, mean


class EgoBranch(nn.Module):
    """Ego roll-out features ``[B, T, N_EGO_FEATURES]`` (`seal.models.objective.features.ego_features`) -> logit
    offsets ``[B, 2]``: per-step MLP, masked max + mean pooling over the valid steps, a linear layer (zero at the
    start, so the branch starts as no offset)."""

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.step = nn.Sequential(nn.Linear(N_EGO_FEATURES, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU())
        self.out = nn.Linear(2 * hidden, N_OUTPUTS)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, feats: torch.Tensor) -> torch.Tensor:
        valid = feats[..., EGO_VALID_FEATURE] > 0.5
        mx, mean = _masked_pool(self.step(feats), valid)
        return self.out(torch.cat([mx, mean], dim=-1))


class ObjectiveNet(nn.Module):
    """Pairs' per-step features ``[B, T, F]`` + validity ``[B, T]`` + features at the closest approach ``[B, F]``
    (``F = config.n_inputs``) -> logits ``[B, 2]`` (both relative to the logit of the largest closeness feature)."""

    def __init__(self, config: ObjectiveConfig) -> None:
        super().__init__()
        self.config = config
        h, n_in = config.hidden, config.n_inputs
        self.step = nn.Sequential(nn.Linear(n_in, h), nn.ReLU(), nn.Linear(h, h), nn.ReLU())
        self.conv = nn.Conv1d(h, h, config.kernel, padding=config.kernel // 2)
        self.mix = nn.Sequential(nn.Linear(2 * h, h), nn.ReLU())
        # The head also sees the per-pair maxima of the raw features (e.g. the largest closeness = the closest
        # approach): a direct path for what f_coll is made of, which the deep path then corrects.
        n_head_in = 2 * h + 2 * n_in + config.n_pair_scalars
        self.head = nn.Sequential(nn.Dropout(config.dropout), nn.Linear(n_head_in, h), nn.ReLU(),
                                  nn.Dropout(config.dropout), nn.Linear(h, N_OUTPUTS))
        if config.zero_init:
            last = self.head[-1]
            assert isinstance(last, nn.Linear)
            nn.init.zeros_(last.weight)
            nn.init.zeros_(last.bias)
        self.ego_branch = EgoBranch(h) if config.ego_branch else None
        # Learned weight of the closeness logit in each output (starts at 1 = "no reaction" for f_coll).
        self.close_gain = nn.Parameter(torch.tensor([1.0, 1.0 if config.diff_on_closeness else 0.0]))

    def forward(self, feats: torch.Tensor, valid: torch.Tensor, closest: torch.Tensor,
                scalars: torch.Tensor | None = None) -> torch.Tensor:
        correction, prior = self.parts(feats, valid, closest, scalars)
        return correction + prior

    def parts(self, feats: torch.Tensor, valid: torch.Tensor, closest: torch.Tensor,
              scalars: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The logits ``[B, 2]`` split into the learned correction and the weighted closeness logit; ``scalars
        [B, config.n_pair_scalars]``: the per-pair scalar inputs (None when the config has none)."""
        h = self.step(feats)
        h = h + torch.relu(self.conv(h.transpose(1, 2)).transpose(1, 2))
        g, _ = _masked_pool(h, valid)
        h = self.mix(torch.cat([h, g[:, None].expand_as(h)], dim=-1))
        mx, mean = _masked_pool(h, valid)
        raw, _ = _masked_pool(feats, valid)
        head_in = [mx, mean, raw, closest] + ([] if scalars is None else [scalars])
        out = self.head(torch.cat(head_in, dim=-1))
        # Both heads are corrections (in logit space) of the closest approach to the previous roll-out,
        # exp(-min_t d / 8): exactly f_coll when the ego does not react, which most candidates do not provoke; and
        # a candidate that passes close is the one that makes the ego change its behaviour (f_diff).
        close = raw[:, CLOSENESS_FEATURE : CLOSENESS_FEATURE + 1].clamp(1e-4, 1 - 1e-4)
        return out, self.close_gain * torch.log(close / (1 - close))

    @overload
    def score_pairs(
        self, cand_xy: torch.Tensor, cand_heading: torch.Tensor, ego_xy: torch.Tensor, ego_heading: torch.Tensor,
        ego_valid: torch.Tensor, with_correction: Literal[False] = False, adv_xy: torch.Tensor | None = None,
        adv_valid: torch.Tensor | None = None, cand_prior: torch.Tensor | None = None,
    ) -> torch.Tensor: ...

    @overload
    def score_pairs(
        self, cand_xy: torch.Tensor, cand_heading: torch.Tensor, ego_xy: torch.Tensor, ego_heading: torch.Tensor,
        ego_valid: torch.Tensor, with_correction: Literal[True], adv_xy: torch.Tensor | None = None,
        adv_valid: torch.Tensor | None = None, cand_prior: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]: ...

    def score_pairs(
        self, cand_xy: torch.Tensor, cand_heading: torch.Tensor, ego_xy: torch.Tensor, ego_heading: torch.Tensor,
        ego_valid: torch.Tensor, with_correction: bool = False, adv_xy: torch.Tensor | None = None,
        adv_valid: torch.Tensor | None = None, cand_prior: torch.Tensor | None = None,
    ) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """Predicted ``[f_coll, f_diff]`` ``[..., 2]`` for pairs given as tracks (shapes as in
        `seal.models.objective.features.pair_features`; leading axes broadcast); with ``with_correction`` also the
        learned logit corrections ``[..., 2]`` (for training's penalty on them). ``adv_xy [..., T, 2]`` /
        ``adv_valid [..., T]``: the previous roll-outs' adversary (shaped like the ego's), needed by a network with
        ``config.prev_adversary`` and ignored by one without. ``cand_prior [..., N_CAND_PRIOR_FEATURES]``: the
        candidates' `seal.models.objective.features.candidate_prior_features` (leading axes broadcast like the
        tracks'), needed by a network with ``config.candidate_prior`` and ignored by one without."""
        feats = pair_features(cand_xy, cand_heading, ego_xy, ego_heading, ego_valid)
        if self.config.prev_adversary:
            if adv_xy is None or adv_valid is None:
                raise ValueError("objective: this model ranks with the previous roll-outs' adversary (prev_adversary); "
                                 "pass adv_xy [K, T, 2] and adv_valid [K, T]")
            extra = prev_adversary_features(cand_xy, cand_heading, ego_xy, ego_heading, ego_valid, adv_xy, adv_valid)
            feats = torch.cat([feats, extra.expand(*feats.shape[:-1], extra.shape[-1])], dim=-1)
        lead = feats.shape[:-2]
        feats = feats.reshape(-1, *feats.shape[-2:])
        closest = closest_step(feats)
        feats = stride_pool(feats, self.config.stride)
        valid = feats[..., VALID_FEATURE] > 0.5
        scalars = None
        if self.config.candidate_prior:
            if cand_prior is None:
                raise ValueError("objective: this model ranks with the candidates' prior probabilities "
                                 "(candidate_prior); pass their probabilities")
            scalars = cand_prior.expand(*lead, cand_prior.shape[-1]).reshape(-1, cand_prior.shape[-1])
        correction, prior = self.parts(feats, valid, closest, scalars)
        correction = correction.reshape(*lead, N_OUTPUTS)
        if self.ego_branch is not None:
            correction = correction + self._ego_offset(ego_xy, ego_heading, ego_valid).expand_as(correction)
        pred = torch.sigmoid(correction + prior.reshape(*lead, N_OUTPUTS))
        return (pred, correction) if with_correction else pred

    def _ego_offset(self, ego_xy: torch.Tensor, ego_heading: torch.Tensor, ego_valid: torch.Tensor) -> torch.Tensor:
        """`EgoBranch` offsets ``[..., 2]`` of the ego roll-outs (their own leading axes, e.g. ``[K, 1]``: computed
        once per roll-out, not once per pair)."""
        assert self.ego_branch is not None
        lead = torch.broadcast_shapes(ego_xy.shape[:-1], ego_heading.shape, ego_valid.shape)
        feats = ego_features(ego_xy.expand(*lead, 2), ego_heading.expand(lead), ego_valid.expand(lead))
        feats = feats[..., :: self.config.stride, :]
        out = self.ego_branch(feats.reshape(-1, *feats.shape[-2:]))
        return out.reshape(*lead[:-1], N_OUTPUTS)
