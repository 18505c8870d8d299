"""The matched collision speed (`seal.experiments.report.generator_stats.MATCHED_SPEED`): the paired difference of
two generators' collision speeds over the episodes where the same ego in the same scenario met a contact in both,
apart from the plain difference of the two means, which also compares *which* scenarios end in a contact."""

from __future__ import annotations

import math

import pytest
from results_builders import episode

from seal.experiments.report.generator_stats import (
    MATCHED_SPEED,
    generator_ci_table,
    generator_difference_markdown,
    generator_difference_table,
)
from seal.experiments.report.thesis_claims import claims_markdown, generator_claims


def _rows(fast_only: range) -> list[dict]:
    """20 scenarios x 3 egos. CAT makes a contact in every one: 1 m/s in the slow scenes (0-9), 6 m/s in the fast
    ones; SEAL only in the scenarios of ``fast_only``, each 0.5 m/s softer than CAT's contact with the same ego."""
    rows = []
    for i in range(20):
        cat_speed = 1.0 if i < 10 else 6.0
        for k in range(3):
            rows.append(episode(run=f"r{k}", setting="cat", scenario_id=f"s{i}", collision_speed_mps=cat_speed))
            seal = cat_speed - 0.5 if i in fast_only else None
            rows.append(episode(run=f"r{k}", setting="seal", scenario_id=f"s{i}", collision_speed_mps=seal))
    return rows


def test_matched_contacts_hold_the_ego_and_scenario_fixed() -> None:
    rows = _rows(range(10, 20))
    table = generator_difference_table(rows, ["cat", "seal"], n_boot=200)
    d = next(r for r in table if (r["setting"], r["reference"]) == ("seal", "cat"))
    # plain: SEAL's contacts average 5.5 m/s, CAT's 3.5 (half of them in the slow scenes): SEAL looks 2 m/s faster
    assert d["collision_speed_mps"] == pytest.approx(2.0) and d["collision_speed_mps_low"] > 0
    # matched: every one of SEAL's 30 contacts is 0.5 m/s softer than CAT's with the same ego in the same scenario
    assert (d[MATCHED_SPEED], d[f"{MATCHED_SPEED}_low"], d[f"{MATCHED_SPEED}_high"]) == pytest.approx(
        (-0.5, -0.5, -0.5))
    assert d["matched_contacts"] == 30
    back = next(r for r in table if (r["setting"], r["reference"]) == ("cat", "seal"))
    assert back[MATCHED_SPEED] == pytest.approx(0.5) and back["matched_contacts"] == 30
    assert "| coll. speed, matched contacts (m/s): row - column | cat | seal |" in generator_difference_markdown(table)
    # the claim's verdict stays on the plain difference (the thesis's measure); the matched reading is its evidence
    gen_ci = generator_ci_table(rows, ["cat", "seal"], n_boot=200)
    (speed,) = [c for c in generator_claims(gen_ci, table) if c["key"] == "collision_speed_mps"]
    assert speed["verdict"] == "reversed"
    md = claims_markdown([], gen_ci, table)
    assert ("on matched contacts (same ego and scenario, both with a contact) -0.500 [-0.500 to -0.500] over 30 "
            "episodes; matched, SEAL faster than none, slower than cat") in md


def test_too_few_matched_scenarios_give_no_interval() -> None:
    table = generator_difference_table(_rows(range(10, 12)), ["cat", "seal"], n_boot=100)
    d = next(r for r in table if r["setting"] == "seal")
    assert d[MATCHED_SPEED] == pytest.approx(-0.5) and d["matched_contacts"] == 6
    assert math.isnan(d[f"{MATCHED_SPEED}_low"]) and math.isnan(d[f"{MATCHED_SPEED}_high"])
    assert "[no interval]" in generator_difference_markdown(table)
