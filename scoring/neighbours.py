"""Fixed-radius neighbour search between two point sets with a uniform grid (numpy only, no Python loops).

Used for path conflicts (points of two agents' paths within 1 m at any two steps): comparing all steps of all
pairs is ``P x T x T`` work, while the grid only visits points in neighbouring cells.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def close_pairs(
    a: np.ndarray, b: np.ndarray, radius: float, allowed: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(ia, ib)`` of all point pairs with ``|a[ia] - b[ib]| <= radius``; ``a [Na, 2]``, ``b [Nb, 2]``.

    ``allowed(ia, ib) -> bool mask`` drops candidate pairs before the exact distance test (cheaper when most
    neighbours are of no interest, e.g. points of the same agent).
    """
    empty = (np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if a.shape[0] == 0 or b.shape[0] == 0:
        return empty
    lo = np.minimum(a.min(0), b.min(0))
    ca = np.floor((a - lo) / radius).astype(np.int64)
    cb = np.floor((b - lo) / radius).astype(np.int64)
    ny = int(max(ca[:, 1].max(), cb[:, 1].max())) + 3
    key_b = (cb[:, 0] + 1) * ny + (cb[:, 1] + 1)  # +1 keeps neighbour keys of cell 0 non-negative and distinct
    order = np.argsort(key_b, kind="stable")
    # Occupied cells of b with the start and size of their run in ``order``: one binary search per query.
    sorted_b = key_b[order]
    cell_start = np.concatenate([[0], np.flatnonzero(np.diff(sorted_b)) + 1])
    cells = sorted_b[cell_start]
    cell_count = np.diff(np.concatenate([cell_start, [sorted_b.size]]))
    key_a = (ca[:, 0] + 1) * ny + (ca[:, 1] + 1)
    offsets = np.array([dx * ny + dy for dx in (-1, 0, 1) for dy in (-1, 0, 1)])
    queries = (key_a[:, None] + offsets[None, :]).ravel()  # [Na * 9]
    pos = np.minimum(np.searchsorted(cells, queries), cells.size - 1)
    hit = cells[pos] == queries
    start = np.where(hit, cell_start[pos], 0)
    count = np.where(hit, cell_count[pos], 0)
    total = int(count.sum())
    if total == 0:
        return empty
    ia = np.repeat(np.repeat(np.arange(a.shape[0]), 9), count)
    run_start = np.repeat(start, count)
    within = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
    ib = order[run_start + within]
    if allowed is not None:
        keep = allowed(ia, ib)
        ia, ib = ia[keep], ib[keep]
    ax, ay = np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1])  # 1-D gathers are the fast kind
    bx, by = np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1])
    dx, dy = ax[ia] - bx[ib], ay[ia] - by[ib]
    d2 = dx * dx + dy * dy
    keep = d2 <= radius * radius
    return ia[keep], ib[keep]
