"""CommonRoad import on small synthetic XML files written by the tests: road, tracks, windows, resampling, bad
input (each error names the file and the element), the directory import that skips bad files, replay, and
scoring / splitting of the imported dataset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely
from scenario_factory import CR_LANE_W as LANE_W
from scenario_factory import cut_in, document, lanelet, obstacle, road_2020a
from scenario_factory import write_text as write

from seal.cli import main
from seal.core.dataset import Dataset
from seal.core.geometry import box_corners, box_gap
from seal.core.importers import ImportFailed, ImportFormatError, import_files
from seal.core.importers.commonroad import read_commonroad
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, N_STEPS, VALID, VX, VY, WIDTH, X, Y
from seal.envs.road_geometry import RoadGeometry
from seal.experiments.evaluation.replay_check import replay_check


@pytest.fixture()
def good_file(tmp_path: Path) -> Path:
    return write(tmp_path / "good.xml", document(road_2020a(), cut_in()))


# ------------------------------------------------------------------------------------------------ road
def test_road_from_lanelets(good_file: Path) -> None:
    rec = read_commonroad(good_file)
    road = rec.road
    assert rec.version == "2020a" and rec.benchmark_id == "TEST-1" and road.layout == "polylines"
    lane1, lane2 = road.lane("1"), road.lane("2")
    np.testing.assert_allclose(lane1.centerline[:, 1], 1.75)
    np.testing.assert_allclose(lane2.centerline[:, 1], 5.25)
    assert lane1.width_m == pytest.approx(LANE_W) and lane2.width_m == pytest.approx(LANE_W)
    # Markings: solid -> continuous, dashed -> striped (left, right as seen driving along the lane).
    assert lane1.line_types == ("striped", "striped") and lane2.line_types == ("continuous", "striped")
    assert road.lane("3").line_types == ("striped", "continuous")
    assert road.lane("4").line_types == ("continuous", "striped")
    assert lane1.successors == ("3",) and lane2.successors == ("4",)
    # The widening ramp is cut into pieces; together with the lanes they cover every lanelet.
    ramp = [lane for lane in road.lanes if lane.lane_id.startswith("5#")]
    assert len(ramp) >= 6 and ramp[0].line_types == ("striped", "continuous")
    assert ramp[-1].width_m == pytest.approx(LANE_W + 2.0)
    geom = RoadGeometry(road)
    true_area = shapely.union_all([
        shapely.box(0, 0, 400, 2 * LANE_W), shapely.Polygon([(0, 0), (100, 0), (100, -LANE_W - 2), (0, -LANE_W)]),
    ])
    assert shapely.difference(shapely.buffer(true_area, -0.05), geom.drivable).area < 1e-6
    assert shapely.difference(geom.drivable, shapely.buffer(true_area, 0.2)).area < 1e-6
    assert not any(len(p.interiors) for p in getattr(geom.drivable, "geoms", [geom.drivable]))  # no holes


def test_2018b_markings_are_inferred_from_adjacency(tmp_path: Path) -> None:
    w = LANE_W
    oncoming = '<adjacentLeft ref="3" drivingDir="opposite"/>'
    lanes = [
        lanelet(1, [(0, w), (300, w)], [(0, 0), (300, 0)], adj_left=2, extra="<speedLimit>22.2</speedLimit>"),
        lanelet(2, [(0, 2 * w), (300, 2 * w)], [(0, w), (300, w)], adj_right=1, extra=oncoming),
        # Lane 3 runs the other way (its left border is lane 2's left border); its right side has no neighbour.
        lanelet(3, [(300, 2 * w), (0, 2 * w)], [(300, 3 * w), (0, 3 * w)],
                extra='<adjacentLeft ref="2" drivingDir="opposite"/>'),
    ]
    obs = [obstacle(7, [(k, 10 + 15 * k * 0.1, 1.75, 0.0, 15.0) for k in range(40)], tag="obstacle", role="dynamic"),
           obstacle(8, [(0, 50.0, 5.25, 0.0, None)], tag="obstacle", role="static")]
    rec = read_commonroad(write(tmp_path / "old.xml", document(lanes, obs, version="2018b")))
    assert rec.version == "2018b"
    # No lineMarking: striped towards a same-direction neighbour, continuous towards oncoming traffic (a median),
    # unmarked ("none") without a neighbour: not a solid line; the drivable area still ends the road there.
    assert rec.road.lane("1").line_types == ("striped", "none")
    assert rec.road.lane("2").line_types == ("continuous", "striped")
    assert rec.road.lane("3").line_types == ("continuous", "none")
    assert rec.road.lane("1").speed_limit_mps == pytest.approx(22.2)
    assert rec.road.lane("2").speed_limit_mps == pytest.approx(30.0)
    assert rec.log.agent_types == ("vehicle", "vehicle")
    static = rec.log.tracks[1]
    assert (static[:, VALID] == 1).all() and (static[:, [VX, VY]] == 0).all()  # stands still for all 40 steps


# ------------------------------------------------------------------------------------------------ tracks
def test_tracks_follow_the_states(good_file: Path) -> None:
    log = read_commonroad(good_file).log
    assert log.n_steps == 101 and list(log.agent_ids) == [10, 11, 12, 13]
    assert log.agent_types == ("vehicle", "vehicle", "vehicle", "vehicle")
    ego = log.tracks[0]
    t = np.arange(101) * 0.1
    np.testing.assert_allclose(ego[:, X], 20 + 20 * t, atol=1e-9)
    np.testing.assert_allclose(ego[:, [Y, HEADING, VX, VY, LENGTH, WIDTH, VALID]],
                               [[1.75, 0.0, 20.0, 0.0, 4.5, 1.8, 1.0]] * 101, atol=1e-9)
    truck = log.tracks[1]
    assert truck[0, LENGTH] == 6.0 and truck[0, WIDTH] == 2.2
    speed, h = np.hypot(truck[:, VX], truck[:, VY]), truck[:, HEADING]
    np.testing.assert_allclose(truck[:, VY], speed * np.sin(h), atol=1e-9)  # velocity along the orientation
    parked = log.tracks[3]
    assert (parked[:, VALID] == 1).all() and (parked[:, X] == 90.0).all()


@pytest.mark.parametrize("dt", [0.05, 0.2])
def test_other_time_steps_are_resampled_to_10hz(tmp_path: Path, dt: float) -> None:
    n = round(8.0 / dt) + 1
    states = [(k, 5.0 + 12.0 * k * dt, 1.75, 0.0, 12.0) for k in range(n)]
    rec = read_commonroad(write(tmp_path / "r.xml", document(road_2020a(), [obstacle(1, states)], dt=dt)))
    assert rec.time_step_s == dt and rec.log.n_steps == 81
    np.testing.assert_allclose(rec.log.tracks[0, :, X], 5.0 + 12.0 * np.arange(81) * 0.1, atol=1e-9)


def test_missing_velocities_come_from_the_positions(tmp_path: Path) -> None:
    states = [(k, 3.0 * k, 1.75, 0.0, None) for k in range(30)]  # 30 m/s
    rec = read_commonroad(write(tmp_path / "nv.xml", document(road_2020a(), [obstacle(1, states)])))
    np.testing.assert_allclose(rec.log.tracks[0, :, VX], 30.0, atol=1e-9)


# ------------------------------------------------------------------------------------------------ windows
def test_the_cut_in_becomes_one_scenario_with_the_cutting_truck_as_adversary(tmp_path: Path, good_file: Path) -> None:
    ds, report = import_files([good_file], tmp_path / "ds", "commonroad", progress=False)
    assert report["scenarios"] == 1 and report["skipped"] == []
    (s,) = ds.load()
    assert s.scenario_id == "good-00" and s.source == "commonroad:good.xml"
    assert (s.ego_id, s.adv_id) == (10, 11)  # the truck changes lane: it is the adversary
    # 10 s of log: every start up to step 10 keeps 91 logged steps; the closest approach then sits near step 40.
    assert s.layout == "TEST" and s.metadata["source"] == "commonroad"  # the benchmark ID's location
    assert s.metadata["lane_change"] and 0 <= s.metadata["t0_step"] <= 10
    assert s.metadata["logged_steps"] == N_STEPS and s.metadata["benchmark_id"] == "TEST-1"
    # Once in lane: bumper gap 8 m - (4.5 + 6) / 2 = 2.75 m; the angled truck's corner comes a bit closer before.
    ego, adv = s.track(10), s.track(11)
    corners = [box_corners(t[:, X], t[:, Y], t[:, HEADING], t[:, LENGTH], t[:, WIDTH]) for t in (ego, adv)]
    gaps = box_gap(*corners)
    assert gaps[-1] == pytest.approx(2.75, abs=1e-4)
    assert s.metadata["pair_min_gap_m"] == pytest.approx(gaps[CURRENT_STEP:].min(), abs=1e-3)
    assert 2.5 < s.metadata["pair_min_gap_m"] < 2.75
    assert s.agent_ids.tolist() == [10, 11, 13]  # 12 stays 130 m ahead, beyond the 80 m context
    t_current = (s.metadata["t0_step"] + CURRENT_STEP) * 0.1  # recording time (s) of the current step
    assert s.tracks[0, CURRENT_STEP, X] == pytest.approx(20 + 20 * t_current)
    result = replay_check([s], progress=False)
    assert result["success_rate"] == 1.0 and result["rows"][0]["max_tracking_error_m"] < 0.05


def test_short_recordings_are_padded_and_far_pairs_ignored(tmp_path: Path) -> None:
    # 4 s of log: windows keep 40 real steps, the rest is padding; the far car makes no pair.
    obs = cut_in(steps=41)
    ds, _ = import_files([write(tmp_path / "short.xml", document(road_2020a(), obs))], tmp_path / "ds",
                         "commonroad", progress=False)
    (s,) = ds.load()
    assert s.metadata["logged_steps"] == 41
    assert s.valid[:, 41:].sum() == 0 and s.valid[s.ego_index, :41].all()
    # Too short for the required future: nothing to import.
    with pytest.raises(ImportFailed, match="no window"):
        import_files([tmp_path / "short.xml"], tmp_path / "ds2", "commonroad", min_future_steps=40, progress=False)


# ------------------------------------------------------------------------------------------------ bad input
def _error(tmp_path: Path, name: str, text: str) -> str:
    path = write(tmp_path / name, text)
    with pytest.raises(ImportFormatError) as exc:
        read_commonroad(path)
    msg = str(exc.value)
    assert msg.startswith(str(path))
    return msg


def test_bad_files_give_clear_errors(tmp_path: Path) -> None:
    good = cut_in()
    msg = _error(tmp_path, "trunc.xml", document(road_2020a(), good)[:-40])
    assert "malformed XML" in msg and "line" in msg
    msg = _error(tmp_path, "v.xml", document(road_2020a(), good, version="2017a"))
    assert "unsupported CommonRoad version '2017a'" in msg and "2018b, 2020a" in msg
    assert "no <lanelet>" in _error(tmp_path, "nolanes.xml", document([], good))
    gap = [(k, 10 + 2.0 * k, 1.75, 0.0, 20.0) for k in range(40) if k not in (13, 14)]
    msg = _error(tmp_path, "gap.xml", document(road_2020a(), [obstacle(7, gap)]))
    assert "dynamicObstacle 7" in msg and "gap" in msg and "13..14" in msg
    poly = "<shape><polygon><point><x>0</x><y>0</y></point></polygon></shape>"
    msg = _error(tmp_path, "shape.xml", document(road_2020a(), [obstacle(7, gap[:5], shape=poly)]))
    assert "dynamicObstacle 7 <shape>" in msg and "polygon" in msg
    bad_num = document(road_2020a(), good).replace("<x>0</x>", "<x>zero</x>", 1)
    msg = _error(tmp_path, "num.xml", bad_num)
    assert "lanelet 1 <leftBound>" in msg and "'zero'" in msg
    msg = _error(tmp_path, "nobound.xml", document([lanelet(1, [(0, 0)], [(0, 0), (1, 0)])], good))
    assert "lanelet 1 <leftBound>" in msg and "at least 2 <point>" in msg
    msg = _error(tmp_path, "nodyn.xml", document(road_2020a(), []))
    assert "no dynamic obstacles" in msg


def test_a_directory_import_reports_and_skips_bad_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "src"
    (src / "sub").mkdir(parents=True)
    write(src / "a.xml", document(road_2020a(), cut_in()))
    write(src / "sub" / "a.xml", document(road_2020a(), cut_in(gap_m=9.0)))  # same stem, other folder
    write(src / "broken.xml", "<commonRoad")
    write(src / "old.xml", document(road_2020a(), cut_in(), version="2017a"))
    write(src / "notes.txt", "not a scenario")
    out = tmp_path / "ds"
    assert main(["data", "import", "commonroad", str(src), "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "imported 2 scenarios from 2 of 4 files" in text and "skipped 2 file(s)" in text
    assert "broken.xml: malformed XML" in text and "old.xml: commonRoad commonRoadVersion" in text
    ds = Dataset.open(out)
    assert sorted(s.scenario_id for s in ds.load()) == ["a-00", "a~1-00"]
    report = json.loads((out / "import_report.json").read_text())
    assert report["skipped_files"] == 2 and report["scenarios"] == 2
    assert ds.manifest["provenance"]["importer"] == "seal.core.importers.commonroad"
    # Every file bad: a clear error, exit status 2.
    assert main(["data", "import", "commonroad", str(src / "broken.xml"), "--out", str(tmp_path / "x"),
                 "--no-progress"]) == 2
    assert "no scenario imported" in capsys.readouterr().err
    from seal.core.importers.driver import staging_dir

    # Nothing is left that `seal data info` would take for an interrupted build.
    assert not (tmp_path / "x").exists() and not staging_dir(tmp_path / "x").exists()
    assert main(["data", "import", "commonroad", str(tmp_path / "nope"), "--out", str(tmp_path / "y")]) == 2
    assert "no such file or directory" in capsys.readouterr().err


def test_an_interrupted_import_resumes_without_rereading_done_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from seal.core.importers import driver

    src = tmp_path / "src"
    src.mkdir()
    for k in range(3):
        write(src / f"f{k}.xml", document(road_2020a(), cut_in(gap_m=6.0 + k)))
    real = driver.FORMATS["commonroad"]
    seen: list[str] = []

    def flaky(path: Path, prefix: str, opts: driver.ImportOptions) -> list:
        seen.append(path.name)
        if path.name == "f1.xml" and seen.count("f1.xml") == 1:
            raise KeyboardInterrupt  # not a bad file: the whole import stops
        return real.read(path, prefix, opts)

    monkeypatch.setattr(driver, "FILES_PER_SHARD", 1)
    monkeypatch.setitem(driver.FORMATS, "commonroad", driver.Format(".xml", 8, flaky))
    with pytest.raises(KeyboardInterrupt):
        import_files([src], tmp_path / "ds", "commonroad", progress=False)
    # The interrupted build waits in the staging folder; no output folder exists until the import completes.
    staging = driver.staging_dir(tmp_path / "ds")
    assert (staging / "build.json").exists() and not (tmp_path / "ds").exists()
    ds, report = import_files([src], tmp_path / "ds", "commonroad", progress=False)
    assert seen == ["f0.xml", "f1.xml", "f1.xml", "f2.xml"]  # f0 was done before the interruption
    assert report["scenarios"] == 3 and [s.scenario_id for s in ds.load()] == ["f0-00", "f1-00", "f2-00"]


def test_imported_datasets_score_and_split(tmp_path: Path) -> None:
    from seal.scoring.splits import make_splits
    from seal.scoring.store import score_dataset

    src = tmp_path / "src"
    src.mkdir()
    for k, gap in enumerate([6.0, 6.5, 7.0, 8.0, 9.0, 10.0]):  # all within 5 m bumper to bumper
        write(src / f"f{k}.xml", document(road_2020a(), cut_in(gap_m=gap, v=16.0 + k)))
    import_files([src], tmp_path / "ds", "commonroad", progress=False)
    score_dataset(tmp_path / "ds", workers=1, progress=False)
    result = make_splits(tmp_path / "ds", hard_quantile=0.5, n_train=2, n_eval=1, n_hard=2, seed=0, hard_by="scene")
    assert result["shared_groups"] == 0 and sum(result["groups"].values()) == 5  # one group per recording
    splits = Dataset.open(tmp_path / "ds").splits
    assert (result["train"], result["eval"], result["hard"]) == (2, 1, 2)
    assert len({*splits["train"], *splits["eval"], *splits["hard"]}) == 5
    assert len(Dataset.open(tmp_path / "ds").load(split="hard")) == 2


def test_cli_help_states_the_importers_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    from seal.core.importers import FORMATS

    for fmt, spec in FORMATS.items():
        with pytest.raises(SystemExit):
            main(["data", "import", fmt, "--help"])
        assert f"(default {spec.default_max_per_file})" in " ".join(capsys.readouterr().out.split())


def test_the_replay_check_explains_its_failures(tmp_path: Path, good_file: Path) -> None:
    import dataclasses

    from seal.core.road import LaneSpec, RoadDescription

    ds, _ = import_files([good_file], tmp_path / "ds", "commonroad", progress=False)
    (s,) = ds.load()
    x_now = float(s.tracks[0, CURRENT_STEP, X])
    # The map ends 30 m ahead of the ego: its logged route runs off the road.
    short = RoadDescription("polylines", (LaneSpec("a", np.array([[0.0, 1.75], [x_now + 30.0, 1.75]]), LANE_W),))
    off = dataclasses.replace(s, scenario_id="off", road=short)
    # A parked car on the ego's logged path from step 30 on: the logged boxes overlap too.
    tracks = s.tracks.copy()
    blocker = np.zeros((1, N_STEPS, 8), dtype=np.float32)
    blocker[0, 30:] = tracks[0, 40]
    blocker[0, 30:, VX:VY + 1] = 0.0
    crash = dataclasses.replace(s, scenario_id="crash", tracks=np.concatenate([tracks, blocker]),
                                agent_ids=np.append(s.agent_ids, 99), agent_types=(*s.agent_types, "vehicle"))
    result = replay_check([s, off, crash], progress=False)
    rows = {r["scenario_id"]: r for r in result["rows"]}
    assert rows[s.scenario_id]["outcome"] == "success"
    assert rows["off"]["outcome"] == "out_of_road" and rows["off"]["reason"] == "off_drivable"
    assert rows["off"]["logged_ego_off_drivable"] is True
    assert rows["crash"]["outcome"] == "crash" and rows["crash"]["crash_agent_id"] == 99
    assert rows["crash"]["logged_boxes_overlap"] is True
    assert result["success_rate"] == pytest.approx(1 / 3)
    assert result["failure_reasons"] == {"crash:logged overlap": 1, "out_of_road:off_drivable": 1}


def test_imported_recordings_keep_their_location_as_layout() -> None:
    from seal.core.importers.commonroad import describe, recording_layout, road_type

    assert recording_layout("USA_US101-26_1_T-1") == "USA_US101"
    assert recording_layout("DEU_Flensburg-1_1_T-1") == "DEU_Flensburg"
    assert road_type(("critical", "interstate")) == "highway" and road_type(("urban", "comfort")) == "urban"
    assert road_type(("comfort",)) is None
    shared = Path(__file__).resolve().parents[3] / "shared" / "data" / "ngsim-us101"
    if not shared.is_dir():
        pytest.skip("no shared NGSIM recordings")
    described = [describe(read_commonroad(shared / f)) for f in ("USA_Lanker-1_1_T-1.xml", "USA_US101-26_1_T-1.xml")]
    found = {d["layout"]: d["road_type"] for d in described}
    assert found == {"USA_Lanker": "urban", "USA_US101": "highway"}  # freeway and urban streets apart
