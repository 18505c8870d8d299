"""The real NGSIM US-101 CommonRoad files (read in place from ../shared/data/ngsim-us101/, never copied)."""

from __future__ import annotations

from pathlib import Path

import pytest

from seal.core.dataset import Dataset
from seal.core.importers import import_files
from seal.core.importers.commonroad import read_commonroad
from seal.experiments.evaluation.replay_check import replay_check

NGSIM = Path(__file__).resolve().parents[3] / "shared" / "data" / "ngsim-us101"
pytestmark = pytest.mark.skipif(
    not NGSIM.is_dir(), reason=f"NGSIM US-101 CommonRoad files not found at {NGSIM} (shared data folder absent)"
)

# The freeway files; the urban Lankershim recording (USA_Lanker-*) has its own rules and tests.
US101_FILES = sorted(NGSIM.glob("USA_US101-*.xml"))


@pytest.fixture(scope="module")
def imported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Dataset, dict]:
    return import_files(US101_FILES, tmp_path_factory.mktemp("ngsim") / "ds", "commonroad", progress=False)


def test_both_versions_and_the_on_ramp_are_read() -> None:
    versions = {}
    for path in US101_FILES:
        rec = read_commonroad(path)
        versions[path.name] = rec.version
        # The on-ramp before it merges: 2020a marks it solid on both sides; 2018b has no markings and the ramp no
        # neighbours, so both its borders are unmarked (the drivable area bounds it).
        sides = ("continuous", "continuous") if rec.version == "2020a" else ("none", "none")
        ramp = [lane for lane in rec.road.lanes if lane.line_types == sides]
        assert ramp, f"{path.name}: no lane with {sides} borders (the on-ramp)"
        assert all(3.0 < lane.width_m < 8.0 for lane in rec.road.lanes)
    assert set(versions.values()) == {"2018b", "2020a"}


def test_every_file_gives_several_scenarios(imported: tuple[Dataset, dict]) -> None:
    ds, report = imported
    assert report["files"] == 3 and report["skipped"] == []
    assert all(n >= 3 for n in report["scenarios_per_file"].values()), report["scenarios_per_file"]
    assert len(ds) == report["scenarios"]


def test_the_logged_ego_replays_to_its_destination(imported: tuple[Dataset, dict]) -> None:
    result = replay_check(imported[0].load(), progress=False)
    assert result["success_rate"] >= 0.9, result["failure_reasons"]


# ------------------------------------------------------------------------------------------------ Lankershim (urban)
LANKERSHIM = sorted(NGSIM.glob("USA_Lanker-*.xml"))


@pytest.fixture(scope="module")
def lankershim(tmp_path_factory: pytest.TempPathFactory) -> tuple[Dataset, dict]:
    if not LANKERSHIM:
        pytest.skip(f"no USA_Lanker-*.xml in {NGSIM}")
    return import_files(LANKERSHIM, tmp_path_factory.mktemp("lanker") / "ds", "commonroad", max_per_file=30,
                        progress=False)


def test_lankershim_logged_egos_replay_and_off_map_windows_are_dropped(lankershim: tuple[Dataset, dict]) -> None:
    ds, report = lankershim
    assert report["skipped"] == [] and len(ds) >= 10
    result = replay_check(ds.load(), progress=False)
    assert result["success_rate"] >= 0.95, result["failure_reasons"]


def test_the_heuristic_ego_meets_no_solid_line_inside_lankershim_junctions(lankershim: tuple[Dataset, dict]) -> None:
    # The recording has no line markings: borders towards oncoming lanes are medians, the others unmarked.
    road = read_commonroad(LANKERSHIM[0]).road
    kinds = {t for lane in road.lanes for t in lane.line_types}
    assert kinds == {"none", "striped", "continuous"}
    result = replay_check(lankershim[0].load(), progress=False, ego="heuristic")
    assert "out_of_road:solid_line" not in result["failure_reasons"], result["failure_reasons"]
