"""Summary statistics of ``seal eval steering``: linearity of a calibration curve (paper 002) and a paired
bootstrap confidence interval (paper 000's structured-vs-random margin)."""

from __future__ import annotations

from typing import Any

import numpy as np

from seal.models.steering.linear import r2_score

LINEAR_RANGE = 0.5
"""Paper 002 measures linearity where the relative speed change lies within +-50 %."""


def straightness_index(x: np.ndarray, y: np.ndarray) -> float:
    """Benhamou's straightness ``D / L`` of the polyline through ``(x_i, y_i)``: end-to-end distance over path
    length (1 = a straight line)."""
    pts = np.stack([x, y], axis=1)
    path = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    return float(np.linalg.norm(pts[-1] - pts[0])) / path if path > 0 else float("nan")


def linearity(taus_pct: np.ndarray, change: np.ndarray, limit: float = LINEAR_RANGE) -> dict[str, Any]:
    """Linearity of relative changes ``change [n]`` (fraction) against ``taus_pct [n]`` (%), on the points with
    ``|change| <= limit``: Pearson, R^2 of the least-squares line, R^2 against the identity ``change = tau / 100``
    (paper 002's 1-to-1 calibration; depends on the unit of tau), slope (change per 100 % tau) and straightness."""
    taus = np.asarray(taus_pct, np.float64) / 100.0
    change = np.asarray(change, np.float64)
    keep = np.abs(change) <= limit
    out: dict[str, Any] = {"points": int(keep.sum()), "tau_range_pct": None}
    if keep.sum() < 3:
        return {**out, "pearson": float("nan"), "r2_fit": float("nan"), "r2_identity": float("nan"),
                "slope": float("nan"), "straightness": float("nan")}
    x, y = taus[keep], change[keep]
    pearson = float(np.corrcoef(x, y)[0, 1])
    slope, icpt = np.polyfit(x, y, 1)
    return {**out, "tau_range_pct": [float(100 * x.min()), float(100 * x.max())], "pearson": pearson,
            "r2_fit": r2_score(y, slope * x + icpt), "r2_identity": r2_score(y, x), "slope": float(slope),
            "straightness": straightness_index(x, y)}


def paired_bootstrap(a: np.ndarray, b: np.ndarray, n_boot: int = 2000, seed: int = 0,
                     level: float = 0.95) -> dict[str, float]:
    """Mean of ``a - b`` over paired rows (nan rows dropped) with a percentile bootstrap CI."""
    d = np.asarray(a, np.float64) - np.asarray(b, np.float64)
    d = d[np.isfinite(d)]
    if d.size == 0:
        return {"mean": float("nan"), "ci_low": float("nan"), "ci_high": float("nan"), "n": 0}
    rng = np.random.default_rng(seed)
    means = d[rng.integers(d.size, size=(n_boot, d.size))].mean(1)
    lo, hi = np.quantile(means, [(1 - level) / 2, 1 - (1 - level) / 2])
    return {"mean": float(d.mean()), "ci_low": float(lo), "ci_high": float(hi), "n": int(d.size)}


def calibrated_tau(taus_pct: np.ndarray, change: np.ndarray, wanted: float) -> tuple[float, bool]:
    """The tau (%) at which the calibration curve reaches relative change ``wanted`` (linear interpolation between
    the two points around it, nearest to tau = 0), and whether it is reached (else the tau of the closest point)."""
    taus, change = np.asarray(taus_pct, np.float64), np.asarray(change, np.float64)
    order = np.argsort(np.abs(taus), kind="stable")
    for i in order:
        for j in (i - 1, i + 1):
            if 0 <= j < len(taus) and (change[i] - wanted) * (change[j] - wanted) <= 0 and change[i] != change[j]:
                f = (wanted - change[i]) / (change[j] - change[i])
                return float(taus[i] + f * (taus[j] - taus[i])), True
    k = int(np.argmin(np.abs(change - wanted)))
    return float(taus[k]), False
