"""Diffusion schedule, the few-step DDIM sampler with physics guidance (paper 004, eq. 7) and the social-force
targets (appendix A), for vehicles.

Schedule: ``N_DIFFUSION`` steps with linearly increasing beta (paper 3.1). Sampling: DDIM (eta = 0) on
``ddim_steps`` evenly spaced steps, from Gaussian noise scaled by ``temperature``. At every step the network's
clean estimate ``x0`` is moved by eq. 7, ``x0 <- x0 - sum_i w_i grad ||x0 - a_i||^2 = x0 - 2 sum_i w_i (x0 - a_i)``,
before the DDIM update; with all weights 0 the sampler is the plain DDIM sampler, bit for bit.

Targets ``a_i`` (agent frame, m/s^2; `physics_targets`):

* destination (eq. 8): ``(v0 e - v) / tau``, ``e`` the unit vector toward the destination, ``v0`` the desired
  speed (where an agent has none: its current speed; with no destination: its heading);
* social (eq. 9): ``x0 + sum_j A_soc exp(-d_ij / B_soc) n_ij`` over the other agents (the ego and the adversary
  included), ``d_ij`` the gap between the two boxes (the larger of the longitudinal and lateral clearances in
  i's frame) less what closing at the current closing speed eats of it in ``t_headway_s`` (>= 0; the
  velocity-dependent form of the social force, Helbing's elliptical specification, for vehicles), weighted by
  the field of view (agents ahead count fully, behind by ``SOCIAL_BEHIND``);
* map (eq. 10): ``x0 + A_obs exp(-d / B_obs) n`` with ``d`` the clearance between the box side and the nearest
  road-edge point, ``n`` pointing away from it;
* leader (vehicles; ``w_leader``): for an agent with a box in its path ahead (`leader_gaps`, the ego included),
  the longitudinal acceleration highway-env's IDM gives it toward its desired speed behind that box
  (`idm_acceleration`); the lateral component is left to the model. The isotropic eq. 9 term only acts within
  a few metres, too late for a vehicle closing at 10 m/s on a slow car; IDM is the car-following physics.
  Off by default: on the validation scenarios (pool2500 train split 300-339) ``w_leader`` 0.3 raised the 8 s ADE
  from 2.3 to 6.0 m and the heuristic ego's crash rate from 0.10 to 0.125 for a small drop in background
  collisions (0.040 -> 0.031).

* safety (vehicles; ``w_safety``, one-sided): the gradient of ``max(x0_lon - a_safe, 0)^2`` with ``a_safe`` the
  Gipps safe-speed bound behind the agent's nearest obstacle (`safety_bound`; in `RapidBackground` the obstacles
  of `seal.envs.car_following.safety_obstacles`: a box in the straight heading corridor only where it is on the
  agent's logged route, and of two simulated agents in each other's way (or where the slower one is only a
  predicted contact of the faster) only the slower one brakes. On 40 validation scenarios (pool2500 train split
  300-339) the route rule and the mutual priority took the 8 s ADE from 2.29 to 2.20 m and the intent speed R^2
  from 0.79 to 0.82, background collisions 0.020 -> 0.034; the priority over a mere predicted contact then
  2.20 -> 2.15 m, R^2 0.822 -> 0.826, collisions 0.037 -> 0.039 (unguided 0.3+; w_safety 0:
  2.07 m, 0.86, 0.041); loosening the bound by as much as the logged pair exceeded it changed nothing
  measurable (2.29 -> 2.28 m, 0.79) and was dropped): zero while the model's own
  acceleration leaves room to stop behind it, so it leaves ordinary driving alone and only caps closing in on a
  slower ego or a car cutting in (the learned model brakes too late for an ego slower than its log); with weight
  0.5 the step is the projection onto the bound. Unlike ``w_leader`` it never pulls an agent toward a headway.
  It is also what limits the intent test's speed R^2 (`seal.experiments.evaluation.background`: every agent gets
  an independent desired speed, so a follower told to go faster than its leader is capped): on the eval split
  0.739 with the bound, 0.811 without, with 12% and 22% of the commanded agents colliding in that roll; a
  stronger pull toward the desired speed (``tau_s`` 0.5, ``w_destination`` 0.3 / 0.4) or a looser bound (no
  predicted contacts, 0.1 s reaction, 1 m stopping gap) moved the validation R^2 by 0.01 at most. On the decisive
  pool (standard preset, first 100 eval scenarios, `Guidance` defaults) 0.747 with every agent commanded and 0.841
  with each commanded agent alone on its road; the env's IDM given the same commands as desired speeds 0.624 and
  0.998.

Deliberate difference from the paper: its social and map targets are the repulsive forces alone, which for
vehicles would pull every acceleration toward zero wherever nothing is near; here they are the model's own
estimate plus the repulsion, so the term is zero when nothing repels (the destination term is the paper's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from seal.core.errors import SealError
from seal.core.scenario import HEADING, VX, VY, WIDTH, X, Y
from seal.envs.background import idm_acceleration, leader_gaps
from seal.envs.car_following import EMERGENCY_DECEL_MPS2, safe_acceleration
from seal.models.rapid.fast import FastDenoiser
from seal.models.rapid.features import ACC_SCALE_MPS2, MapGeometry, PairScan, scan_pairs
from seal.models.rapid.network import Denoiser

N_DIFFUSION = 50
SOCIAL_BEHIND = 0.1
"""Weight of a repulsion from an agent straight behind (1 straight ahead; the social-force field of view)."""


def schedule(n: int = N_DIFFUSION) -> torch.Tensor:
    """``alpha_bar [n]`` of a linear beta schedule from 1e-4 to 0.2."""
    betas = torch.linspace(1e-4, 0.2, n)
    return torch.cumprod(1.0 - betas, dim=0)


@dataclass(frozen=True)
class Guidance:
    """Physics-guidance options of the sampler (eq. 7 weights and the social-force constants). ``tau_s`` was
    chosen among 2 s and 1 s on 12 validation scenarios (pool2500 train split 300-311, not used for fitting).
    ``w_destination`` / ``w_social`` (0.3 / 0.5; before 0.2 / 0.3) on 60 validation scenarios of the decisive pool
    (train split 300-359; the standard-preset fit reads the first 200), 8 s ADE m / background collisions / the
    heuristic ego's closed-loop crash rate / speed R^2:

    ===============  =====  =====  =====  =====
    (w_dest, w_soc)  ADE   coll.  crash  R^2
    ===============  =====  =====  =====  =====
    (0.2, 0.3)       2.41   0.031  0.050  0.734
    (0.3, 0.3)       1.83   0.053  0.067  0.763
    (0.4, 0.3)       1.83   0.071  0.033  0.772
    (0.3, 0.5)       2.08   0.037  0.033  0.761
    (0.3, 0.8)       2.40   0.027  0.017  0.749
    unguided         9.31   0.366  0.233  0.199
    ===============  =====  =====  =====  =====

    Held out (first 100 eval scenarios; closed loop on all 300), (0.2, 0.3) -> (0.3, 0.5): 8 s ADE 2.31 -> 2.08 m
    (IDM without its schedule 2.27, constant velocity 6.85), background collisions 0.046 -> 0.034 (log 0.029),
    heuristic ego crash rate 0.140 -> 0.113 (replayed background 0.110), speed R^2 0.725 -> 0.747, heading R^2 at
    24 steps 0.911 -> 0.889.

    Attributes:
        w_destination, w_social, w_map, w_leader: weights w_i of eq. 7 (0 = off).
        w_safety: weight of the one-sided safety term (`safety_bound`; 0.5, the default, projects the
            longitudinal acceleration onto the bound, 0 = off). On the validation scenarios (pool2500 train split
            300-399, closed loop) 0.5 against 0 lowered the heuristic ego's crash rate from 0.13 to 0.09 and the
            Replay ego's from 0.14 to 0.10 (replayed background: 0.09 and 0.07).
        tau_s: relaxation time of the destination term (s).
        a_social_mps2, b_social_m: strength and range of the repulsion between agents.
        a_map_mps2, b_map_m: strength and range of the repulsion from the road's edges.
        t_headway_s: the social gap is the box gap left after closing at the current closing speed for this
            long (0, the default: the paper's static distance). On the validation scenarios 0.4 s / 1 s lowered
            background collisions (0.040 -> 0.013 / 0.018) but raised the 8 s ADE (2.3 -> 3.2 / 4.4 m) and did
            not lower the heuristic ego's crashes, so it is off by default.
    """

    w_destination: float = 0.3
    w_social: float = 0.5
    w_map: float = 0.1
    w_leader: float = 0.0
    w_safety: float = 0.5
    tau_s: float = 1.0
    a_social_mps2: float = 6.0
    b_social_m: float = 2.0
    a_map_mps2: float = 3.0
    b_map_m: float = 0.5
    t_headway_s: float = 0.0

    def __post_init__(self) -> None:
        positive = ("tau_s", "b_social_m", "b_map_m")
        for name, value in vars(self).items():
            if not value >= 0.0 or (name in positive and not value > 0.0):
                raise SealError(f"RAPID guidance option {name} must be {'> 0' if name in positive else '>= 0'}, "
                                f"got {value}")


def destination_force(cur: np.ndarray, rows: np.ndarray, desired: np.ndarray, dest: np.ndarray,
                      tau_s: float) -> np.ndarray:
    """Eq. 8 ``[n, 2]`` in the map frame (m/s^2)."""
    me = cur[rows]
    vel = me[:, [VX, VY]]
    speed = np.hypot(vel[:, 0], vel[:, 1])
    v0 = np.where(np.isfinite(desired), desired, speed)
    heading = np.column_stack([np.cos(me[:, HEADING]), np.sin(me[:, HEADING])])
    to = np.nan_to_num(dest) - me[:, [X, Y]]
    dist = np.hypot(to[:, 0], to[:, 1])
    ok = np.isfinite(dest).all(axis=1) & (dist > 1.0)
    e = np.where(ok[:, None], to / np.maximum(dist, 1e-9)[:, None], heading)
    return (v0[:, None] * e - vel) / tau_s


def social_force(cur: np.ndarray, rows: np.ndarray, g: Guidance) -> np.ndarray:
    """Eq. 9 ``[n, 2]`` in the map frame (m/s^2): box-gap repulsion from every other present agent (module
    docstring), computed by the compiled `scan_pairs`."""
    return scan_pairs(cur, rows, None, social_constants(g)).social


def map_force(geo: MapGeometry, cur: np.ndarray, rows: np.ndarray, g: Guidance, edge_xy: np.ndarray | None = None
              ) -> np.ndarray:
    """Eq. 10 ``[n, 2]`` in the map frame (m/s^2): repulsion from the nearest road-edge point (``edge_xy [n, 2]``
    (m) where the caller has it: `seal.models.rapid.features.InputTables.edge_xy`, the same point)."""
    if not len(geo.edges.a):
        return np.zeros((rows.size, 2))
    xy = cur[rows][:, [X, Y]]
    q = geo.edges.nearest(xy)[0] if edge_xy is None else edge_xy
    away = xy - q
    dist = np.maximum(np.hypot(away[:, 0], away[:, 1]), 1e-6)
    clearance = np.maximum(dist - 0.5 * cur[rows, WIDTH], 0.0)
    return (g.a_map_mps2 * np.exp(-clearance / g.b_map_m) / dist)[:, None] * away


def physics_targets(geo: MapGeometry, cur: np.ndarray, rows: np.ndarray, desired: np.ndarray, dest: np.ndarray,
                    g: Guidance, logged: np.ndarray | None = None, scan: PairScan | None = None,
                    edge_xy: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per term, the agent-frame force ``[n, 2]`` / `ACC_SCALE_MPS2` (model units); the repulsive ones are added
    to the model's estimate in `ddim_sample` (module docstring); ``logged [A, 8]``: the logged boxes of the step
    (`safety_bound`); ``scan``: `scan_pairs` of ``rows`` with ``logged`` and ``g``'s social constants (computed
    here when not given): the social force and the obstacles come from it, one compiled pass; ``edge_xy``: the
    nearest road-edge points (`map_force`)."""
    if scan is None and (g.w_social or g.w_safety):
        scan = scan_pairs(cur, rows, logged, social_constants(g))
    c, s = np.cos(cur[rows, HEADING]), np.sin(cur[rows, HEADING])

    def local(f: np.ndarray) -> np.ndarray:
        return np.column_stack([c * f[:, 0] + s * f[:, 1], -s * f[:, 0] + c * f[:, 1]]) / ACC_SCALE_MPS2

    out = {}
    if g.w_destination:
        out["destination"] = local(destination_force(cur, rows, desired, dest, g.tau_s))
    if g.w_social:
        assert scan is not None
        out["social"] = local(scan.social)
    if g.w_map:
        out["map"] = local(map_force(geo, cur, rows, g, edge_xy))
    if g.w_leader:
        out["leader"] = leader_target(cur, rows, desired)
    if g.w_safety:
        assert scan is not None
        out["safety"] = safety_bound(cur, rows, scan.obstacle_gap, scan.obstacle_v)
    return out


NO_BOUND = 1e6
"""`safety_bound`'s value (model units) for an agent with no obstacle."""


def social_constants(g: Guidance) -> tuple[float, float, float, float]:
    """The eq. 9 constants `scan_pairs` takes: strength, range, headway, weight behind."""
    return (g.a_social_mps2, g.b_social_m, g.t_headway_s, SOCIAL_BEHIND)


def safety_bound(cur: np.ndarray, rows: np.ndarray, gap: np.ndarray, lead_v: np.ndarray) -> np.ndarray:
    """``[n, 1]``: the largest longitudinal acceleration (model units) each agent may take, the Gipps bound
    (`seal.envs.car_following.safe_acceleration`) behind its nearest obstacle (``gap`` (m, inf: none) and
    ``lead_v`` (m/s) of `seal.envs.car_following.obstacle_gaps`: the box ahead, a car cutting in or crossing
    first that the log did not have, the ego included), no harder than `EMERGENCY_DECEL_MPS2`; `NO_BOUND`
    without an obstacle."""
    speed = np.hypot(cur[rows, VX], cur[rows, VY])
    bound = np.maximum(safe_acceleration(speed, gap, lead_v), -EMERGENCY_DECEL_MPS2) / ACC_SCALE_MPS2
    return np.where(np.isfinite(bound), bound, NO_BOUND)[:, None]


def leader_target(cur: np.ndarray, rows: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """``[n, 2]``: column 0 the IDM longitudinal acceleration behind the box ahead (model units), column 1 1.0
    where an agent has such a box within `LEADER_RANGE_M` (else 0: no term)."""
    gap, lead_v = leader_gaps(cur, rows)
    speed = np.hypot(cur[rows, VX], cur[rows, VY])
    v0 = np.where(np.isfinite(desired), desired, speed)
    acc = idm_acceleration(speed, v0, gap, lead_v) / ACC_SCALE_MPS2
    has = np.isfinite(gap)
    return np.column_stack([np.where(has, acc, 0.0), has.astype(np.float64)])


def guide(x0: torch.Tensor, targets: dict[str, torch.Tensor], g: Guidance) -> torch.Tensor:
    """Eq. 7 on the clean estimate ``x0 [n, 2]``: destination target as is, repulsions added to ``x0``."""
    out = x0
    if "destination" in targets:
        out = out - 2.0 * g.w_destination * (x0 - targets["destination"])
    if "social" in targets:
        out = out + 2.0 * g.w_social * targets["social"]
    if "map" in targets:
        out = out + 2.0 * g.w_map * targets["map"]
    if "leader" in targets:
        lead = targets["leader"]
        lon = out[:, 0] - 2.0 * g.w_leader * lead[:, 1] * (x0[:, 0] - lead[:, 0])
        out = torch.stack([lon, out[:, 1]], dim=1)
    if "safety" in targets:
        excess = torch.clamp(out[:, 0] - targets["safety"][:, 0], min=0.0)
        out = torch.stack([out[:, 0] - 2.0 * g.w_safety * excess, out[:, 1]], dim=1)
    return out


def ddim_steps(n_steps: int, n_train: int = N_DIFFUSION) -> list[int]:
    """The descending diffusion steps a ``n_steps``-step DDIM sampler visits."""
    return sorted({int(round(k)) for k in np.linspace(n_train - 1, 0, n_steps)}, reverse=True)


@torch.no_grad()
def ddim_sample(denoise: torch.nn.Module | FastDenoiser, ctx: torch.Tensor, alpha_bar: torch.Tensor, n_steps: int,
                generator: torch.Generator, targets: dict[str, torch.Tensor], g: Guidance,
                temperature: float = 1.0) -> torch.Tensor:
    """Clean accelerations ``[n, 2]`` (model units) for contexts ``ctx [n, D]`` (module docstring); a
    `Denoiser` (or its `FastDenoiser`) multiplies the contexts once per call (`Denoiser.context_part`), any other
    module is called as ``denoise(x, k, ctx)`` at every step."""
    n = ctx.shape[0]
    x = torch.randn(n, 2, generator=generator) * temperature
    steps = ddim_steps(n_steps, len(alpha_bar))
    if isinstance(denoise, (Denoiser, FastDenoiser)):
        ctx_part = denoise.context_part(ctx)

        def predict(x: torch.Tensor, k: int) -> torch.Tensor:
            return denoise.forward_from(x, k, ctx_part)
    else:
        def predict(x: torch.Tensor, k: int) -> torch.Tensor:
            return denoise(x, torch.full((n,), k), ctx)
    for i, k in enumerate(steps):
        ab = alpha_bar[k]
        x0 = predict(x, k)
        if targets:
            x0 = guide(x0, targets, g)
        eps = (x - ab.sqrt() * x0) / (1.0 - ab).sqrt()
        ab_next = alpha_bar[steps[i + 1]] if i + 1 < len(steps) else torch.tensor(1.0)
        x = ab_next.sqrt() * x0 + (1.0 - ab_next).sqrt() * eps
    return x
