"""Bounded controls -> positions: why the prior's candidates are drivable by construction.

The network does not regress positions. Each mode gives longitudinal acceleration and yaw rate at a few knots,
squashed into the vehicle limits with ``tanh``, linearly interpolated to every 0.1 s step and integrated from the
agent's current speed and direction of travel (a unicycle model):

    v_t = max(0, v_0 + sum_{j<=t} a_j dt),  theta_t = theta_0 + sum_{j<=t} omega_j dt,
    p_t = p_{t-1} + v_t dt (cos theta_t, sin theta_t).

So heading and speed recovered from the positions (`Candidates.from_positions`) are exactly ``theta_t`` and
``v_t``: |acceleration| <= the acceleration limit (the clamp at zero only shrinks speed changes) and |yaw rate| <=
the yaw-rate limit at every step, and trajectories are smooth (piecewise-linear controls).
"""

from __future__ import annotations

import torch

from seal.core.scenario import DT_S


def knot_matrix(n_knots: int, n_steps: int) -> torch.Tensor:
    """``[n_steps, n_knots]`` linear-interpolation weights from evenly spaced knots to every step."""
    if n_knots < 2 or n_steps < 2:
        raise ValueError(f"knot_matrix: need n_knots >= 2 and n_steps >= 2, got {n_knots}, {n_steps}")
    pos = torch.linspace(0.0, n_knots - 1.0, n_steps, dtype=torch.float64)
    lo = pos.floor().clamp(max=n_knots - 2).long()
    frac = pos - lo
    w = torch.zeros(n_steps, n_knots, dtype=torch.float64)
    w[torch.arange(n_steps), lo] = 1.0 - frac
    w[torch.arange(n_steps), lo + 1] += frac
    return w.float()


def integrate_controls(
    acc_mps2: torch.Tensor, yaw_rate_rps: torch.Tensor, speed_mps: torch.Tensor, course_rad: torch.Tensor,
    dt_s: float = DT_S,
) -> torch.Tensor:
    """Positions from per-step controls, starting at the origin.

    Args:
        acc_mps2: ``[..., T]`` longitudinal acceleration (m/s^2).
        yaw_rate_rps: ``[..., T]`` yaw rate (rad/s).
        speed_mps: ``[...]`` initial speed (m/s).
        course_rad: ``[...]`` initial direction of travel (rad, in the output frame).
        dt_s: step (s).

    Returns:
        ``[..., T, 2]`` positions (m); step ``t`` is ``(t + 1) * dt_s`` after the start.
    """
    speed = torch.relu(speed_mps[..., None] + torch.cumsum(acc_mps2 * dt_s, dim=-1))
    theta = course_rad[..., None] + torch.cumsum(yaw_rate_rps * dt_s, dim=-1)
    step = torch.stack([torch.cos(theta), torch.sin(theta)], dim=-1) * (speed * dt_s)[..., None]
    return torch.cumsum(step, dim=-2)
