"""Paired success gaps (`seal.experiments.report.gaps`): the scenarios drawn once for both sides."""

from __future__ import annotations

import numpy as np
import pytest

from seal.experiments.report.gaps import gap_lookup, gap_table, paired_gap
from seal.experiments.report.stats import ScoreMatrix, mean_iqm_intervals


def _matrix(success: np.ndarray, ids: list[str] | None = None) -> ScoreMatrix:
    """ScoreMatrix from ``success [scenarios, seeds]`` 0/1 (crash = not success, never out of road)."""
    s = success.astype(bool)
    values = np.stack([s, ~s, np.zeros_like(s)], axis=2).astype(np.float64)
    ids = ids or [f"s{i:03d}" for i in range(s.shape[0])]
    return ScoreMatrix(tuple(ids), tuple(f"r{k}" for k in range(s.shape[1])), values)


def test_a_shared_scenario_difficulty_cancels_in_the_gap() -> None:
    """Two pipelines on scenarios of very different difficulty (logit sd 3, shared), one 1 logit better: their
    own intervals overlap, so asking for intervals apart would miss the difference; the paired gap's interval is
    above 0 and its half-width well under the sum of the two own half-widths (the margin non-overlap asks for)."""
    rng = np.random.default_rng(0)
    difficulty = rng.normal(0.0, 3.0, 300)[:, None]
    x = _matrix(rng.random((300, 4)) < 1 / (1 + np.exp(-(difficulty + 1.0))))
    y = _matrix(rng.random((300, 4)) < 1 / (1 + np.exp(-difficulty)))
    g = paired_gap(x, y, n_boot=1000)
    own = [mean_iqm_intervals(m, n_boot=1000)["success"] for m in (x, y)]
    assert g["gap"] == pytest.approx(x.rates().mean() - y.rates().mean())
    assert g["gap_low"] > 0 and g["scenarios"] == 300
    assert own[0]["mean_low"] < own[1]["mean_high"]  # the two own intervals overlap...
    own_sum = sum(o["mean_high"] - o["mean_low"] for o in own) / 2
    assert (g["gap_high"] - g["gap_low"]) / 2 < 0.6 * own_sum


def test_gap_uses_only_the_common_scenarios_and_no_gap_without_any() -> None:
    x = _matrix(np.array([[1, 1], [1, 1], [0, 0]]), ["a", "b", "c"])
    y = _matrix(np.array([[0], [1]]), ["b", "c"])
    g = paired_gap(x, y, n_boot=200)
    assert g["scenarios"] == 2 and g["gap"] == pytest.approx(0.5 - 0.5)
    assert np.isnan(paired_gap(x, _matrix(np.array([[1]]), ["z"]))["gap"])


def test_gap_table_and_lookup_both_ways() -> None:
    rows = [{"pipeline": p, "setting": "normal", "run": f"{p}-s{k}", "scenario_id": f"s{i}",
             "success": i < wins, "crash": i >= wins, "out_of_road": False}
            for p, wins in (("cat", 8), ("noadv", 5)) for k in range(2) for i in range(10)]
    table = gap_table(rows, [("cat", "noadv", "normal"), ("cat", "seal", "normal")], n_boot=200)
    assert len(table) == 1 and table[0]["gap"] == pytest.approx(0.3)
    back = gap_lookup(table)[("noadv", "cat", "normal")]
    assert back["gap"] == pytest.approx(-0.3)
    assert (back["gap_low"], back["gap_high"]) == (-table[0]["gap_high"], -table[0]["gap_low"])
