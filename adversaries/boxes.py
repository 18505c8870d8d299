"""Oriented-box overlap in centre form, broadcast over any leading axes (CAT's candidates x roll-outs x times).

`seal.core.geometry.boxes_overlap` works on corner arrays and projects all 8 corners on 4 axes; here the separating
axis test uses each box's half extents directly (``|d . u| > r_a + r_b`` on the 4 box axes, with the projection
radius ``r = l/2 |cos| + w/2 |sin|`` of a box on an axis at relative angle), which is ~30x faster on the few
thousand pairs CAT tests per scenario and allocates no ``[..., 4, 4]`` intermediates. Touching boxes count as
overlapping, as in `seal.core.geometry.boxes_overlap`.
"""

from __future__ import annotations

import numpy as np


def obb_overlap(
    x_a: np.ndarray, y_a: np.ndarray, h_a: np.ndarray, l_a: float | np.ndarray, w_a: float | np.ndarray,
    x_b: np.ndarray, y_b: np.ndarray, h_b: np.ndarray, l_b: float | np.ndarray, w_b: float | np.ndarray,
) -> np.ndarray:
    """Bool ``[...]``: do boxes a (centre x, y in m, heading rad, length, width in m) and boxes b overlap?"""
    ca, sa, cb, sb = np.cos(h_a), np.sin(h_a), np.cos(h_b), np.sin(h_b)
    dx, dy = x_b - x_a, y_b - y_a
    cos_d = np.abs(ca * cb + sa * sb)  # |cos| of the angle between the boxes
    sin_d = np.abs(ca * sb - sa * cb)
    la, wa, lb, wb = 0.5 * np.asarray(l_a), 0.5 * np.asarray(w_a), 0.5 * np.asarray(l_b), 0.5 * np.asarray(w_b)
    sep = np.abs(dx * ca + dy * sa) > la + lb * cos_d + wb * sin_d  # a's heading axis
    sep |= np.abs(dy * ca - dx * sa) > wa + lb * sin_d + wb * cos_d  # a's normal
    sep |= np.abs(dx * cb + dy * sb) > lb + la * cos_d + wa * sin_d  # b's heading axis
    sep |= np.abs(dy * cb - dx * sb) > wb + la * sin_d + wa * cos_d  # b's normal
    return ~sep
