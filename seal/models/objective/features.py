"""Per-timestep input features of pi_score: a previous ego roll-out seen from a candidate adversary.

For a pair (ego roll-out, candidate) and every timestep ``t`` (the same scenario step in both), the ego is
expressed in the candidate adversary's frame at ``t`` (origin at the candidate's position, x along its heading):
relative position, distance, relative heading and relative velocity; plus the candidate seen from the ego (is it
ahead or beside?), both speeds, a validity flag and the time. Invalid ego steps have every feature zeroed except
the time, and the valid flag says so.

Everything is torch and broadcasts over leading batch axes, so training (gathered pairs ``[B, T]``) and
inference (all pairs ``[K, N, T]`` at once) share one implementation.
"""

from __future__ import annotations

import numpy as np
import torch

from seal.core.scenario import CURRENT_STEP, DT_S, N_FUTURE

POS_SCALE_M = 20.0
"""Positions and distances are divided by this (m)."""
SPEED_SCALE_MPS = 10.0
"""Speeds and velocities are divided by this (m/s)."""
CLOSE_SCALE_M = 8.0
"""Distance scale of the closeness feature ``exp(-d / 8)`` (the b of f_coll)."""
POS_CLIP = 5.0
"""Scaled positions are clipped to +-this (100 m): farther away nothing interacts."""

FEATURE_NAMES = (
    "ego_x_in_adv", "ego_y_in_adv", "distance", "closeness", "cos_rel_heading", "sin_rel_heading",
    "adv_x_in_ego", "adv_y_in_ego", "rel_vx_in_adv", "rel_vy_in_adv", "adv_speed", "ego_speed", "valid", "time",
)
N_FEATURES = len(FEATURE_NAMES)


