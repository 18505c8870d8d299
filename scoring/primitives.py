"""Clustered motion primitives and the trajectory (pair) anomaly features (SafeShift, after [51] in the thesis).

A *primitive* is a 2 s window of motion (21 steps; 5 windows spread evenly over the 91 steps, starting at steps
0, 18, 35, 52, 70, so that they cover the whole scenario with little overlap) in the frame of the agent at the
window start (translated to its position, rotated by its heading), sampled every 4 steps (0.4 s): 5 points = 10
numbers (m). A *pair primitive* adds the other agent's 6 positions (start included) in the same frame: 22
numbers. Only windows where the agent(s) are valid throughout count, and pair windows only when the two start
within 50 m.

`fit_primitives` z-scores each dimension and runs k-means (k-means++, seeded) on a dataset's logged windows. The
anomaly of a window is its RMS distance (z units per dimension, the distance divided by sqrt(dim), as in the
SafeShift code) to the nearest cluster centre; an agent's anomaly is the mean over its windows (0 without a full
window) and a pair's is the larger of the two orderings' means.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

WINDOW_STEPS = 20
SAMPLE_EVERY = 4
PAIR_MAX_DIST_M = 50.0
_OFFSETS = np.arange(SAMPLE_EVERY, WINDOW_STEPS + 1, SAMPLE_EVERY)  # 4, 8, ..., 20
_PAIR_OFFSETS = np.arange(0, WINDOW_STEPS + 1, SAMPLE_EVERY)  # 0, 4, ..., 20


@dataclass(frozen=True)
class Primitives:
    """Fitted primitives: z-score statistics and k-means centres (z units) for single and pair windows."""

    single_mean: np.ndarray
    single_std: np.ndarray
    single_centres: np.ndarray
    pair_mean: np.ndarray
    pair_std: np.ndarray
    pair_centres: np.ndarray

    def to_arrays(self, prefix: str = "prim_") -> dict[str, np.ndarray]:
        return {prefix + k: np.asarray(getattr(self, k)) for k in self.__dataclass_fields__}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], prefix: str = "prim_") -> Primitives:
        return cls(**{k: np.asarray(arrays[prefix + k], dtype=np.float64) for k in cls.__dataclass_fields__})


@functools.lru_cache(maxsize=8)
def window_starts(n_steps: int) -> np.ndarray:
    """Start steps of the windows: as few as cover all ``n_steps`` steps, spread evenly (do not modify)."""
    last = n_steps - 1 - WINDOW_STEPS
    if last < 0:
        return np.zeros(0, dtype=np.int64)
    n = int(np.ceil((n_steps - 1) / WINDOW_STEPS))
    return np.unique(np.round(np.linspace(0, last, n)).astype(np.int64))


def _window_ok(valid: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """``[..., W]`` True where ``valid [..., T]`` holds on every step of the window."""
    c = np.concatenate([np.zeros(valid.shape[:-1] + (1,)), np.cumsum(valid, axis=-1)], axis=-1)
    return (c[..., starts + WINDOW_STEPS + 1] - c[..., starts]) == WINDOW_STEPS + 1


@dataclass(frozen=True)
class AgentWindows:
    """Every agent's windows of one track set, computed once and shared by the single and pair features.

    Attributes (``A`` agents, ``W`` windows): ``origin [A, W, 2]`` and ``cos`` / ``sin [A, W]`` of each window's
    frame, ``own [A, W, 10]`` the agent's single-window features, ``pts [A, W, 6, 2]`` its positions at the pair
    sample steps (world frame), ``ok [A, W]`` valid over the whole window.
    """

    origin: np.ndarray
    cos: np.ndarray
    sin: np.ndarray
    own: np.ndarray
    pts: np.ndarray
    ok: np.ndarray


def agent_windows(pos: np.ndarray, heading: np.ndarray, valid: np.ndarray) -> AgentWindows:
    """`AgentWindows` of positions ``[A, T, 2]`` (m), headings ``[A, T]`` (rad) and validity ``[A, T]``."""
    starts = window_starts(valid.shape[1])
    origin = pos[:, starts]
    c, s = np.cos(heading[:, starts]), np.sin(heading[:, starts])
    own = _rotate(pos[:, starts[:, None] + _OFFSETS[None, :]] - origin[:, :, None, :], c, s)
    return AgentWindows(
        origin=origin, cos=c, sin=s, own=own.reshape(*own.shape[:2], -1),
        pts=pos[:, starts[:, None] + _PAIR_OFFSETS[None, :]], ok=_window_ok(valid, starts),
    )


def _rotate(rel: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Vectors ``[..., K, 2]`` rotated by minus the angle with cosine / sine ``c``, ``s [...]``."""
    c, s = c[..., None], s[..., None]
    return np.stack([c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]], axis=-1)


