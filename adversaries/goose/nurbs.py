"""Planar NURBS curves (clamped, uniform knots): evaluation, derivatives, arc length and least-squares fitting.

A NURBS curve of degree ``p`` with control points ``P_i`` (m) and weights ``w_i > 0`` is

    C(u) = sum_i N_ip(u) w_i P_i / sum_i N_ip(u) w_i,      u in [0, 1],

with B-spline basis functions ``N_ip`` on a clamped uniform knot vector (``p + 1`` zeros, evenly spaced interior
knots, ``p + 1`` ones), so the curve starts at ``P_0`` and ends at ``P_{n-1}``. Equal weights give a plain
B-spline. GOOSE uses degree 3 with 5 control points (knots ``[0, 0, 0, 0, 0.5, 1, 1, 1, 1]``).

Everything is vectorised over the parameter values and over leading batch axes of the control points.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

DEGREE = 3
N_CTRL = 5


def clamped_uniform_knots(n_ctrl: int = N_CTRL, degree: int = DEGREE) -> np.ndarray:
    """Knot vector ``[n_ctrl + degree + 1]``: ``degree + 1`` zeros, uniform interior knots, ``degree + 1`` ones."""
    if degree < 1 or n_ctrl < degree + 1:
        raise ValueError(f"a clamped NURBS needs degree >= 1 and n_ctrl >= degree + 1, got {degree=}, {n_ctrl=}")
    interior = np.linspace(0.0, 1.0, n_ctrl - degree + 1)[1:-1]
    return np.concatenate([np.zeros(degree + 1), interior, np.ones(degree + 1)])


def _basis(u: np.ndarray, knots: np.ndarray, degree: int) -> np.ndarray:
    """Cox-de Boor recursion for all basis functions of degrees 0..degree; returns the degree-``degree`` ones
    ``[M, n_ctrl]`` (terms with a zero-length knot span are 0, the usual 0/0 := 0 convention)."""
    u = np.clip(np.asarray(u, dtype=np.float64).reshape(-1), knots[0], knots[-1])
    n_spans = len(knots) - 1
    # Degree 0: the half-open span [t_i, t_i+1) holding u; u = 1 belongs to the last non-empty span.
    last = int(np.flatnonzero(knots[1:] > knots[:-1])[-1])
    span = np.clip(np.searchsorted(knots, u, side="right") - 1, 0, last)
    n = (np.arange(n_spans)[None, :] == span[:, None]).astype(np.float64)
    for p in range(1, degree + 1):
        k = n_spans - p  # number of degree-p functions
        t_i, t_ip, t_i1, t_ip1 = knots[:k], knots[p : p + k], knots[1 : k + 1], knots[p + 1 : p + 1 + k]
        left_den = t_ip - t_i
        right_den = t_ip1 - t_i1
        left = np.divide(u[:, None] - t_i, left_den, out=np.zeros((len(u), k)), where=left_den > 0)
        right = np.divide(t_ip1 - u[:, None], right_den, out=np.zeros((len(u), k)), where=right_den > 0)
        n = left * n[:, :k] + right * n[:, 1 : k + 1]
    return n


def basis_functions(u: np.ndarray, knots: np.ndarray, degree: int = DEGREE) -> np.ndarray:
    """B-spline basis ``[M, n_ctrl]`` at parameters ``u [M]`` (clipped to the knot range)."""
    return _basis(u, np.asarray(knots, dtype=np.float64), degree)


def basis_derivatives(u: np.ndarray, knots: np.ndarray, degree: int = DEGREE) -> np.ndarray:
    """First derivatives ``dN_ip/du [M, n_ctrl]``:
    ``N'_ip = p / (t_i+p - t_i) N_i,p-1 - p / (t_i+p+1 - t_i+1) N_i+1,p-1``."""
    knots = np.asarray(knots, dtype=np.float64)
    low = _basis(u, knots, degree - 1)  # [M, n_ctrl + 1]
    n_ctrl = len(knots) - degree - 1
    i = np.arange(n_ctrl)
    a_den = knots[i + degree] - knots[i]
    b_den = knots[i + degree + 1] - knots[i + 1]
    a = np.divide(degree, a_den, out=np.zeros(n_ctrl), where=a_den > 0)
    b = np.divide(degree, b_den, out=np.zeros(n_ctrl), where=b_den > 0)
    return a * low[:, :n_ctrl] - b * low[:, 1 : n_ctrl + 1]


