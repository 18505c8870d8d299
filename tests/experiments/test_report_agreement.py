"""Per-scenario agreement of egos within and across pipelines (`seal.experiments.report.agreement`): the agreements
against a count by hand, the permutation test finding a pipeline that changes what its egos do and not finding one
where the pipeline changes nothing, the reference egos' agreement, the pooled row and the first page's line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from seal.experiments.report.agreement import (
    ALL_SETTINGS,
    agreement_line,
    agreement_markdown,
    agreement_table,
    within_across,
)
from seal.experiments.report.first_page import first_page_markdown


def _rows(pipeline: str, outcomes: list[list[int]], setting: str = "normal") -> list[dict]:
    """One row per (seed k, scenario i) with ``success = outcomes[k][i]``."""
    return [{"pipeline": pipeline, "setting": setting, "run": f"{pipeline}-s{k}", "scenario_id": f"s{i:03d}",
             "success": bool(v), "crash": not v, "out_of_road": False}
            for k, seed in enumerate(outcomes) for i, v in enumerate(seed)]


def test_within_and_across_against_a_count_by_hand() -> None:
    # Egos a0, a1 (pipeline a) and b0, b1 (pipeline b) on 4 scenarios.
    success = np.array([[1, 1, 0, 0], [1, 1, 1, 0], [0, 1, 1, 1], [0, 0, 1, 1]]).T
    # a0-a1 agree on 3 of 4, b0-b1 on 3 of 4; across: a0-b0 1/4, a0-b1 0/4, a1-b0 2/4, a1-b1 1/4.
    r = within_across(success, ["a", "a", "b", "b"], n_permutations=500)
    assert r["within"] == pytest.approx(0.75) and r["across"] == pytest.approx(0.25)
    assert r["difference"] == pytest.approx(0.5)
    # Of the 3 ways to split 4 egos into two pairs only the observed one reaches +0.5, so about 1/3 of the
    # relabellings do: four egos cannot make a small p.
    assert 0.25 < r["p_value"] < 0.42
    # one ego per pipeline: no pair within a pipeline, no test
    assert math.isnan(within_across(success, ["a", "b", "c", "d"])["p_value"])


def test_permutation_finds_a_pipeline_that_changes_what_its_egos_do() -> None:
    rng = np.random.default_rng(0)
    base = rng.random(60) < 0.5
    # pipeline a's egos solve `base`, b's its complement on half the scenarios; each seed flips 5 % at random
    a = [np.where(rng.random(60) < 0.05, ~base, base) for _ in range(4)]
    shifted = base.copy()
    shifted[:30] = ~shifted[:30]
    b = [np.where(rng.random(60) < 0.05, ~shifted, shifted) for _ in range(4)]
    rows = _rows("a", [list(map(int, x)) for x in a]) + _rows("b", [list(map(int, x)) for x in b])
    (row,) = [r for r in agreement_table(rows, n_permutations=400) if r["setting"] == "normal"]
    assert row["within"] > 0.85 and row["across"] < 0.6 and row["p_value"] < 0.05


def test_permutation_finds_no_trace_where_the_pipeline_changes_nothing() -> None:
    rng = np.random.default_rng(1)
    base = rng.random(80) < 0.6
    egos = [np.where(rng.random(80) < 0.1, ~base, base) for _ in range(8)]  # every ego the same up to noise
    rows = _rows("a", [list(map(int, x)) for x in egos[:4]]) + _rows("b", [list(map(int, x)) for x in egos[4:]])
    (row,) = [r for r in agreement_table(rows, n_permutations=400) if r["setting"] == "normal"]
    assert abs(row["difference"]) < 0.05 and row["p_value"] > 0.05


def test_reference_agreement_and_the_pooled_row() -> None:
    rows = _rows("cat", [[1, 1, 0, 0], [1, 0, 0, 0]]) + _rows("noadv", [[1, 1, 1, 0], [1, 1, 0, 0]])
    rows += _rows("heuristic", [[1, 1, 0, 0]])
    rows += _rows("cat", [[0, 0], [0, 1]], "hard") + _rows("noadv", [[1, 1], [0, 1]], "hard")
    table = {r["setting"]: r for r in agreement_table(rows, n_permutations=50)}
    assert set(table) == {"normal", "hard", ALL_SETTINGS}
    # heuristic vs the four trained egos on normal: 4, 3, 3 and 4 of 4 scenarios agree
    assert table["normal"]["agree_heuristic"] == pytest.approx(14 / 16)
    assert "agree_heuristic" not in table["hard"] and "agree_heuristic" not in table[ALL_SETTINGS]
    pooled = table[ALL_SETTINGS]
    assert pooled["scenarios"] == 6 and pooled["egos"] == 4
    # pooled within: cat-s0/s1 agree on 3 of 4 + 1 of 2, noadv-s0/s1 on 3 of 4 + 1 of 2 -> (4 + 4) / 12
    assert pooled["within"] == pytest.approx(8 / 12)
    md = agreement_markdown(list(table.values()))
    assert "| normal | 4 | 4 | 75.0 % |" in md and "heuristic agrees" in md


def test_first_page_says_whether_the_pipeline_leaves_a_trace() -> None:
    rows = _rows("cat", [[1, 1, 0, 0]] * 3) + _rows("noadv", [[1, 1, 0, 0]] * 3)
    pooled = [{"setting": ALL_SETTINGS, "algo": "", "scenarios": 4, "within": 1.0, "across": 1.0, "difference": 0.0,
               "p_value": 1.0, "agree_heuristic": 0.5}]
    line = agreement_line(pooled[0])
    assert "no trace of the pipeline" in line and "heuristic ego agrees with them on 50.0 %" in line
    from seal.experiments.report.stats import ego_ci_table

    page = first_page_markdown(ego_ci_table(rows, 50, 0), [], [], [], agreement=pooled)
    assert line in page