def pair_features(wf: AgentWindows, f: np.ndarray, wo: AgentWindows, o: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pair features ``[P, W, 22]`` (m) of agents ``o`` (windows ``wo``) seen from agents ``f`` (windows ``wf``)
    and the ok mask ``[P, W]`` (both valid over the window, within 50 m at its start)."""
    origin = wf.origin[f]
    rel = wo.pts[o] - origin[:, :, None, :]
    other = _rotate(rel, wf.cos[f], wf.sin[f])
    feats = np.concatenate([wf.own[f], other.reshape(*other.shape[:2], -1)], axis=-1)
    close = np.hypot(rel[:, :, 0, 0], rel[:, :, 0, 1]) < PAIR_MAX_DIST_M  # sample 0 is the window start
    return feats, wf.ok[f] & wo.ok[o] & close


def _nearest_rms(z: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """RMS distance (per dimension) from rows of ``z [N, D]`` to the nearest centre ``[K, D]``."""
    # einsum instead of a matrix product: small products through multi-threaded BLAS are slow on busy machines.
    d2 = (z**2).sum(1)[:, None] - 2.0 * np.einsum("nd,kd->nk", z, centres) + (centres**2).sum(1)[None, :]
    return np.sqrt(np.maximum(d2.min(1), 0.0) / z.shape[1])


def _mean_over_windows(dist: np.ndarray, ok: np.ndarray) -> np.ndarray:
    n = ok.sum(-1)
    return np.where(n > 0, np.where(ok, dist, 0.0).sum(-1) / np.maximum(n, 1), 0.0)


def single_anomaly(prim: Primitives | None, w: AgentWindows) -> np.ndarray:
    """``[A]`` trajectory anomaly of every agent (0 when ``prim`` is None or the agent has no full window)."""
    if prim is None:
        return np.zeros(w.ok.shape[0])
    dist = np.zeros(w.ok.shape)
    if w.ok.any():
        dist[w.ok] = _nearest_rms((w.own[w.ok] - prim.single_mean) / prim.single_std, prim.single_centres)
    return _mean_over_windows(dist, w.ok)


def pair_anomaly(
    prim: Primitives | None, wa: AgentWindows, i: np.ndarray, wb: AgentWindows, j: np.ndarray
) -> np.ndarray:
    """``[P]`` anomaly of pairs (agent ``i[p]`` of set a, ``j[p]`` of set b): the larger of the i-frame and
    j-frame means over the windows."""
    if prim is None or i.size == 0:
        return np.zeros(i.size)
    out = []
    for wf, f, wo, o in ((wa, i, wb, j), (wb, j, wa, i)):
        feats, ok = pair_features(wf, f, wo, o)
        dist = np.zeros(ok.shape)
        if ok.any():
            dist[ok] = _nearest_rms((feats[ok] - prim.pair_mean) / prim.pair_std, prim.pair_centres)
        out.append(_mean_over_windows(dist, ok))
    return np.maximum(out[0], out[1])


# ------------------------------------------------------------------------------------------------- fitting
def kmeans(x: np.ndarray, k: int, seed: int = 0, iters: int = 25) -> np.ndarray:
    """Centres ``[k, D]`` of k-means (Lloyd, k-means++ initialisation) on ``x [N, D]``; deterministic per seed."""
    rng = np.random.default_rng(seed)
    n = x.shape[0]
    k = min(k, n)
    sq = (x**2).sum(1)
    centres = [x[rng.integers(n)]]
    d2 = np.maximum(sq - 2 * x @ centres[0] + centres[0] @ centres[0], 0.0)
    for _ in range(1, k):
        total = d2.sum()
        nxt = x[rng.choice(n, p=d2 / total)] if total > 0 else x[rng.integers(n)]
        centres.append(nxt)
        d2 = np.minimum(d2, np.maximum(sq - 2 * x @ nxt + nxt @ nxt, 0.0))
    c = np.array(centres)
    for _ in range(iters):
        label = np.argmin(sq[:, None] - 2 * x @ c.T + (c**2).sum(1)[None, :], axis=1)
        counts = np.bincount(label, minlength=k)
        sums = np.stack([np.bincount(label, weights=x[:, d], minlength=k) for d in range(x.shape[1])], axis=1)
        new = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], c)
        if np.allclose(new, c):
            break
        c = new
    return c


def fit_primitives(
    tracks: list[tuple[np.ndarray, np.ndarray, np.ndarray]], k: int = 32, seed: int = 0, max_windows: int = 20_000
) -> Primitives:
    """Fit primitives on logged tracks: a list of ``(pos [A, T, 2], heading [A, T], valid [A, T])`` per scenario.

    Pair windows use every ordered pair; at most ``max_windows`` windows of each kind (a seeded random subset)
    enter the z-score statistics and k-means.
    """
    rng = np.random.default_rng(seed)
    # Cap each scenario's share so that a few crowded scenes cannot dominate (and memory stays small).
    per_scene = max(64, 2 * max_windows // max(len(tracks), 1))
    singles, pairs = [], []
    for pos, heading, valid in tracks:
        w = agent_windows(pos, heading, valid)
        singles.append(_subsample(w.own[w.ok], per_scene, rng))
        ii, jj = np.nonzero(~np.eye(pos.shape[0], dtype=bool))
        pf, pok = pair_features(w, ii, w, jj)
        pairs.append(_subsample(pf[pok], per_scene, rng))
    return Primitives(*_fit_one(singles, k, rng, seed, max_windows), *_fit_one(pairs, k, rng, seed, max_windows))


def _subsample(x: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return x if x.shape[0] <= n else x[rng.choice(x.shape[0], n, replace=False)]


def _fit_one(chunks: list[np.ndarray], k: int, rng: np.random.Generator, seed: int, max_windows: int):
    x = np.concatenate(chunks) if chunks else np.zeros((0, 1))
    if x.shape[0] == 0:
        raise ValueError("cannot fit motion primitives: no agent is valid over a full 2 s window")
    if x.shape[0] > max_windows:
        x = x[rng.choice(x.shape[0], max_windows, replace=False)]
    mean = x.mean(0)
    std = np.maximum(x.std(0), 1e-3)  # dimensions that never vary (none in practice) must not blow up
    z = (x - mean) / std
    return mean, std, kmeans(z, k, seed=seed)