def nurbs_points(
    ctrl: np.ndarray, weights: np.ndarray, u: np.ndarray, knots: np.ndarray | None = None, degree: int = DEGREE
) -> np.ndarray:
    """Curve points ``[..., M, 2]`` for control points ``[..., n, 2]`` (m), weights ``[..., n]``, ``u [M]``."""
    ctrl = np.asarray(ctrl, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    knots = clamped_uniform_knots(ctrl.shape[-2], degree) if knots is None else np.asarray(knots, dtype=np.float64)
    nb = basis_functions(u, knots, degree)  # [M, n]
    nw = nb * w[..., None, :]  # [..., M, n]
    return (nw @ ctrl) / nw.sum(axis=-1, keepdims=True)


def nurbs_derivatives(
    ctrl: np.ndarray, weights: np.ndarray, u: np.ndarray, knots: np.ndarray | None = None, degree: int = DEGREE
) -> np.ndarray:
    """``dC/du [..., M, 2]`` (m per unit parameter), quotient rule on ``A(u) / W(u)``."""
    ctrl = np.asarray(ctrl, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    knots = clamped_uniform_knots(ctrl.shape[-2], degree) if knots is None else np.asarray(knots, dtype=np.float64)
    nb = basis_functions(u, knots, degree) * w[..., None, :]
    db = basis_derivatives(u, knots, degree) * w[..., None, :]
    big_w, d_w = nb.sum(axis=-1, keepdims=True), db.sum(axis=-1, keepdims=True)
    return ((db @ ctrl) * big_w - (nb @ ctrl) * d_w) / big_w**2


@dataclass(frozen=True)
class NurbsCurve:
    """A planar clamped NURBS curve.

    Attributes:
        ctrl: ``[n, 2]`` control points (m).
        weights: ``[n]`` positive weights.
        degree: polynomial degree.
    """

    ctrl: np.ndarray
    weights: np.ndarray
    degree: int = DEGREE

    def __post_init__(self) -> None:
        ctrl = np.asarray(self.ctrl, dtype=np.float64)
        weights = np.asarray(self.weights, dtype=np.float64).reshape(-1)
        if ctrl.ndim != 2 or ctrl.shape[1] != 2 or weights.shape != (ctrl.shape[0],):
            raise ValueError(f"NURBS needs ctrl [n, 2] and weights [n], got {ctrl.shape} and {weights.shape}")
        if not np.all(weights > 0):
            raise ValueError(f"NURBS weights must be positive, got {weights.tolist()}")
        object.__setattr__(self, "ctrl", ctrl)
        object.__setattr__(self, "weights", weights)

    @property
    def knots(self) -> np.ndarray:
        return clamped_uniform_knots(len(self.ctrl), self.degree)

    def points(self, u: np.ndarray) -> np.ndarray:
        """``[M, 2]`` points at parameters ``u [M]``."""
        return nurbs_points(self.ctrl, self.weights, u, self.knots, self.degree)

    def derivatives(self, u: np.ndarray) -> np.ndarray:
        """``[M, 2]`` first derivatives at ``u [M]``."""
        return nurbs_derivatives(self.ctrl, self.weights, u, self.knots, self.degree)

    def arc_length_table(self, n_samples: int = 512) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Dense samples: ``u [S]``, points ``[S, 2]`` and cumulative chord length ``s [S]`` (m, s[0] = 0)."""
        u, nb = _grid_basis(n_samples, len(self.ctrl), self.degree)
        nw = nb * self.weights
        pts = (nw @ self.ctrl) / nw.sum(axis=1, keepdims=True)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
        return u, pts, s

    def length(self, n_samples: int = 512) -> float:
        """Arc length (m), from a dense polyline."""
        return float(self.arc_length_table(n_samples)[2][-1])

    def at_arc_length(self, s: np.ndarray, n_samples: int = 512) -> tuple[np.ndarray, np.ndarray]:
        """Points ``[M, 2]`` and tangent headings ``[M]`` (rad) at arc lengths ``s [M]`` (m, clipped to the
        curve); the parameter is interpolated in the dense arc-length table."""
        u_tab, _, s_tab = self.arc_length_table(n_samples)
        u = np.interp(np.clip(np.asarray(s, dtype=np.float64), 0.0, s_tab[-1]), s_tab, u_tab)
        d = self.derivatives(u)
        return self.points(u), np.arctan2(d[:, 1], d[:, 0])


def chord_length_params(path: np.ndarray) -> np.ndarray:
    """Parameters ``[P]`` in [0, 1] proportional to the cumulative chord length of ``path [P, 2]``."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(np.asarray(path, dtype=np.float64), axis=0).T))])
    return s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, len(s))


@functools.lru_cache(maxsize=16)
def _grid_basis(n_samples: int, n_ctrl: int, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Uniform parameter grid ``[S]`` and its basis ``[S, n_ctrl]`` (fixed per knot vector, so cached; read-only)."""
    u = np.linspace(0.0, 1.0, n_samples)
    nb = basis_functions(u, clamped_uniform_knots(n_ctrl, degree), degree)
    u.setflags(write=False)
    nb.setflags(write=False)
    return u, nb


def closest_params(points: np.ndarray, curve: NurbsCurve, n_samples: int = 512, newton_iters: int = 2) -> np.ndarray:
    """Parameter ``[P]`` of the closest curve point for each of ``points [P, 2]``: the closest of ``n_samples``
    dense samples, then Newton steps on ``(C(u) - q) . C'(u) = 0`` (kept inside [0, 1]; a step that does not get
    closer is not taken)."""
    q = np.asarray(points, dtype=np.float64)
    u_tab, poly, _ = curve.arc_length_table(n_samples)
    d2 = ((q[:, None, :] - poly[None]) ** 2).sum(axis=-1)
    best = np.argmin(d2, axis=1)
    u, dist2 = u_tab[best], d2[np.arange(len(q)), best]
    for _ in range(newton_iters):
        d = curve.derivatives(u)
        step = ((q - curve.points(u)) * d).sum(axis=1) / np.maximum((d**2).sum(axis=1), 1e-12)
        u_new = np.clip(u + step, 0.0, 1.0)
        new2 = ((q - curve.points(u_new)) ** 2).sum(axis=1)
        better = new2 < dist2
        u, dist2 = np.where(better, u_new, u), np.where(better, new2, dist2)
    return u


def distance_to_curve(points: np.ndarray, curve: NurbsCurve) -> np.ndarray:
    """Distance ``[P]`` (m) from each point ``[P, 2]`` to the curve (at `closest_params`)."""
    q = np.asarray(points, dtype=np.float64)
    return np.hypot(*(q - curve.points(closest_params(q, curve))).T)


def _solve_interior(nb: np.ndarray, rhs: np.ndarray, start_direction: np.ndarray | None,
                    start: np.ndarray) -> np.ndarray:
    """Interior control points ``[n_ctrl - 2, 2]`` minimising ``|N[:, 1:-1] P_mid - rhs|``; with
    ``start_direction`` (unit ``[2]``) control point 1 is ``start + t d`` with ``t >= 0`` the only free value of it."""
    if start_direction is None:
        mid, *_ = np.linalg.lstsq(nb[:, 1:-1], rhs, rcond=None)
        return np.asarray(mid)
    d = np.asarray(start_direction, dtype=np.float64)
    rest = nb[:, 2:-1]
    k, n = len(nb), rest.shape[1]
    # Unknowns [t, x_2.., y_2..]; x rows then y rows of the stacked residual.
    a = np.zeros((2 * k, 1 + 2 * n))
    a[:k, 0], a[k:, 0] = nb[:, 1] * d[0], nb[:, 1] * d[1]
    a[:k, 1 : 1 + n], a[k:, 1 + n :] = rest, rest
    b = np.concatenate([rhs[:, 0] - nb[:, 1] * start[0], rhs[:, 1] - nb[:, 1] * start[1]])
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    t = max(float(sol[0]), 1e-3)  # never behind the start (a reversing tangent)
    return np.vstack([start + t * d, np.stack([sol[1 : 1 + n], sol[1 + n :]], axis=-1)])


def fit_nurbs(
    path: np.ndarray, n_ctrl: int = N_CTRL, degree: int = DEGREE, refine_iters: int = 3,
    start_direction: np.ndarray | None = None,
) -> NurbsCurve:
    """Least-squares NURBS (unit weights) through a polyline, end control points pinned to the path ends.

    Chord-length parameters, then the interior control points solve the linear least-squares problem
    ``N[:, 1:-1] P_mid = Q - N[:, 0] Q_0 - N[:, -1] Q_end``; ``refine_iters`` rounds of parameter correction
    (each path point re-parameterised to its closest curve point, then re-solved) tighten the fit.

    Args:
        path: ``[P, 2]`` points in driving order (m); at least 2.
        n_ctrl, degree: control point count and degree (GOOSE: 5, 3).
        refine_iters: parameter-correction rounds.
        start_direction: unit ``[2]``: control point 1 is kept on the ray from the start along it, so the curve
            leaves the start in that direction (``C'(0)`` is parallel to ``P1 - P0``): a vehicle's path starts
            along its current heading.
    """
    q = np.asarray(path, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 2 or len(q) < 2:
        raise ValueError(f"fit_nurbs needs a path [P >= 2, 2], got shape {q.shape}")
    knots = clamped_uniform_knots(n_ctrl, degree)
    ends = np.stack([q[0], q[-1]])
    u = chord_length_params(q)
    if u[-1] <= 0 or len(q) < n_ctrl:
        # Too short / too few points to pin the interior: control points evenly along the chord (a straight
        # line through both ends, by the linear precision of B-splines at the Greville abscissae).
        greville = np.convolve(knots[1:-1], np.ones(degree) / degree, mode="valid")
        ctrl = q[0] + greville[:, None] * (q[-1] - q[0])
        if start_direction is not None:  # keep the start tangent even on a stub
            d = np.asarray(start_direction, dtype=np.float64)
            ctrl[1] = q[0] + max(float((ctrl[1] - q[0]) @ d), 1e-3) * d
        return NurbsCurve(ctrl, np.ones(n_ctrl), degree)
    curve = None
    for _ in range(refine_iters + 1):
        nb = basis_functions(u, knots, degree)
        rhs = q - nb[:, [0, -1]] @ ends
        mid = _solve_interior(nb, rhs, start_direction, q[0])
        curve = NurbsCurve(np.vstack([ends[:1], mid, ends[1:]]), np.ones(n_ctrl), degree)
        u = closest_params(q, curve, newton_iters=1)
        u[0], u[-1] = 0.0, 1.0
    assert curve is not None
    return curve


def greville_abscissae(n_ctrl: int = N_CTRL, degree: int = DEGREE) -> np.ndarray:
    """``[n_ctrl]`` parameters where each control point "sits" (averages of ``degree`` consecutive interior knots;
    for GOOSE's knots ``[0, 1/6, 1/2, 5/6, 1]``). A B-spline whose control values are their own Greville abscissae
    is the identity ``u -> u`` (linear precision)."""
    knots = clamped_uniform_knots(n_ctrl, degree)
    return np.convolve(knots[1:-1], np.ones(degree) / degree, mode="valid")


def fit_timed_nurbs(
    path: np.ndarray, start_derivative: np.ndarray, n_ctrl: int = N_CTRL, degree: int = DEGREE,
    least_squares: bool = True,
) -> NurbsCurve:
    """Least-squares NURBS (unit weights) through positions sampled at equal time steps, with the parameter
    proportional to time: point ``k`` of ``P`` is fitted at ``u = k / (P - 1)`` (no re-parameterisation, which
    would change the timing). Control point 0 and the last are pinned to the path's ends and control point 1 is
    set by the start derivative: ``C'(0) = (P_1 - P_0) / xi_1`` (``xi`` the Greville abscissae), so a vehicle's
    curve starts with its current velocity. The remaining points solve the linear least-squares problem around
    their Greville guess (the path at ``u = xi_i``), which also keeps them in place when a short path leaves
    them under-determined.

    Args:
        path: ``[P >= 2, 2]`` positions at equal time steps (m).
        start_derivative: ``[2]`` ``dC/du`` at ``u = 0`` (m per unit parameter: velocity (m/s) x duration (s)).
        least_squares: False keeps the Greville guess (a control polygon in the path's own order, for logs whose
            least-squares fit overshoots a stop and comes back).
    """
    q = np.asarray(path, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != 2 or len(q) < 2:
        raise ValueError(f"fit_timed_nurbs needs a path [P >= 2, 2], got shape {q.shape}")
    knots = clamped_uniform_knots(n_ctrl, degree)
    xi = greville_abscissae(n_ctrl, degree)
    u = np.linspace(0.0, 1.0, len(q))
    guess = np.stack([np.interp(xi, u, q[:, 0]), np.interp(xi, u, q[:, 1])], axis=-1)
    guess[0], guess[-1] = q[0], q[-1]
    guess[1] = q[0] + xi[1] * np.asarray(start_derivative, dtype=np.float64)
    if not least_squares:
        return NurbsCurve(guess, np.ones(n_ctrl), degree)
    nb = basis_functions(u, knots, degree)
    rhs = q - nb @ guess  # residual of the guess; the free points 2 .. n-2 move by the min-norm correction
    delta, *_ = np.linalg.lstsq(nb[:, 2:-1], rhs, rcond=None)
    ctrl = guess.copy()
    ctrl[2:-1] += delta
    return NurbsCurve(ctrl, np.ones(n_ctrl), degree)
