"""What the behaviour encoder sees (thesis 7.3.1): one agent's *full* trajectory and the other agents' full
trajectories in that agent's frame, no map.

The frame of a target agent has its origin at the agent's position at `CURRENT_STEP` (the fixed reference step) and
+x along its heading there. Every track is sub-sampled every ``stride_steps`` steps over the whole 9.1 s scenario
(``rows = 0, stride, 2 stride, ... <= N_STEPS - 1``, ``S`` rows). Each agent token holds, per row, ``x, y`` (m,
divided by ``pos_scale_m``), ``cos, sin`` of the heading relative to the target's, ``vx, vy`` (m/s, target frame,
divided by ``vel_scale_mps``) and the valid flag, then the agent's length / 5 m, width / 2 m and an is-target flag.
The target comes first, then the ``n_agents - 1`` agents that come closest to it (smallest centre distance over the
sub-sampled rows where both exist).

`target_inputs` works on a batch of scenes ``tracks [P, A, T, 8]`` at once, so the RCG selection embeds all
``N_cand x K`` perturbed scenes of one generation in one call (`seal.adversaries.rcg.select`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, N_STEPS, VALID, VX, VY, WIDTH, X, Y

STEP_FEATURES = 7
"""Per-row features of an agent token: x, y, cos, sin, vx, vy, valid."""
STATIC_FEATURES = 3
"""Length, width, is-target."""


@dataclass(frozen=True)
class BehaviorFeatureConfig:
    """Inputs of the behaviour encoder (recorded in every saved model).

    Attributes:
        n_agents: agent tokens per target, the target included.
        stride_steps: sub-sampling of the 10 Hz tracks (5 = 0.5 s, CAT's sub-sampling).
        pos_scale_m: positions are divided by this (m).
        vel_scale_mps: velocities are divided by this (m/s).
    """

    n_agents: int = 12
    stride_steps: int = 5
    pos_scale_m: float = 20.0
    vel_scale_mps: float = 10.0

    def __post_init__(self) -> None:
        if self.n_agents < 1 or self.stride_steps < 1 or self.pos_scale_m <= 0 or self.vel_scale_mps <= 0:
            raise ValueError(f"behaviour features: n_agents, stride_steps >= 1 and scales > 0 required, got {self}")

    @property
    def rows(self) -> np.ndarray:
        """Scenario steps of the sub-sampled rows ``[S]``."""
        return np.arange(0, N_STEPS, self.stride_steps)

    @property
    def n_rows(self) -> int:
        return int(self.rows.size)

    @property
    def token_features(self) -> int:
        """Width of one agent token's input."""
        return STEP_FEATURES * self.n_rows + STATIC_FEATURES

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)


@dataclass(frozen=True)
class BehaviorInputs:
    """Encoder inputs of ``P`` targets.

    Attributes:
        agents: ``[P, n_agents, token_features]`` float32 tokens (zeros for missing agents).
        mask: ``[P, n_agents]`` bool, True = token present (column 0, the target, always).
        target_xy: ``[P, S, 2]`` float32 the target's positions in its own frame (m): the reconstruction target.
        target_valid: ``[P, S]`` bool.
    """

    agents: np.ndarray
    mask: np.ndarray
    target_xy: np.ndarray
    target_valid: np.ndarray

    def __len__(self) -> int:
        return int(self.agents.shape[0])

    @staticmethod
    def concat(parts: list[BehaviorInputs]) -> BehaviorInputs:
        """The inputs of several batches, in order."""
        return BehaviorInputs(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                                ("agents", "mask", "target_xy", "target_valid")))

    def take(self, rows: np.ndarray | slice) -> BehaviorInputs:
        return BehaviorInputs(self.agents[rows], self.mask[rows], self.target_xy[rows], self.target_valid[rows])


