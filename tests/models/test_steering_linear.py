"""Probes and steering directions on a synthetic latent space with a known direction: the probes find it, the
risk and control vectors point along it, random labels give nothing, SAE vectors agree with plain PCA."""

from __future__ import annotations

import numpy as np
import pytest

from seal.models.steering.linear import (
    pca_control_vector,
    r2_score,
    random_direction,
    ridge_probe,
    scene_split,
    softmax_probe,
    whitened_mean_difference,
)
from seal.models.steering.sae import SAEConfig, fit_sae, sae_control_vector

D = 16


def _latents(n: int = 2000, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Latents ``[n, D]`` = score * u + anisotropic noise (a loud nuisance axis), the score, u and scene ids."""
    rng = np.random.default_rng(seed)
    u = np.zeros(D)
    u[[2, 5]] = [0.6, 0.8]
    score = rng.normal(size=n)
    noise = rng.normal(size=(n, D)) * np.where(np.arange(D) == 0, 5.0, 0.5)
    return score[:, None] * u + noise, score, u, np.repeat(np.arange(n // 10), 10)


def test_scene_split_holds_out_whole_scenes() -> None:
    groups = np.repeat(np.arange(20), 3)
    train, test = scene_split(groups, 0.25, seed=1)
    assert test.sum() == 15 and not set(groups[train]) & set(groups[test])
    assert (train ^ test).all()


def test_ridge_probe_recovers_the_score_and_its_direction() -> None:
    z, score, u, groups = _latents()
    train, test = scene_split(groups, 0.25, seed=0)
    probe = ridge_probe(z, score, train, test, groups=groups)
    # The noise along u has std 0.5 against a unit score: R^2 = 1 / (1 + 0.25) at best.
    assert probe.r2_test == pytest.approx(0.8, abs=0.05)
    assert abs(probe.direction @ u) > 0.95
    shuffled = np.random.default_rng(3).permutation(score)
    assert ridge_probe(z, shuffled, train, test, groups=groups).r2_test < 0.02


def test_whitened_mean_difference_points_along_the_risk_direction_not_the_loud_axis() -> None:
    z, score, u, _ = _latents()
    w = whitened_mean_difference(z, score)
    assert np.linalg.norm(w) == pytest.approx(1.0)
    assert w @ u > 0.95  # sign: +alpha raises the score
    assert abs(w[0]) < 0.1
    w_neg = whitened_mean_difference(z, -score)
    assert w_neg @ u < -0.95


def test_control_vector_is_the_class_axis_with_the_class_gap() -> None:
    rng = np.random.default_rng(0)
    gap = np.zeros(D)
    gap[3] = 4.0
    pos = rng.normal(size=(800, D)) + gap / 2
    neg = rng.normal(size=(600, D)) - gap / 2
    v, unit = pca_control_vector(pos, neg, seed=0)
    assert v[3] > 0.97 and unit == pytest.approx(4.0, abs=0.2)
    with pytest.raises(ValueError, match="both classes"):
        pca_control_vector(pos, neg[:0])


def test_softmax_probe_separates_classes_along_the_direction_and_reports_the_majority() -> None:
    z, score, _, groups = _latents()
    labels = np.digitize(score, [-0.5, 0.5])  # 3 classes by the score
    train, test = scene_split(groups, 0.25, seed=0)
    p = softmax_probe(z, labels, 3, train, test)
    assert p.accuracy_test > 0.7 > p.majority_test
    assert sum(p.class_counts) == len(z)
    noise = np.random.default_rng(1).integers(0, 3, size=len(z))
    assert softmax_probe(z, noise, 3, train, test).accuracy_test < 0.45


def test_random_direction_is_unit_and_seeded() -> None:
    a = random_direction(D, np.random.default_rng(5))
    assert np.linalg.norm(a) == pytest.approx(1.0)
    np.testing.assert_array_equal(a, random_direction(D, np.random.default_rng(5)))


def test_r2_score_values() -> None:
    y = np.array([1.0, 2.0, 3.0])
    assert r2_score(y, y) == 1.0 and r2_score(y, np.full(3, 2.0)) == 0.0
    assert np.isnan(r2_score(np.ones(3), y))


def test_sae_reconstructs_sparsely_and_refines_to_the_same_axis() -> None:
    rng = np.random.default_rng(0)
    gap = np.zeros(D)
    gap[7] = 3.0
    pos = rng.normal(size=(500, D)) * 0.7 + gap / 2
    neg = rng.normal(size=(500, D)) * 0.7 - gap / 2
    z = np.concatenate([pos, neg])
    sae, stats = fit_sae(z, SAEConfig(width=32, epochs=60, l1=1e-2, seed=0))
    assert stats.explained_variance > 0.8 and 0 < stats.l0 < 32
    v, unit = sae_control_vector(sae, pos, neg, seed=0)
    assert np.linalg.norm(v) == pytest.approx(1.0) and v[7] > 0.9 and unit > 2.0
