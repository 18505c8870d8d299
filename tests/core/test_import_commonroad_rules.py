"""CommonRoad import rules for real files: unmarked borders, uncertain states, windows whose logged ego leaves the
mapped road, and atomic, fingerprinted imports (small hand-built documents)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scenario_factory import CR_LANE_W as W
from scenario_factory import cut_in, document, lanelet, obstacle, road_2020a, write_text

from seal.cli import main
from seal.core.dataset import Dataset
from seal.core.importers import ImportFailed, import_files
from seal.core.importers.commonroad import read_commonroad
from seal.core.importers.driver import staging_dir
from seal.envs.road_geometry import RoadGeometry


# ------------------------------------------------------------------------------------------------ unmarked borders
def test_an_unmarked_border_without_a_neighbour_is_no_solid_line(tmp_path: Path) -> None:
    """Two lanelets side by side with no markings and no declared adjacency (as inside a junction): a car across
    their shared border is on the drivable area and crosses no solid line; the outer edge still ends the road."""
    lanes = [lanelet(1, [(0, W), (300, W)], [(0, 0), (300, 0)]),
             lanelet(2, [(0, 2 * W), (300, 2 * W)], [(0, W), (300, W)])]
    traffic = [obstacle(7, [(k, 10 + 1.5 * k, 1.75, 0.0, 15.0) for k in range(40)])]
    rec = read_commonroad(write_text(tmp_path / "junction.xml", document(lanes, traffic)))
    assert {lane.line_types for lane in rec.road.lanes} == {("none", "none")}
    geom = RoadGeometry(rec.road)
    assert geom.continuous_polylines == []
    straddling = (100.0, W, 0.3, 4.5, 1.8)  # centred on the shared border, slightly turned
    assert not geom.crosses_continuous(*straddling)
    assert geom.on_road(np.array([100.0]), np.array([W]))
    assert not geom.on_road(np.array([100.0]), np.array([2 * W + 1.0]))  # beyond the outer, unmarked edge
    # The road edge is still an edge for the ego's edge rays: the drivable-area boundary.
    assert len(geom.boundary_polylines) >= 1


# ------------------------------------------------------------------------------------------------ uncertain states
def _uncertain_state(tag: str, step: int, x: float, y: float, h: float, v: float) -> str:
    """A BMW-style state: position within a rectangle, orientation and velocity as intervals around the truth."""
    return (f"<{tag}><position><rectangle><length>2.0</length><width>1.0</width><orientation>{h}</orientation>"
            f"<center><x>{x}</x><y>{y}</y></center></rectangle></position>"
            f"<orientation><intervalStart>{h - 0.02}</intervalStart><intervalEnd>{h + 0.02}</intervalEnd>"
            f"</orientation><time><exact>{step}</exact></time>"
            f"<velocity><intervalStart>{v - 0.5}</intervalStart><intervalEnd>{v + 0.5}</intervalEnd>"
            f"</velocity></{tag}>")


def test_uncertain_states_read_as_the_centre_and_the_midpoint(tmp_path: Path) -> None:
    states = [_uncertain_state("initialState" if k == 0 else "state", k, 30.0 + 2.0 * k, 1.75, 0.1, 20.0)
              for k in range(30)]
    fuzzy = ('<dynamicObstacle id="40"><type>car</type><shape><rectangle><length>4.5</length><width>1.8</width>'
             "</rectangle></shape>" + states[0] + "<trajectory>" + "".join(states[1:]) + "</trajectory>"
             "</dynamicObstacle>")
    circle = ('<dynamicObstacle id="41"><type>car</type><shape><circle><radius>1.0</radius></circle></shape>'
              "<initialState><position><circle><radius>0.5</radius><center><x>60</x><y>5.25</y></center></circle>"
              "</position><orientation><exact>0</exact></orientation><time><exact>0</exact></time>"
              "</initialState></dynamicObstacle>")
    path = write_text(tmp_path / "bmw.xml", document(road_2020a(), [*cut_in(), fuzzy, circle]))
    rec = read_commonroad(path)
    row = rec.log.tracks[list(rec.log.agent_ids).index(40)]
    np.testing.assert_allclose(row[:30, 0], 30.0 + 2.0 * np.arange(30), atol=1e-9)
    np.testing.assert_allclose(row[:30, 2], 0.1, atol=1e-9)  # orientation: the interval's midpoint
    np.testing.assert_allclose(np.hypot(row[:30, 3], row[:30, 4]), 20.0, atol=1e-9)
    circ = rec.log.tracks[list(rec.log.agent_ids).index(41)]
    np.testing.assert_allclose(circ[0, :2], [60.0, 5.25])
    assert rec.uncertain_states == 31
    _, report = import_files([path], tmp_path / "ds", "commonroad", progress=False)
    assert report["repaired"] == {"uncertain_states": 31}


def test_bad_uncertain_values_name_the_element(tmp_path: Path) -> None:
    bad = ('<dynamicObstacle id="40"><type>car</type><shape><rectangle><length>4.5</length><width>1.8</width>'
           "</rectangle></shape><initialState><position><lanelet ref=\"1\"/></position>"
           "<orientation><exact>0</exact></orientation><time><exact>0</exact></time></initialState>"
           "</dynamicObstacle>")
    with pytest.raises(ValueError, match=r"dynamicObstacle 40 <initialState> <position>: needs a <point> or a"):
        read_commonroad(write_text(tmp_path / "bad.xml", document(road_2020a(), [*cut_in(), bad])))
    reversed_interval = _uncertain_state("initialState", 0, 30.0, 1.75, 0.0, 20.0).replace(
        "<intervalStart>19.5</intervalStart><intervalEnd>20.5</intervalEnd>",
        "<intervalStart>20.5</intervalStart><intervalEnd>19.5</intervalEnd>")
    bad = ('<dynamicObstacle id="40"><type>car</type><shape><rectangle><length>4.5</length><width>1.8</width>'
           "</rectangle></shape>" + reversed_interval + "</dynamicObstacle>")
    with pytest.raises(ValueError, match=r"<velocity>: interval end 19.5 is below its start 20.5"):
        read_commonroad(write_text(tmp_path / "bad2.xml", document(road_2020a(), [*cut_in(), bad])))


# ------------------------------------------------------------------------------------------------ off the map
def test_windows_whose_logged_ego_leaves_the_mapped_road_are_dropped(tmp_path: Path) -> None:
    short = [lanelet(1, [(0, W), (120, W)], [(0, 0), (120, 0)], ("dashed", "solid"), (), 2),
             lanelet(2, [(0, 2 * W), (120, 2 * W)], [(0, W), (120, W)], ("solid", "dashed"), (), None, 1)]
    path = write_text(tmp_path / "short.xml", document(short, cut_in()))
    with pytest.raises(ImportFailed, match=r"window\(s\) dropped: the logged ego leaves the mapped road"):
        import_files([path], tmp_path / "ds", "commonroad", progress=False)
    # The same traffic on a road long enough for it: imported, nothing dropped.
    good = write_text(tmp_path / "long.xml", document(road_2020a(), cut_in()))
    _, report = import_files([good, path], tmp_path / "ds", "commonroad", progress=False)
    assert report["scenarios_per_file"] == {str(good): 1, str(path): 0}
    assert report["dropped"]["windows_ego_leaves_mapped_road"] >= 1
    assert "windows_ego_leaves_mapped_road" not in report["per_file"][str(good)]["dropped"]


# ------------------------------------------------------------------------------------------------ atomic imports
def test_a_failed_import_leaves_nothing_and_a_fixed_input_is_read_again(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_text(tmp_path / "rec.xml", document(road_2020a(), cut_in()).replace("<x>", "<x>oops", 1))
    out = tmp_path / "ds"
    args = ["data", "import", "commonroad", str(path), "--out", str(out), "--no-progress", "--json"]
    assert main(args) == 2
    assert "rec.xml: lanelet 1 <leftBound>: <x> is not a number" in capsys.readouterr().err
    assert not out.exists() and not staging_dir(out).exists()
    write_text(path, document(road_2020a(), cut_in()))  # fixed: the same command reads it again
    assert main(args) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["scenarios"] == 1 and report["skipped"] == []
    assert len(Dataset.open(out)) == 1 and not staging_dir(out).exists()
    assert json.loads((out / "import_report.json").read_text())["scenarios"] == 1


def test_a_resumed_import_reads_changed_files_again(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from seal.core.importers import driver

    src = tmp_path / "src"
    src.mkdir()
    for k in range(3):
        write_text(src / f"f{k}.xml", document(road_2020a(), cut_in(gap_m=6.0 + k)))
    real = driver.FORMATS["commonroad"]
    seen: list[str] = []

    def flaky(path: Path, prefix: str, opts: driver.ImportOptions) -> driver.FileImport:
        seen.append(path.name)
        if path.name == "f2.xml" and seen.count("f2.xml") == 1:
            raise KeyboardInterrupt
        return real.read(path, prefix, opts)

    monkeypatch.setattr(driver, "FILES_PER_SHARD", 1)
    monkeypatch.setitem(driver.FORMATS, "commonroad", driver.Format(".xml", 8, flaky))
    with pytest.raises(KeyboardInterrupt):
        import_files([src], tmp_path / "ds", "commonroad", progress=False)
    # f0 changes while the import is interrupted (f1 does not): the resumed import reads f0 again.
    write_text(src / "f0.xml", document(road_2020a(), cut_in(gap_m=9.0)))
    ds, report = import_files([src], tmp_path / "ds", "commonroad", progress=False)
    assert seen == ["f0.xml", "f1.xml", "f2.xml", "f0.xml", "f2.xml"]
    first = ds.load()[0]
    gap = first.track(first.adv_id)[0, 0] - first.track(first.ego_id)[0, 0]  # both at 20 m/s: constant along x
    assert first.scenario_id == "f0-00" and math.isclose(gap, 9.0, abs_tol=1e-3)  # the new f0, not the old
    assert report["scenarios"] == 3


def test_overwrite_keeps_the_old_dataset_until_the_new_one_is_complete(tmp_path: Path) -> None:
    good = write_text(tmp_path / "good.xml", document(road_2020a(), cut_in()))
    out = tmp_path / "ds"
    import_files([good], out, "commonroad", progress=False)
    bad = write_text(tmp_path / "bad.xml", "<commonRoad")
    with pytest.raises(ImportFailed):
        import_files([bad], out, "commonroad", overwrite=True, progress=False)
    assert len(Dataset.open(out)) == 1 and not staging_dir(out).exists()
    # Without --overwrite a finished dataset or a foreign folder is refused, naming it.
    with pytest.raises(RuntimeError, match="already holds a finished dataset"):
        import_files([good], out, "commonroad", progress=False)
    (tmp_path / "other").mkdir()
    (tmp_path / "other" / "notes.txt").write_text("mine")
    with pytest.raises(RuntimeError, match="other exists and is not a seal dataset"):
        import_files([good], tmp_path / "other", "commonroad", progress=False)
    assert (tmp_path / "other" / "notes.txt").read_text() == "mine"
