"""The probability of improvement of one pipeline's egos over another's (`seal.experiments.report.stats`): the
count of seed pairs by hand, the vectorised estimator equal to rliable's inside the same bootstrap, whole egos
resampled across settings, the permutation test against a count of splits, and the verdict that needs both, checked
for its error rate on pipelines without a difference."""

from __future__ import annotations

import numpy as np
import pytest

from seal.experiments.report.stats import pairwise_improvement, poi_interval, poi_permutation_p, poi_verdict


def test_probability_of_improvement_counts_pairs_and_half_ties() -> None:
    # pairs: (0.6>0.4) 1, (0.6=0.6) 0.5, (0.8>0.4) 1, (0.8>0.6) 1 -> 3.5 / 4
    p, lo, hi = poi_interval([np.array([0.6, 0.8])], [np.array([0.4, 0.6])], n_boot=200)
    assert p == pytest.approx(0.875) and lo <= p <= hi
    p, lo, hi = poi_interval([np.array([0.9, 0.8])], [np.array([0.1, 0.2])], n_boot=200)
    assert (p, lo, hi) == (1.0, 1.0, 1.0)
    p, _, _ = poi_interval([np.array([0.6, 0.8]), np.array([0.1, 0.1])], [np.array([0.4, 0.6]), np.array([0.3, 0.3])],
                           n_boot=100)
    assert p == pytest.approx((0.875 + 0.0) / 2)


def test_pairwise_improvement_equals_rliable_and_leaves_the_interval_unchanged() -> None:
    from arch.bootstrap import IndependentSamplesBootstrap
    from rliable import metrics

    rng = np.random.default_rng(5)
    for runs_x, runs_y, tasks in ((4, 4, 10), (8, 4, 3), (3, 5, 1)):
        # rates of 300 scenarios: coarse values, so ties within and across the two sides are common
        x, y = rng.integers(140, 160, (runs_x, tasks)) / 300, rng.integers(140, 160, (runs_y, tasks)) / 300
        assert pairwise_improvement(x, y) == pytest.approx(metrics.probability_of_improvement(x, y), abs=1e-12)
        assert pairwise_improvement(x, x) == 0.5
        p, lo, hi = poi_interval(list(x.T), list(y.T), n_boot=300, seed=2)
        reference = IndependentSamplesBootstrap(x, y, seed=np.random.default_rng(2)).conf_int(
            lambda a, b: np.array([metrics.probability_of_improvement(a, b)]), reps=300, method="percentile",
            size=0.95).ravel()
        assert (lo, hi) == pytest.approx(tuple(reference), abs=1e-12)


def test_permutation_p_counts_the_splits_at_least_as_extreme() -> None:
    # 2 + 2 egos, one setting, fully separated: of the C(4, 2) = 6 splits only the observed one and its mirror give
    # |P - 0.5| = 0.5
    assert poi_permutation_p([np.array([0.8, 0.9])], [np.array([0.1, 0.2])]) == pytest.approx(2 / 6)
    # 4 + 4 egos separated in every setting: 2 of 70 splits
    x, y = [np.array([0.6, 0.7, 0.8, 0.9])] * 3, [np.array([0.1, 0.2, 0.3, 0.4])] * 3
    assert poi_permutation_p(x, y) == pytest.approx(2 / 70)
    assert poi_permutation_p(x, x) == 1.0  # P = 0.5 exactly: every split is at least as extreme
    # more splits than n_perm: random splits, (hits + 1) / (n + 1), reproducible with the seed
    big_x, big_y = [np.linspace(0.5, 0.9, 9)], [np.linspace(0.1, 0.5, 9)]
    p = poi_permutation_p(big_x, big_y, n_perm=500, seed=1)
    assert p == poi_permutation_p(big_x, big_y, n_perm=500, seed=1) and 1 / 501 <= p < 0.01


def test_poi_verdict_needs_the_interval_and_the_permutation_test() -> None:
    row = {"seeds": 4, "reference_seeds": 4, "p_improvement": 0.8, "ci_low": 0.6, "ci_high": 0.95, "p_perm": 0.03}
    assert poi_verdict(row) == "holds"
    assert poi_verdict({**row, "p_perm": 0.11}) == "not shown"  # interval above 0.5, permutation test not
    assert poi_verdict({**row, "ci_low": 0.45}) == "not shown"
    assert poi_verdict({**row, "p_improvement": 0.2, "ci_low": 0.05, "ci_high": 0.4}) == "reversed"
    assert poi_verdict({**row, "reference_seeds": 2}) == "not shown"


def test_poi_verdict_is_calibrated_on_pipelines_without_a_difference() -> None:
    # 4 + 4 seeds drawn from one distribution of per-seed rates in 10 settings (a seed offset shared by its
    # settings, as one ego plays them all): the verdict may call at most ~5 % of them either way
    rng = np.random.default_rng(0)
    verdicts, bootstrap_only = [], []
    for i in range(300):
        rates = 0.5 + rng.normal(0, 0.04, (8, 1)) + rng.normal(0, 0.02, (8, 10))
        x, y = list(rates[:4].T), list(rates[4:].T)
        p, lo, hi = poi_interval(x, y, n_boot=200, seed=i)
        row = {"seeds": 4, "reference_seeds": 4, "p_improvement": p, "ci_low": lo, "ci_high": hi,
               "p_perm": poi_permutation_p(x, y)}
        verdicts.append(poi_verdict(row) != "not shown")
        bootstrap_only.append(lo > 0.5 or hi < 0.5)
    assert np.mean(verdicts) <= 0.05
    assert np.mean(bootstrap_only) > np.mean(verdicts)


def test_probability_of_improvement_resamples_whole_egos_across_settings() -> None:
    # One ego plays every setting: No-Adv's seed 0 is weak everywhere, the rest tie with CAT. Ten identical settings
    # carry no more evidence than one, so the interval over ten must be the one-setting interval; redrawing the seeds
    # per setting (10 "independent" seeds) would narrow it above 0.5. P = (4 wins + 12 half ties) / 16.
    cat, noadv = np.array([0.6, 0.6, 0.6, 0.6]), np.array([0.5, 0.6, 0.6, 0.6])
    one = poi_interval([cat], [noadv], n_boot=500, seed=3)
    ten = poi_interval([cat] * 10, [noadv] * 10, n_boot=500, seed=3)
    assert one[0] == pytest.approx(0.625) and ten == pytest.approx(one)
    # a resample without the weak seed ((3/4)^4 = 32 % of them) gives exactly 0.5
    assert ten[1] == pytest.approx(0.5)
