"""Summary statistics of `seal eval steering`: linearity measures, the paired bootstrap, the calibrated tau, the
slowed-future domain shift and the displacement errors, on inputs with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from seal.experiments.steering.metrics import calibrated_tau, linearity, paired_bootstrap, straightness_index
from seal.experiments.steering.sweeps import displacement, slowed_future


def test_linearity_of_an_exact_identity_and_of_a_bent_curve() -> None:
    taus = np.arange(-100.0, 101.0, 10.0)
    exact = linearity(taus, taus / 100.0)
    # Only |change| <= 50 % counts: taus -50..50.
    assert exact["points"] == 11 and exact["tau_range_pct"] == [-50.0, 50.0]
    for key in ("pearson", "r2_fit", "r2_identity", "slope", "straightness"):
        assert exact[key] == pytest.approx(1.0)
    half = linearity(taus, taus / 200.0)
    assert half["pearson"] == pytest.approx(1.0) and half["slope"] == pytest.approx(0.5)
    assert half["r2_identity"] == pytest.approx(0.0, abs=1e-12)  # straight, but half the identity: nothing explained
    bent = linearity(taus, 0.4 * np.sin(taus / 60.0))
    assert bent["pearson"] < 1.0 and bent["straightness"] < 1.0
    assert np.isnan(linearity(taus, np.ones_like(taus))["pearson"])  # nothing within +-50 %


def test_straightness_index_of_a_detour() -> None:
    assert straightness_index(np.array([0.0, 1.0, 2.0]), np.array([0.0, 1.0, 0.0])) == pytest.approx(2 / (2 * 2**0.5))


def test_paired_bootstrap_centres_on_the_mean_difference() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(1.0, 0.1, 400)
    b = a - 0.2 + rng.normal(0, 0.05, 400)
    r = paired_bootstrap(a, b, seed=1)
    assert r["mean"] == pytest.approx(0.2, abs=0.01) and r["ci_low"] < r["mean"] < r["ci_high"]
    assert r["ci_high"] - r["ci_low"] < 0.02 and r["n"] == 400
    b[:10] = np.nan
    assert paired_bootstrap(a, b)["n"] == 390


def test_calibrated_tau_interpolates_and_says_when_the_curve_falls_short() -> None:
    taus = np.array([-100.0, -50.0, 0.0, 50.0, 100.0])
    assert calibrated_tau(taus, taus / 200.0, -0.5) == (-100.0, True)
    assert calibrated_tau(taus, taus / 100.0, -0.25) == (pytest.approx(-25.0), True)
    tau, reached = calibrated_tau(taus, taus / 1000.0, -0.5)
    assert tau == -100.0 and not reached


def test_slowed_future_halves_a_constant_speed() -> None:
    t = np.arange(1, 81)
    fut = np.stack([2.0 * t, np.zeros(80)], axis=-1)[None]  # 20 m/s
    slow = slowed_future(fut, np.zeros((1, 2)), 0.5)
    np.testing.assert_allclose(slow[0, :, 0], t.astype(float))
    np.testing.assert_allclose(slow[0, -1], fut[0, 39])


def test_displacement_takes_the_six_most_probable() -> None:
    fut = np.zeros((1, 80, 2))
    cands = np.zeros((1, 8, 80, 2))
    cands[0, :, :, 0] = np.arange(8)[:, None] + 1.0  # candidate j is j + 1 m off
    probs = np.array([[0.01, 0.2, 0.2, 0.2, 0.1, 0.1, 0.1, 0.09]])
    r = displacement(cands, probs, fut, k=6, miss_m=2.5)
    assert r["min_ade"] == pytest.approx(2.0) and r["min_fde"] == pytest.approx(2.0) and r["miss_rate"] == 0.0
    assert displacement(cands, probs, fut, k=6, miss_m=1.5)["miss_rate"] == 1.0
