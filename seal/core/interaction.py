"""When two vehicles interact: the "own lanes" rule shared by the scenario-window finders of the generator
(`seal.envs.windows`) and of the importers (`seal.core.importers.windows`).

Lanes are about 4 m wide and cars about 2 m wide, so every overtake on a multi-lane road passes within a couple of
metres; such closeness is not an interaction. Two vehicles keep to their own lanes when they drive parallel or
oncoming (headings within `PARALLEL_RAD` of 0 or pi) with a lateral body gap of at least `SIDE_GAP_M`.
"""

from __future__ import annotations

import numpy as np

from seal.core.geometry import wrap_angle

SIDE_GAP_M = 1.0
"""Parallel (or oncoming) vehicles whose bodies keep at least this lateral gap (m), measured across the first
vehicle's heading, are in their own lanes."""
PARALLEL_RAD = float(np.radians(20.0))
"""Largest heading difference (rad) from 0 or pi that still counts as parallel / oncoming."""


def in_own_lanes(
    xy_a: np.ndarray, heading_a: np.ndarray, width_a: np.ndarray,
    xy_b: np.ndarray, heading_b: np.ndarray, width_b: np.ndarray,
    lengths_m: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """``[...]`` bool: vehicles ``a`` and ``b`` keep to their own lanes (see the module docstring).

    Args:
        xy_a, xy_b: ``[..., 2]`` centre positions (m).
        heading_a, heading_b: ``[...]`` headings (rad).
        width_a, width_b: ``[...]`` body widths (m).
        lengths_m: body lengths ``([...], [...])`` (m) of ``a`` and ``b``; when given, the vehicles must also
            overlap along ``a``'s heading (be alongside). The importers use this: recorded freeway traffic is
            all parallel, and a neighbour ahead or behind in the next lane is where lane changes come from.
    """
    d = np.asarray(xy_b, dtype=np.float64) - np.asarray(xy_a, dtype=np.float64)
    lat = -d[..., 0] * np.sin(heading_a) + d[..., 1] * np.cos(heading_a)
    turn = np.abs(wrap_angle(np.asarray(heading_b) - np.asarray(heading_a)))
    parallel = (turn < PARALLEL_RAD) | (turn > np.pi - PARALLEL_RAD)
    own = parallel & (np.abs(lat) - 0.5 * (np.asarray(width_a) + np.asarray(width_b)) >= SIDE_GAP_M)
    if lengths_m is not None:
        lon = d[..., 0] * np.cos(heading_a) + d[..., 1] * np.sin(heading_a)
        own &= np.abs(lon) < 0.5 * (np.asarray(lengths_m[0]) + np.asarray(lengths_m[1]))
    return own