def _closest_agents(xy: np.ndarray, valid: np.ndarray, target: np.ndarray, n_agents: int) -> np.ndarray:
    """``[P, n_agents]`` agent rows (-1 = none), the target first, then by smallest distance to it over rows where
    both are valid. ``xy [P, A, S, 2]``, ``valid [P, A, S]``, ``target [P]``."""
    p = np.arange(xy.shape[0])
    rel = xy - xy[p, target][:, None]
    gap = np.hypot(rel[..., 0], rel[..., 1])  # [P, A, S]
    both = valid & valid[p, target][:, None]
    dist = np.where(both, gap, np.inf).min(axis=-1)  # [P, A]
    dist[p, target] = -1.0
    order = np.argsort(dist, axis=1, kind="stable")[:, :n_agents]
    order = np.where(np.isfinite(np.take_along_axis(dist, order, axis=1)), order, -1)
    if order.shape[1] < n_agents:
        order = np.pad(order, ((0, 0), (0, n_agents - order.shape[1])), constant_values=-1)
    return order


def _in_frame(sub: np.ndarray, ref: np.ndarray, cfg: BehaviorFeatureConfig
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sub-sampled tracks ``sub [..., S, 8]`` in the frame(s) ``ref [..., 8]`` (broadcast against ``sub[..., 0, :]``):
    ``(steps [..., S, 7] token features, xy [..., S, 2] (m), valid [..., S], size [..., 2] (length, width, m))``."""
    valid = sub[..., VALID] > 0.5
    cos, sin = np.cos(ref[..., HEADING])[..., None], np.sin(ref[..., HEADING])[..., None]
    dx, dy = sub[..., X] - ref[..., None, X], sub[..., Y] - ref[..., None, Y]
    xy = np.stack([cos * dx + sin * dy, -sin * dx + cos * dy], axis=-1)
    dh = sub[..., HEADING] - ref[..., None, HEADING]
    vx = cos * sub[..., VX] + sin * sub[..., VY]
    vy = -sin * sub[..., VX] + cos * sub[..., VY]
    v = valid.astype(np.float64)
    steps = np.stack([xy[..., 0] / cfg.pos_scale_m, xy[..., 1] / cfg.pos_scale_m, np.cos(dh), np.sin(dh),
                      vx / cfg.vel_scale_mps, vy / cfg.vel_scale_mps, v], axis=-1) * v[..., None]
    # Size at the agent's latest valid sub-sampled row (boxes are constant in the data; this skips invalid zeros).
    last = sub.shape[-2] - 1 - np.argmax(valid[..., ::-1], axis=-1)
    size = np.take_along_axis(sub[..., [LENGTH, WIDTH]], last[..., None, None], axis=-2)[..., 0, :]
    return steps, xy, valid, size


def _assemble(steps: np.ndarray, xy: np.ndarray, valid: np.ndarray, size: np.ndarray, target: np.ndarray,
              cfg: BehaviorFeatureConfig) -> BehaviorInputs:
    """Tokens of the closest agents from per-scene agent features (``[P, A, ...]`` as `_in_frame` gives them)."""
    p = np.arange(target.size)
    chosen = _closest_agents(xy, valid, target, cfg.n_agents)  # [P, N]
    present = chosen >= 0
    rows = np.where(present, chosen, 0)
    tok_steps = steps[p[:, None], rows].reshape(target.size, cfg.n_agents, -1)  # [P, N, S * 7]
    static = np.concatenate([size[p[:, None], rows] / np.array([5.0, 2.0]),
                             (np.arange(cfg.n_agents) == 0)[None, :, None].repeat(target.size, 0)], axis=-1)
    agents = np.concatenate([tok_steps, static], axis=-1) * present[..., None]
    return BehaviorInputs(
        agents=agents.astype(np.float32),
        mask=present,
        target_xy=(xy[p, target] * valid[p, target][..., None]).astype(np.float32),
        target_valid=valid[p, target],
    )


def _check_targets(ref: np.ndarray, target: np.ndarray) -> None:
    if (ref[..., VALID] < 0.5).any():
        raise ValueError("target_inputs: every target must be valid at the current step "
                         f"{CURRENT_STEP} (targets {np.unique(target[ref[..., VALID] < 0.5]).tolist()})")


def target_inputs(tracks: np.ndarray, target: np.ndarray, cfg: BehaviorFeatureConfig) -> BehaviorInputs:
    """Encoder inputs of agent ``target[p]`` in scene ``tracks[p]`` (see the module docstring).

    Args:
        tracks: ``[P, A, N_STEPS, 8]`` scene tracks (scenario layout, world frame); a broadcast view is fine.
        target: ``[P]`` row of the target agent in each scene; it must be valid at `CURRENT_STEP`.
        cfg: the feature settings.
    """
    tracks = np.asarray(tracks)
    target = np.asarray(target, dtype=np.int64).reshape(-1)
    if tracks.ndim != 4 or tracks.shape[2] != N_STEPS or tracks.shape[0] != target.size:
        raise ValueError(f"target_inputs: expected tracks [P, A, {N_STEPS}, 8] and target [P], got "
                         f"{tracks.shape} and {target.shape}")
    ref = tracks[np.arange(target.size), target, CURRENT_STEP].astype(np.float64)  # [P, 8]
    _check_targets(ref, target)
    sub = tracks[:, :, cfg.rows].astype(np.float64)  # [P, A, S, 8]
    return _assemble(*_in_frame(sub, ref[:, None], cfg), target, cfg)


def shared_frame_inputs(bank: np.ndarray, scenes: np.ndarray, target_col: int, cfg: BehaviorFeatureConfig
                        ) -> BehaviorInputs:
    """`target_inputs` of scenes assembled from a bank of tracks whose target has the same pose at `CURRENT_STEP`
    in every scene (RCG's perturbed scenes: every candidate continues the adversary's logged history), so every
    track is put into the frame once instead of once per scene.

    Args:
        bank: ``[R, N_STEPS, 8]`` tracks.
        scenes: ``[P, A]`` rows of ``bank`` forming each scene.
        target_col: column of the target in every scene (``bank[scenes[p, target_col]]``).
        cfg: the feature settings.
    """
    bank = np.asarray(bank, dtype=np.float64)
    scenes = np.asarray(scenes, dtype=np.int64)
    targets = scenes[:, target_col]
    ref = bank[targets, CURRENT_STEP]  # [P, 8]
    _check_targets(ref, targets)
    if not np.allclose(ref[:, [X, Y, HEADING]], ref[:1, [X, Y, HEADING]], atol=1e-6):
        raise ValueError("shared_frame_inputs: the targets' poses at the current step differ between scenes")
    steps, xy, valid, size = _in_frame(bank[:, cfg.rows], ref[0], cfg)  # [R, ...]
    target = np.full(scenes.shape[0], target_col)
    return _assemble(steps[scenes], xy[scenes], valid[scenes], size[scenes], target, cfg)


def scene_targets(tracks: np.ndarray, min_valid_rows: int, cfg: BehaviorFeatureConfig) -> np.ndarray:
    """Rows of the agents of one scene ``tracks [A, N_STEPS, 8]`` that can be targets: valid at `CURRENT_STEP` and
    on at least ``min_valid_rows`` sub-sampled rows."""
    valid = tracks[:, :, VALID] > 0.5
    enough = valid[:, cfg.rows].sum(axis=1) >= min_valid_rows
    return np.flatnonzero(valid[:, CURRENT_STEP] & enough)


def scene_inputs(tracks: np.ndarray, targets: np.ndarray, cfg: BehaviorFeatureConfig) -> BehaviorInputs:
    """`target_inputs` of several agents ``targets [P]`` of one scene ``tracks [A, N_STEPS, 8]``."""
    targets = np.asarray(targets, dtype=np.int64)
    return target_inputs(np.broadcast_to(tracks[None], (targets.size, *tracks.shape)), targets, cfg)
