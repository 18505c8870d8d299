"""NURBS evaluation against analytic curves, and the least-squares fit GOOSE starts from."""

from __future__ import annotations

import math

import numpy as np
import pytest

from seal.adversaries.goose.nurbs import (
    NurbsCurve,
    basis_functions,
    chord_length_params,
    clamped_uniform_knots,
    distance_to_curve,
    fit_nurbs,
    nurbs_derivatives,
    nurbs_points,
)

U = np.linspace(0.0, 1.0, 101)


def test_knot_vector_and_basis_values_at_the_interior_knot() -> None:
    knots = clamped_uniform_knots(5, 3)
    np.testing.assert_array_equal(knots, [0, 0, 0, 0, 0.5, 1, 1, 1, 1])
    # Cox-de Boor by hand at u = 0.5: N = (0, 1/4, 1/2, 1/4, 0).
    np.testing.assert_allclose(basis_functions(np.array([0.5]), knots)[0], [0, 0.25, 0.5, 0.25, 0], atol=1e-12)
    n = basis_functions(U, knots)
    np.testing.assert_allclose(n.sum(axis=1), 1.0, atol=1e-12)  # partition of unity
    assert n.min() >= 0.0
    np.testing.assert_allclose(n[0], [1, 0, 0, 0, 0])
    np.testing.assert_allclose(n[-1], [0, 0, 0, 0, 1])
    with pytest.raises(ValueError, match="n_ctrl >= degree"):
        clamped_uniform_knots(3, 3)


def test_end_points_are_interpolated_whatever_the_weights() -> None:
    rng = np.random.default_rng(0)
    ctrl = rng.normal(size=(5, 2)) * 10
    w = rng.uniform(0.3, 3.0, 5)
    pts = nurbs_points(ctrl, w, np.array([0.0, 1.0]))
    np.testing.assert_allclose(pts, ctrl[[0, -1]], atol=1e-12)


def test_equal_weights_give_the_bezier_curve_for_a_single_segment() -> None:
    # 4 control points, degree 3: knots [0,0,0,0,1,1,1,1], the B-spline basis is Bernstein's.
    ctrl = np.array([[0.0, 0.0], [3.0, 7.0], [8.0, -2.0], [10.0, 4.0]])
    b = np.stack([(1 - U) ** 3, 3 * U * (1 - U) ** 2, 3 * U**2 * (1 - U), U**3], axis=1)
    for w in (1.0, 2.5):
        np.testing.assert_allclose(nurbs_points(ctrl, np.full(4, w), U), b @ ctrl, atol=1e-12)


def test_rational_quadratic_is_an_exact_circular_arc() -> None:
    # Quarter circle: P = (1,0), (1,1), (0,1), weights (1, cos 45deg, 1).
    ctrl = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    pts = nurbs_points(ctrl, np.array([1.0, math.sqrt(0.5), 1.0]), U, degree=2)
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1]), 1.0, atol=1e-12)
    np.testing.assert_allclose(pts[50], [math.sqrt(0.5)] * 2, atol=1e-12)
    curve = NurbsCurve(ctrl, np.array([1.0, math.sqrt(0.5), 1.0]), degree=2)
    assert curve.length(4096) == pytest.approx(math.pi / 2, abs=1e-5)
    theta = np.array([0.2, 0.7, 1.3])
    p, heading = curve.at_arc_length(theta, 4096)  # arc length = angle on the unit circle
    np.testing.assert_allclose(p, np.stack([np.cos(theta), np.sin(theta)], axis=1), atol=1e-4)
    np.testing.assert_allclose(heading, theta + math.pi / 2, atol=1e-3)


def test_weight_scaling_invariance_and_pull_towards_a_heavier_point() -> None:
    ctrl = np.array([[0.0, 0.0], [10.0, 5.0], [20.0, -5.0], [30.0, 5.0], [40.0, 0.0]])
    w = np.array([1.0, 0.5, 2.0, 1.0, 1.5])
    np.testing.assert_allclose(nurbs_points(ctrl, 3.0 * w, U), nurbs_points(ctrl, w, U), atol=1e-12)
    heavy = w.copy()
    heavy[2] = 8.0
    u_mid = np.array([0.5])
    d_before = np.linalg.norm(nurbs_points(ctrl, w, u_mid)[0] - ctrl[2])
    d_after = np.linalg.norm(nurbs_points(ctrl, heavy, u_mid)[0] - ctrl[2])
    assert d_after < 0.5 * d_before


def test_linear_precision_at_the_greville_abscissae() -> None:
    # Control points at the Greville abscissae (0, 1/6, 1/2, 5/6, 1) of a line reproduce C(u) = u * L exactly.
    greville = np.array([0.0, 1 / 6, 0.5, 5 / 6, 1.0])
    ctrl = np.stack([greville * 60.0, greville * 30.0], axis=1)
    np.testing.assert_allclose(nurbs_points(ctrl, np.ones(5), U), np.stack([U * 60.0, U * 30.0], axis=1), atol=1e-12)


