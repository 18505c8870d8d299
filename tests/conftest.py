"""Shared fixtures: hand-built scenarios from `scenario_factory` (built once per session)."""

from __future__ import annotations

import pytest
import scenario_factory as sf

from seal.core.scenario import Scenario


@pytest.fixture(scope="session")
def lane_change() -> Scenario:
    return sf.lane_change_scenario()


@pytest.fixture(scope="session")
def curve() -> Scenario:
    return sf.curve_scenario()


@pytest.fixture(scope="session")
def stopped_adv() -> Scenario:
    return sf.stopped_adversary_scenario()


@pytest.fixture(scope="session")
def highway() -> list[Scenario]:
    return [sf.highway_scenario(i) for i in range(3)]


@pytest.fixture(scope="session")
def all_scenarios(lane_change: Scenario, curve: Scenario, stopped_adv: Scenario, highway: list[Scenario]
                  ) -> list[Scenario]:
    return [lane_change, curve, stopped_adv, *highway]
