"""Uncertainty statistics of the report: probability of improvement by hand, bootstrap intervals that contain the
point estimate and shrink with more data, references from the registry, and the tables from store-like rows."""

from __future__ import annotations

import numpy as np
import pytest

from seal.experiments.report.stats import (
    average_poi,
    bootstrap_mean_ci,
    ego_ci_table,
    improvement_table,
    probability_of_improvement,
    references,
)


def test_probability_of_improvement_counts_pairs_and_half_ties() -> None:
    assert probability_of_improvement(np.array([0.5, 0.7]), np.array([0.6])) == pytest.approx(0.5)
    # pairs: (0.6>0.4) 1, (0.6=0.6) 0.5, (0.8>0.4) 1, (0.8>0.6) 1 -> 3.5 / 4
    assert probability_of_improvement(np.array([0.6, 0.8]), np.array([0.4, 0.6])) == pytest.approx(0.875)
    point, lo, hi = average_poi([np.array([0.9, 0.8])], [np.array([0.1, 0.2])], n_boot=200)
    assert point == 1.0 and lo == 1.0 and hi == 1.0
    point, lo, hi = average_poi([np.array([0.6, 0.8]), np.array([0.1])], [np.array([0.4, 0.6]), np.array([0.3])],
                                n_boot=500)
    assert point == pytest.approx((0.875 + 0.0) / 2) and lo <= point <= hi


def test_bootstrap_interval_contains_the_mean_and_shrinks_with_more_episodes() -> None:
    rng = np.random.default_rng(0)
    small = [rng.random(10) < 0.6 for _ in range(3)]
    big = [rng.random(400) < 0.6 for _ in range(3)]
    for runs in (small, big):
        mean, lo, hi = bootstrap_mean_ci([r.astype(float) for r in runs], n_boot=500)
        assert lo <= mean <= hi
    width_small = np.subtract(*bootstrap_mean_ci([r.astype(float) for r in small], n_boot=500)[2:0:-1])
    width_big = np.subtract(*bootstrap_mean_ci([r.astype(float) for r in big], n_boot=500)[2:0:-1])
    assert width_big < width_small
    assert np.isnan(bootstrap_mean_ci([])[0])


def test_references_come_from_the_registry() -> None:
    assert references("cat-rcg") == ["cat", "noadv"]
    assert references("seal-rcg") == ["seal", "noadv"]
    assert references("cat") == ["noadv"] and references("noadv") == []


def _rows(pipeline: str, run_rates: list[float], setting: str = "normal", n: int = 10) -> list[dict]:
    rows = []
    for k, rate in enumerate(run_rates):
        wins = round(rate * n)
        rows += [{"pipeline": pipeline, "setting": setting, "run": f"{pipeline}-s{k}", "success": i < wins,
                  "crash": i >= wins, "out_of_road": False} for i in range(n)]
    return rows


def test_tables_from_rows() -> None:
    rows = _rows("cat", [0.2, 0.4]) + _rows("cat-rcg", [0.5, 0.7]) + _rows("noadv", [0.3, 0.3])
    rows += _rows("cat", [0.1, 0.1], setting="hard") + _rows("cat-rcg", [0.1, 0.3], setting="hard")
    cis = {(r["pipeline"], r["setting"], r["metric"]): r for r in ego_ci_table(rows, n_boot=300)}
    assert cis[("cat-rcg", "normal", "success")]["mean"] == pytest.approx(0.6)
    assert cis[("cat", "hard", "crash")]["mean"] == pytest.approx(0.9)
    poi = {(r["pipeline"], r["reference"]): r for r in improvement_table(rows, n_boot=300)}
    # normal: all four pairs better -> 1; hard: (0.1 = 0.1) 0.5, (0.1 = 0.1) 0.5, (0.3 > 0.1) 1, 1 -> 0.75
    assert poi[("cat-rcg", "cat")]["p_improvement"] == pytest.approx((1.0 + 0.75) / 2)
    assert poi[("cat-rcg", "cat")]["settings"] == 2
    assert poi[("cat-rcg", "noadv")]["settings"] == 1 and poi[("cat-rcg", "noadv")]["p_improvement"] == 1.0
    assert poi[("cat", "noadv")]["p_improvement"] == pytest.approx(0.5)  # 0.2 < 0.3 < 0.4