def to_frame(dx: torch.Tensor, dy: torch.Tensor, heading: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """World-frame vectors ``(dx, dy)`` expressed in a frame rotated by ``heading`` (rad): ``(along, left)``."""
    c, s = torch.cos(heading), torch.sin(heading)
    return c * dx + s * dy, -s * dx + c * dy


def _velocity(xy: torch.Tensor) -> torch.Tensor:
    """``[..., T, 2]`` finite-difference velocity (m/s); step 0 takes the first forward difference."""
    vel = torch.diff(xy, dim=-2) / DT_S
    return torch.cat([vel[..., :1, :], vel], dim=-2)


def pair_features(
    cand_xy: torch.Tensor, cand_heading: torch.Tensor, ego_xy: torch.Tensor, ego_heading: torch.Tensor,
    ego_valid: torch.Tensor,
) -> torch.Tensor:
    """Features ``[..., T, N_FEATURES]`` (order: `FEATURE_NAMES`) of ego roll-outs against candidates.

    Args:
        cand_xy: ``[..., T, 2]`` candidate positions (m, world frame).
        cand_heading: ``[..., T]`` candidate headings (rad).
        ego_xy: ``[..., T, 2]`` ego positions (m); row ``t`` is the same scenario step as the candidate's.
        ego_heading: ``[..., T]`` ego headings (rad).
        ego_valid: ``[..., T]`` bool, False where the roll-out had ended (its xy / heading are ignored there).

    All leading axes broadcast against each other (e.g. ego ``[K, 1, T, 2]`` with candidates ``[1, N, T, 2]``).
    """
    valid = ego_valid.to(cand_xy.dtype)
    # A finished roll-out holds its last position (zeros would invent a jump in the velocity features).
    ego_xy = _hold_last(ego_xy, ego_valid)
    dx = ego_xy[..., 0] - cand_xy[..., 0]
    dy = ego_xy[..., 1] - cand_xy[..., 1]
    ex, ey = to_frame(dx, dy, cand_heading)
    ax, ay = to_frame(-dx, -dy, ego_heading)
    dist = torch.sqrt(dx * dx + dy * dy + 1e-12)
    rel = ego_heading - cand_heading
    cand_v = _velocity(cand_xy)
    ego_v = _velocity(ego_xy) * torch.cat([valid[..., :1], valid[..., 1:] * valid[..., :-1]], dim=-1)[..., None]
    rvx, rvy = to_frame(ego_v[..., 0] - cand_v[..., 0], ego_v[..., 1] - cand_v[..., 1], cand_heading)
    n_steps = cand_xy.shape[-2]
    time = torch.arange(n_steps, dtype=cand_xy.dtype, device=cand_xy.device) / max(n_steps - 1, 1)
    feats = [
        (ex / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP), (ey / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP),
        (dist / POS_SCALE_M).clamp(max=POS_CLIP), torch.exp(-dist / CLOSE_SCALE_M), torch.cos(rel), torch.sin(rel),
        (ax / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP), (ay / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP),
        rvx / SPEED_SCALE_MPS, rvy / SPEED_SCALE_MPS,
        torch.linalg.vector_norm(cand_v, dim=-1) / SPEED_SCALE_MPS,
        torch.linalg.vector_norm(ego_v, dim=-1) / SPEED_SCALE_MPS,
    ]
    shape = torch.broadcast_shapes(*(f.shape for f in feats), valid.shape)
    out = torch.stack([f.expand(shape) * valid.expand(shape) for f in feats]
                      + [valid.expand(shape), time.expand(shape)], dim=-1)
    return out


PREV_ADV_FEATURE_NAMES = ("prev_adv_x_in_cand", "prev_adv_y_in_cand", "prev_adv_to_cand_distance",
                          "prev_adv_x_in_ego", "prev_adv_y_in_ego", "prev_adv_closeness")
N_PREV_ADV_FEATURES = len(PREV_ADV_FEATURE_NAMES)


def prev_adversary_features(
    cand_xy: torch.Tensor, cand_heading: torch.Tensor, ego_xy: torch.Tensor, ego_heading: torch.Tensor,
    ego_valid: torch.Tensor, adv_xy: torch.Tensor, adv_valid: torch.Tensor,
) -> torch.Tensor:
    """Features ``[..., T, N_PREV_ADV_FEATURES]`` (order: `PREV_ADV_FEATURE_NAMES`) of the adversary of the previous
    roll-out: where it was relative to the candidate (the candidate's frame, and their distance) and relative to the
    previous ego (the ego's frame, and the closeness ``exp(-d / 8)``).

    Why: f_diff compares the ego's next roll-out with the previous one, and the previous one is the ego's answer to
    the previous adversary. A candidate that drives like the previous adversary leaves the ego's path as it was
    (f_diff near 0) even when it comes close, and one that stays away from an ego the previous adversary pressed
    moves the ego's path; neither is visible from the ego's roll-out alone.

    Args:
        cand_xy, cand_heading, ego_xy, ego_heading, ego_valid: as in `pair_features`.
        adv_xy: ``[..., T, 2]`` the previous roll-out's adversary positions (m), same steps.
        adv_valid: ``[..., T]`` bool, False where that adversary was not on the road.

    Steps where the previous ego or its adversary is invalid have every feature zeroed.
    """
    valid = (ego_valid & adv_valid).to(cand_xy.dtype)
    ego_xy = _hold_last(ego_xy, ego_valid)
    adv_xy = _hold_last(adv_xy, adv_valid)
    cx, cy = to_frame(adv_xy[..., 0] - cand_xy[..., 0], adv_xy[..., 1] - cand_xy[..., 1], cand_heading)
    cand_dist = torch.sqrt(cx * cx + cy * cy + 1e-12)
    dx, dy = adv_xy[..., 0] - ego_xy[..., 0], adv_xy[..., 1] - ego_xy[..., 1]
    ex, ey = to_frame(dx, dy, ego_heading)
    ego_dist = torch.sqrt(dx * dx + dy * dy + 1e-12)
    feats = [(cx / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP), (cy / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP),
             (cand_dist / POS_SCALE_M).clamp(max=POS_CLIP), (ex / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP),
             (ey / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP), torch.exp(-ego_dist / CLOSE_SCALE_M)]
    shape = torch.broadcast_shapes(*(f.shape for f in feats), valid.shape)
    return torch.stack([f.expand(shape) * valid.expand(shape) for f in feats], dim=-1)


CAND_PRIOR_FEATURE_NAMES = ("log_prob_below_best", "prob_rank")
N_CAND_PRIOR_FEATURES = len(CAND_PRIOR_FEATURE_NAMES)
LOG_PROB_SCALE = 10.0
"""Log-probability gaps are divided by this (nats) and clipped at -`POS_CLIP` (50 nats below the best)."""


def candidate_prior_features(probs: torch.Tensor) -> torch.Tensor:
    """Per-candidate features ``[..., N, N_CAND_PRIOR_FEATURES]`` (order: `CAND_PRIOR_FEATURE_NAMES`) of the
    trajectory prior's probabilities ``probs [..., N]`` of one scenario's N candidates: how far the candidate's log
    probability lies below the best one's, and its rank among them (0 = the most probable, 1 = the least; ties share
    the better rank).

    Why: what the adversary can really drive depends on how plausible the candidate is (a low-probability mode is
    often one the adversary's controller cannot follow, or one the skill switch leaves at once), and CAT's score,
    which ranks the logged previous roll-out's candidates better than closeness, weighs hits by exactly this. Both
    features are relative to the scenario's own candidates, so they do not depend on how sharp the prior is.
    """
    logp = torch.log(probs.clamp(min=1e-30))
    gap = ((logp - logp.max(dim=-1, keepdim=True).values) / LOG_PROB_SCALE).clamp(min=-POS_CLIP)
    n = probs.shape[-1]
    better = (logp[..., None, :] > logp[..., :, None]).sum(dim=-1).to(probs.dtype)
    return torch.stack([gap, better / max(n - 1, 1)], dim=-1)


EGO_FEATURE_NAMES = ("x_in_start", "y_in_start", "cos_heading_change", "sin_heading_change", "speed", "accel",
                     "valid", "time")
N_EGO_FEATURES = len(EGO_FEATURE_NAMES)
ACCEL_SCALE_MPS2 = 5.0
"""Accelerations are divided by this (m/s^2)."""


def ego_features(ego_xy: torch.Tensor, ego_heading: torch.Tensor, ego_valid: torch.Tensor) -> torch.Tensor:
    """Features ``[..., T, N_EGO_FEATURES]`` (order: `EGO_FEATURE_NAMES`) of previous ego roll-outs on their own,
    without any candidate: how the ego drove (position and heading change in the frame of its first valid step,
    speed, acceleration). They describe the scenario and the roll-out, not a candidate, so anything computed from
    them shifts all candidates of one (scenario, roll-out) group alike. Invalid steps are zeroed except the valid
    flag and the time (as in `pair_features`).

    Args:
        ego_xy: ``[..., T, 2]`` ego positions (m, world frame).
        ego_heading: ``[..., T]`` ego headings (rad).
        ego_valid: ``[..., T]`` bool.
    """
    valid = ego_valid.to(ego_xy.dtype)
    xy = _hold_last(ego_xy, ego_valid)
    first = ego_valid.int().argmax(dim=-1, keepdim=True)
    x0 = torch.gather(xy, -2, first[..., None].expand(*first.shape, 2))
    h0 = torch.gather(ego_heading, -1, first)
    x, y = to_frame(xy[..., 0] - x0[..., 0], xy[..., 1] - x0[..., 1], h0)
    rel = ego_heading - h0
    pair_valid = torch.cat([valid[..., :1], valid[..., 1:] * valid[..., :-1]], dim=-1)
    speed = torch.linalg.vector_norm(_velocity(xy), dim=-1) * pair_valid
    accel = torch.cat([torch.zeros_like(speed[..., :1]), torch.diff(speed, dim=-1) / DT_S], dim=-1)
    accel = accel * torch.cat([valid[..., :1] * 0, pair_valid[..., 1:] * pair_valid[..., :-1]], dim=-1)
    n_steps = ego_xy.shape[-2]
    time = torch.arange(n_steps, dtype=ego_xy.dtype, device=ego_xy.device) / max(n_steps - 1, 1)
    feats = [(x / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP), (y / POS_SCALE_M).clamp(-POS_CLIP, POS_CLIP),
             torch.cos(rel), torch.sin(rel), speed / SPEED_SCALE_MPS,
             (accel / ACCEL_SCALE_MPS2).clamp(-POS_CLIP, POS_CLIP)]
    return torch.stack([f * valid for f in feats] + [valid, time.expand_as(valid)], dim=-1)


def _hold_last(xy: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """``xy`` with every invalid step replaced by the last valid position before it (steps before the first
    valid one take the first valid position; all-invalid rows take row 0, masked anyway)."""
    idx = torch.arange(xy.shape[-2], device=xy.device).expand(valid.shape)
    last = torch.cummax(torch.where(valid, idx, torch.full_like(idx, -1)), dim=-1).values
    first = valid.int().argmax(dim=-1, keepdim=True)
    src = torch.where(last < 0, first.expand_as(last), last)
    return torch.gather(xy, -2, src[..., None].expand(*src.shape, 2))


def align_ego_rollouts(
    ego_xy: np.ndarray, ego_heading: np.ndarray, ego_valid: np.ndarray, n_steps: int = N_FUTURE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut ego arrays indexed by scenario step (e.g. ``seal.adversaries.candidate_generator.stack_ego_rollouts``:
    ``[K, T_s, ...]``) to the candidates' steps ``CURRENT_STEP + 1 .. CURRENT_STEP + n_steps``, padding missing
    steps as invalid.

    Returns ``xy [K, n_steps, 2]``, ``heading [K, n_steps]``, ``valid [K, n_steps]``.
    """
    ego_xy, ego_heading = np.asarray(ego_xy, np.float64), np.asarray(ego_heading, np.float64)
    ego_valid = np.asarray(ego_valid, bool)
    k, t_s = ego_valid.shape
    lo = CURRENT_STEP + 1
    hi = min(t_s, lo + n_steps)
    xy = np.zeros((k, n_steps, 2))
    heading = np.zeros((k, n_steps))
    valid = np.zeros((k, n_steps), dtype=bool)
    if hi > lo:
        xy[:, : hi - lo], heading[:, : hi - lo], valid[:, : hi - lo] = ego_xy[:, lo:hi], ego_heading[:, lo:hi], \
            ego_valid[:, lo:hi]
    return xy, heading, valid
