"""Shared fixtures: hand-built scenarios from `scenario_factory` (built once per session)."""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
import scenario_factory as sf

from seal.core.scenario import Scenario


@pytest.fixture(scope="session", autouse=True)
def sb3_logs_in_pytest_tmp(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """Tests that call an SB3 model's ``learn`` without a logger of their own get SB3's default one, which makes an
    (empty) ``SB3-<date>`` folder in the system temp dir on every call; point it at pytest's temp dir instead."""
    old = os.environ.get("SB3_LOGDIR")
    os.environ["SB3_LOGDIR"] = str(tmp_path_factory.mktemp("sb3-logs"))
    yield
    if old is None:
        os.environ.pop("SB3_LOGDIR", None)
    else:
        os.environ["SB3_LOGDIR"] = old


@pytest.fixture(scope="session", autouse=True)
def one_torch_thread() -> Iterator[None]:
    """One torch thread per test process, as the CLI's fits and workers set for themselves: ``pytest -n auto``
    runs a process per core, and torch's own threads on top of that oversubscribe the cores (a small GRU fit took
    8x longer with two threads per process on this 2-core machine under load)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


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
