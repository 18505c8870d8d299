"""Ray directions of the observation's sensors. The ray casts themselves are compiled
(`seal.envs.obs_kernels.cast_rays_into`); the numpy caster they replaced is the tests' reference
(``tests/kernel_reference.py``).

A ray ``t * d`` (t >= 0, unit d) hits a segment ``a + u * e`` (0 <= u <= 1) at ``t = (a x e) / (d x e)``,
``u = (a x d) / (d x e)`` (2-D cross products).
"""

from __future__ import annotations

import numpy as np


def ray_angles(n: int) -> np.ndarray:
    """Angles ``[n]`` (rad) of ``n`` rays spread over 360 deg, ray 0 straight ahead, counter-clockwise."""
    return 2.0 * np.pi * np.arange(n) / n
