"""Success differences against the No-Adv pipeline (`seal.experiments.report.differences`): the difference and
Welch's interval against a hand computation, only the scenarios both played, the all-settings row, pipelines of
another algorithm or without the reference, no spread, the first page's sentence, and the interval's calibration on
pipelines without a difference (where a bootstrap of 4 seeds is not)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from seal.experiments.report.agreement import ALL_SETTINGS
from seal.experiments.report.differences import bound_line, difference_interval, difference_markdown, difference_table


def _rows(pipeline: str, outcomes: list[list[int]], setting: str = "normal") -> list[dict]:
    """One row per (seed k, scenario i) with ``success = outcomes[k][i]``."""
    return [{"pipeline": pipeline, "setting": setting, "run": f"{pipeline}-s{k}", "scenario_id": f"s{i:03d}",
             "success": bool(v), "crash": not v, "out_of_road": False}
            for k, seed in enumerate(outcomes) for i, v in enumerate(seed)]


CAT = [[1, 1, 1, 0], [1, 1, 0, 0], [1, 1, 1, 1]]  # seed rates 0.75, 0.5, 1.0
NOADV = [[1, 0, 0, 0], [1, 1, 0, 0], [0, 0, 0, 0]]  # 0.25, 0.5, 0.0


def test_difference_and_welch_interval_by_hand() -> None:
    table = difference_table(_rows("noadv (td3)", NOADV) + _rows("cat (td3)", CAT))
    (row,) = table  # one setting: no all-settings row
    assert (row["pipeline"], row["reference"], row["setting"]) == ("cat (td3)", "noadv (td3)", "normal")
    assert row["difference"] == pytest.approx(0.75 - 0.25)
    ci = stats.ttest_ind([0.75, 0.5, 1.0], [0.25, 0.5, 0.0], equal_var=False).confidence_interval(0.95)
    assert (row["low"], row["high"]) == pytest.approx((ci.low, min(1.0, ci.high)))  # clipped to a rate difference
    assert row["seeds"] == row["reference_seeds"] == 3 and row["scenarios"] == 4
    assert "| cat (td3) | +50.0 [" in difference_markdown(table)


def test_only_the_scenarios_both_played_count() -> None:
    # cat's seeds also played a fifth scenario, failed by all; noadv never played it
    cat = [seed + [0] for seed in CAT]
    (row,) = difference_table(_rows("noadv", NOADV) + _rows("cat", cat))
    assert row["difference"] == pytest.approx(0.5) and row["scenarios"] == 4


def test_all_settings_row_averages_each_seed_over_the_settings() -> None:
    rows = (_rows("noadv", NOADV) + _rows("cat", CAT)
            + _rows("noadv", NOADV, "hard") + _rows("cat", [[0, 0, 0, 0]] * 3, "hard"))
    table = {r["setting"]: r for r in difference_table(rows)}
    assert table["hard"]["difference"] == pytest.approx(-0.25)
    pooled = table[ALL_SETTINGS]
    x = (np.array([0.75, 0.5, 1.0]) + 0) / 2
    r = np.array([0.25, 0.5, 0.0])  # the same in both settings
    ci = stats.ttest_ind(x, r, equal_var=False).confidence_interval(0.95)
    assert pooled["difference"] == pytest.approx(x.mean() - r.mean()) and pooled["scenarios"] == 8
    assert (pooled["low"], pooled["high"]) == pytest.approx((ci.low, ci.high))
    # a pipeline whose seeds are not the same egos in every setting gets no all-settings row
    other = [{**e, "run": e["run"] + "b"} for e in _rows("cat", CAT, "hard")]
    changed = _rows("noadv", NOADV) + _rows("cat", CAT) + _rows("noadv", NOADV, "hard") + other
    assert ALL_SETTINGS not in {r["setting"] for r in difference_table(changed)}


def test_other_algorithms_and_missing_reference_are_not_compared() -> None:
    assert difference_table(_rows("cat", CAT) + _rows("seal", NOADV)) == []  # no No-Adv pipeline
    rows = _rows("noadv (td3)", NOADV) + _rows("cat (reskill)", CAT) + _rows("heuristic", [[1, 1, 1, 1]])
    assert difference_table(rows) == []  # another algorithm, and a reference ego, are no pipeline to difference


def test_no_spread_gives_no_interval() -> None:
    d, low, high = difference_interval([(np.ones((4, 3)), np.ones((4, 2)))])
    assert d == 0.0 and math.isnan(low) and math.isnan(high)
    # 2 seeds a side: the t interval (1-2 degrees of freedom) is clipped to what a difference of rates can be
    _, low, high = difference_interval([(np.array([[1.0, 0.0]]), np.array([[1.0, 0.0]]))])
    assert (low, high) == (-1.0, 1.0)
    (row,) = difference_table(_rows("noadv", [[1, 1]] * 3) + _rows("cat", [[1, 1]] * 3))
    assert "+0.0 [no spread]" in difference_markdown([row])


def test_first_page_sentence_gives_the_range_and_the_pooled_rows() -> None:
    rows = (_rows("noadv (td3)", NOADV) + _rows("cat (td3)", CAT)
            + _rows("noadv (td3)", NOADV, "hard") + _rows("cat (td3)", NOADV, "hard"))
    table = difference_table(rows)
    line = bound_line(table, "td3")
    per_setting = [r for r in table if r["setting"] != ALL_SETTINGS]
    low, high = min(r["low"] for r in per_setting), max(r["high"] for r in per_setting)
    assert line is not None and f"within {100 * low:+.1f} to {100 * high:+.1f} in every setting" in line
    assert "here as few as 3 a pipeline" in line
    assert "; over all settings cat +25.0 [" in line
    assert bound_line(table, "reskill") is None


def test_welch_interval_is_calibrated_where_a_bootstrap_of_four_seeds_is_not() -> None:
    # 4 + 4 seeds from one distribution (no difference): how often does 0 fall outside the 95 % interval?
    rng = np.random.default_rng(0)
    welch, bootstrap = [], []
    for _ in range(400):
        x, r = rng.normal(0.5, 0.05, 4), rng.normal(0.5, 0.05, 4)
        _, low, high = difference_interval([(x[None, :], r[None, :])])
        welch.append(low > 0 or high < 0)
        boot = rng.choice(x, (2000, 4)).mean(1) - rng.choice(r, (2000, 4)).mean(1)
        lo, hi = np.percentile(boot, [2.5, 97.5])
        bootstrap.append(lo > 0 or hi < 0)
    assert np.mean(welch) <= 0.07 and np.mean(bootstrap) >= 0.10


def test_difference_figure_per_algorithm(tmp_path) -> None:
    from seal.experiments.report.ci_plots import plot_success_differences

    rows = (_rows("noadv (td3)", NOADV) + _rows("cat (td3)", CAT) + _rows("noadv (reskill)", NOADV)
            + _rows("cat (reskill)", [[1, 1]] * 3) + _rows("noadv (reskill)", NOADV, "hard")
            + _rows("cat (reskill)", NOADV, "hard"))
    paths = plot_success_differences(difference_table(rows), tmp_path)
    assert sorted(p.name for p in paths) == ["success_differences_reskill.png", "success_differences_td3.png"]
    assert all(p.stat().st_size > 1000 for p in paths)
    assert plot_success_differences([], tmp_path) == []