def test_derivatives_match_the_analytic_start_tangent_and_finite_differences() -> None:
    rng = np.random.default_rng(1)
    ctrl = rng.normal(size=(5, 2)) * 10
    w = rng.uniform(0.5, 2.0, 5)
    # C'(0) = p / (t_{p+1} - t_1) * w1 / w0 * (P1 - P0) = 6 w1 / w0 (P1 - P0) for knots [0,0,0,0,.5,1,1,1,1].
    d0 = nurbs_derivatives(ctrl, w, np.array([0.0]))[0]
    np.testing.assert_allclose(d0, 6.0 * w[1] / w[0] * (ctrl[1] - ctrl[0]), rtol=1e-10)
    u = np.array([0.1, 0.37, 0.5, 0.81])
    h = 1e-6
    fd = (nurbs_points(ctrl, w, u + h) - nurbs_points(ctrl, w, u - h)) / (2 * h)
    np.testing.assert_allclose(nurbs_derivatives(ctrl, w, u), fd, rtol=1e-5, atol=1e-5)


def test_batched_control_points_evaluate_like_one_curve_at_a_time() -> None:
    rng = np.random.default_rng(2)
    ctrl = rng.normal(size=(3, 5, 2))
    w = rng.uniform(0.5, 2.0, (3, 5))
    batch = nurbs_points(ctrl, w, U)
    assert batch.shape == (3, len(U), 2)
    for i in range(3):
        np.testing.assert_allclose(batch[i], nurbs_points(ctrl[i], w[i], U), atol=1e-12)


def test_fit_reproduces_a_straight_path() -> None:
    path = np.stack([np.linspace(0.0, 120.0, 81), np.linspace(0.0, 24.0, 81)], axis=1)
    curve = fit_nurbs(path)
    assert distance_to_curve(path, curve).max() < 0.3
    assert distance_to_curve(path, curve).max() < 1e-6  # a line is in the curve family: exact
    np.testing.assert_allclose(curve.ctrl[[0, -1]], path[[0, -1]])
    np.testing.assert_allclose(curve.weights, 1.0)


def test_fit_reproduces_a_circular_arc_within_tolerance() -> None:
    # Radius 50 m, 60 m of arc, 10 Hz-like spacing.
    theta = np.linspace(0.0, 60.0 / 50.0, 61)
    path = np.stack([50.0 * np.sin(theta), 50.0 * (1.0 - np.cos(theta))], axis=1)
    curve = fit_nurbs(path)
    err = distance_to_curve(path, curve)
    assert err.max() < 0.3
    assert err.max() < 0.05  # in fact far tighter
    assert curve.length() == pytest.approx(60.0, abs=0.1)
    np.testing.assert_allclose(curve.ctrl[[0, -1]], path[[0, -1]], atol=1e-12)  # ends pinned
    # Densely sampled curve points lie on the circle, not just the fitted samples.
    pts = curve.points(U)
    np.testing.assert_allclose(np.hypot(pts[:, 0], pts[:, 1] - 50.0), 50.0, atol=0.05)


def test_fit_of_degenerate_paths_and_bad_input() -> None:
    short = fit_nurbs(np.array([[0.0, 0.0], [2.0, 0.0]]))  # fewer points than control points: straight line
    np.testing.assert_allclose(short.points(U)[:, 0], 2.0 * U, atol=1e-12)
    still = fit_nurbs(np.zeros((10, 2)))  # a standing vehicle: all control points on it
    np.testing.assert_allclose(still.ctrl, 0.0)
    with pytest.raises(ValueError, match="path"):
        fit_nurbs(np.zeros((1, 2)))
    with pytest.raises(ValueError, match="positive"):
        NurbsCurve(np.zeros((5, 2)), np.array([1.0, 0.0, 1.0, 1.0, 1.0]))


def test_chord_length_params_and_distance_to_curve() -> None:
    np.testing.assert_allclose(chord_length_params(np.array([[0, 0], [1, 0], [3, 0], [4, 0]])), [0, 0.25, 0.75, 1])
    line = NurbsCurve(np.stack([np.linspace(0, 40, 5), np.zeros(5)], axis=1), np.ones(5))
    pts = np.array([[10.0, 3.0], [20.0, -1.5], [50.0, 0.0]])  # the last is 10 m beyond the end
    np.testing.assert_allclose(distance_to_curve(pts, line), [3.0, 1.5, 10.0], atol=1e-9)


def test_fit_with_a_start_direction_leaves_the_start_along_it() -> None:
    # A lane change that starts at once: the free fit's start tangent points into the turn.
    x = np.linspace(0.0, 80.0, 81)
    path = np.stack([x, 3.5 * (1.0 - np.cos(np.pi * np.clip(x / 40.0, 0.0, 1.0))) / 2.0], axis=1)
    free = fit_nurbs(path)
    d_free = nurbs_derivatives(free.ctrl, free.weights, np.array([0.0]))[0]
    assert abs(math.atan2(d_free[1], d_free[0])) > 0.01
    for direction in (np.array([1.0, 0.0]), np.array([math.cos(0.2), math.sin(0.2)])):
        fixed = fit_nurbs(path, start_direction=direction)
        d0 = nurbs_derivatives(fixed.ctrl, fixed.weights, np.array([0.0]))[0]
        assert d0 @ direction > 0 and abs(d0[0] * direction[1] - d0[1] * direction[0]) < 1e-9 * np.linalg.norm(d0)
        np.testing.assert_allclose(fixed.ctrl[[0, -1]], path[[0, -1]], atol=1e-12)
    assert distance_to_curve(path, fit_nurbs(path, start_direction=np.array([1.0, 0.0]))).max() < 0.3
    stub = fit_nurbs(np.array([[0.0, 0.0], [0.0, 2.0]]), start_direction=np.array([1.0, 0.0]))
    assert stub.ctrl[1, 1] == 0.0 and stub.ctrl[1, 0] > 0  # even a stub leaves along the direction
