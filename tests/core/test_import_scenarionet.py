"""ScenarioNet import on pickles built by the tests in the documented format, and the restricted unpickler."""

from __future__ import annotations

import collections
import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scenario_factory import SN_LANE_W as LANE_W
from scenario_factory import SN_T as T
from scenario_factory import dump_pickle as dump
from scenario_factory import scenarionet_scenario as scenario

from seal.cli import main
from seal.core.dataset import Dataset
from seal.core.importers import ImportFormatError, UnsafePickleError, import_files, safe_load
from seal.core.importers.scenarionet import read_scenarionet
from seal.core.scenario import HEADING, LENGTH, VALID, VX, WIDTH, X
from seal.experiments.evaluation.replay_check import replay_check


# ------------------------------------------------------------------------------------------------ safe pickle
@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_safe_load_round_trips_numpy_and_plain_containers(tmp_path: Path, protocol: int) -> None:
    obj = {"a": np.arange(6, dtype=np.float32).reshape(2, 3), "b": np.array([True, False]), "c": np.float64(2.5),
           "d": collections.defaultdict(int, {"x": 3}), "e": {"s", "t"}, "f": (1, [2.0, "x"]), "g": b"\x00\x01",
           "h": np.array(["ab", "c"]), "i": 2**70, "j": None}
    got = safe_load(dump(tmp_path / "ok.pkl", obj, protocol))
    assert got["a"].dtype == np.float32 and np.array_equal(got["a"], obj["a"])
    assert np.array_equal(got["b"], obj["b"]) and got["c"] == 2.5 and type(got["d"]) is dict and got["d"] == {"x": 3}
    assert got["e"] == {"s", "t"} and got["f"] == (1, [2.0, "x"]) and got["g"] == b"\x00\x01"
    assert got["h"].tolist() == ["ab", "c"] and got["i"] == 2**70 and got["j"] is None


class _Evil:
    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple:
        return (os.system, (f"touch {self.marker}",))


def test_a_forbidden_class_is_refused_before_anything_runs(tmp_path: Path) -> None:
    marker = tmp_path / "pwned"
    data = scenario()
    data["metadata"]["payload"] = _Evil(marker)
    path = dump(tmp_path / "evil.pkl", data)
    with pytest.raises(UnsafePickleError) as exc:
        read_scenarionet(path)
    assert str(exc.value).startswith(str(path)) and f"{os.system.__module__}.system" in str(exc.value)
    assert not marker.exists()
    # Any non-plain class, even a harmless one, is refused by name.
    with pytest.raises(UnsafePickleError, match=r"refused to load collections\.Counter"):
        safe_load(dump(tmp_path / "counter.pkl", {"c": collections.Counter("ab")}))


# ------------------------------------------------------------------------------------------------ import
def test_road_from_map_features(tmp_path: Path) -> None:
    rec = read_scenarionet(dump(tmp_path / "sd_waymo_v1_abc.pkl", scenario()))
    road = rec.road
    assert {lane.lane_id for lane in road.lanes} == {"1", "2", "3", "4"}  # the bike lane is left out
    lane1, lane2, lane4 = road.lane("1"), road.lane("2"), road.lane("4")
    assert lane1.width_m == pytest.approx(LANE_W) and lane2.width_m == pytest.approx(LANE_W)
    assert lane4.width_m == pytest.approx(3.0, abs=0.01)  # from its polygon
    assert road.lane("3").width_m == pytest.approx(3.7)  # no width information: the default
    # Sides from the nearest road line / edge: broken -> striped, solid yellow / edge -> continuous, none -> none.
    assert lane1.line_types == ("striped", "continuous") and lane2.line_types == ("continuous", "striped")
    assert lane4.line_types == ("none", "none")
    assert lane1.successors == ("3",) and road.lane("3").successors == ()  # unknown exit lane dropped
    assert lane1.speed_limit_mps == pytest.approx(25 * 0.44704)


def test_tracks_ego_adversary_and_gaps(tmp_path: Path) -> None:
    rec = read_scenarionet(dump(tmp_path / "s.pkl", scenario()))
    log = rec.log
    assert log.source_ids == ("100", "200", "300", "400", "500", "600") and list(log.agent_ids) == [100, 200, 300,
                                                                                                    400, 500, 600]
    assert log.agent_types == ("vehicle", "vehicle", "pedestrian", "vehicle", "vehicle", "vehicle")
    assert rec.sdc_row == 0 and rec.interest_rows == (2, 1)
    t = np.arange(T) * 0.1
    np.testing.assert_allclose(log.tracks[0, :, X], 12.0 * t, atol=1e-4)
    np.testing.assert_allclose(log.tracks[0, :, [LENGTH, WIDTH]].T, [[4.6, 1.9]] * T, atol=1e-6)
    # The 3-step occlusion of 400 is bridged by interpolation (exact for its straight, steady motion).
    assert log.valid[3].all()
    np.testing.assert_allclose(log.tracks[3, 48:56, X], -25.0 + 12.0 * t[48:56], atol=1e-4)
    assert not log.valid[4, 40:60].any() and log.valid[4, :40].all()  # 20 steps are too long to bridge

    ds, report = import_files([tmp_path / "s.pkl"], tmp_path / "ds", "scenarionet", progress=False)
    (s,) = ds.load()
    # The pedestrian of interest cannot be the adversary: the next object of interest is.
    assert (s.ego_id, s.adv_id) == (100, 200) and s.source == "scenarionet:waymo:s.pkl"
    assert s.metadata["t0_step"] == 0 and s.metadata["logged_steps"] == T and s.metadata["dataset"] == "waymo"
    assert s.metadata["ego_source_id"] == "100" and s.metadata["lane_change"]
    assert 600 not in s.agent_ids.tolist()  # 200 m away: outside the 80 m context
    gone = s.track(500)
    assert gone[:40, VALID].all() and not gone[40:, VALID].any()  # one block: the one holding the current step
    result = replay_check(ds.load(), progress=False)
    assert result["success_rate"] == 1.0


def test_without_objects_of_interest_the_most_interacting_vehicle_is_the_adversary(tmp_path: Path) -> None:
    ds, _ = import_files([dump(tmp_path / "s.pkl", scenario(objects_of_interest=None))], tmp_path / "ds",
                         "scenarionet", progress=False)
    (s,) = ds.load()
    assert (s.ego_id, s.adv_id) == (100, 200)


def test_objects_of_interest_are_taken_in_their_order(tmp_path: Path) -> None:
    # 400 trails the SDC by 25 m without interacting, but it is listed first: the dataset's choice wins.
    ds, _ = import_files([dump(tmp_path / "s.pkl", scenario(objects_of_interest=["400", "200"]))], tmp_path / "ds",
                         "scenarionet", progress=False)
    (s,) = ds.load()
    assert (s.ego_id, s.adv_id) == (100, 400)
    assert s.metadata["objects_of_interest"] == ["400", "200"]


def test_other_rates_are_resampled(tmp_path: Path) -> None:
    data = scenario()
    # Keep every other step: a 5 Hz recording of the same motion.
    keep = np.arange(0, T, 2)
    for obj in data["tracks"].values():
        obj["state"] = {k: v[keep] for k, v in obj["state"].items()}
    data["metadata"]["ts"] = data["metadata"]["ts"][keep]
    data["length"] = len(keep)
    rec = read_scenarionet(dump(tmp_path / "s.pkl", data))
    assert rec.log.n_steps == T
    np.testing.assert_allclose(rec.log.tracks[0, :, X], 12.0 * np.arange(T) * 0.1, atol=1e-4)
    np.testing.assert_allclose(rec.log.tracks[0, :, HEADING], 0.0, atol=1e-6)
    np.testing.assert_allclose(rec.log.tracks[0, :, VX], 12.0, atol=1e-5)


def _expect(tmp_path: Path, data: Any, *fragments: str) -> None:
    path = dump(tmp_path / "bad.pkl", data)
    with pytest.raises(ImportFormatError) as exc:
        read_scenarionet(path)
    msg = str(exc.value)
    assert msg.startswith(str(path)), msg
    for f in fragments:
        assert f in msg, msg


def test_bad_scenarios_give_clear_errors(tmp_path: Path) -> None:
    _expect(tmp_path, [1, 2], "scenario", "must be a dict")
    d = scenario()
    del d["map_features"]
    _expect(tmp_path, d, "missing key 'map_features'")
    d = scenario()
    del d["metadata"]["sdc_id"]
    _expect(tmp_path, d, "metadata.sdc_id", "missing")
    d = scenario()
    d["metadata"]["sdc_id"] = "77"
    _expect(tmp_path, d, "metadata.sdc_id", "'77' is not among the tracks")
    d = scenario()
    d["tracks"]["200"]["state"]["heading"] = np.zeros(5)
    _expect(tmp_path, d, "tracks['200'].state.heading", "shape [91]")
    d = scenario()
    d["map_features"] = {k: v for k, v in d["map_features"].items() if not v["type"].startswith("LANE")}
    _expect(tmp_path, d, "map_features", "no lane centre lines")
    d = scenario()
    d["metadata"]["ts"] = d["metadata"]["ts"][:10]
    _expect(tmp_path, d, "metadata.ts", "10 time stamps")
    (tmp_path / "trunc.pkl").write_bytes(pickle.dumps(scenario())[:200])
    with pytest.raises(ImportFormatError, match="not a readable pickle"):
        read_scenarionet(tmp_path / "trunc.pkl")


def test_a_directory_import_skips_bad_and_non_scenario_pickles(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "dataset"
    src.mkdir()
    dump(src / "sd_waymo_v1_a.pkl", scenario())
    dump(src / "sd_waymo_v1_b.pkl", scenario(objects_of_interest=None), protocol=2)
    bad = scenario()
    bad["metadata"]["payload"] = _Evil(tmp_path / "pwned")
    dump(src / "sd_waymo_v1_evil.pkl", bad)
    dump(src / "dataset_summary.pkl", {"sd_waymo_v1_a.pkl": {}})  # ScenarioNet's index, not a scenario
    out = tmp_path / "ds"
    assert main(["data", "import", "scenarionet", str(src), "--out", str(out), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "imported 2 scenarios from 2 of 3 files" in text
    assert "sd_waymo_v1_evil.pkl: pickle: refused to load" in text and not (tmp_path / "pwned").exists()
    assert sorted(s.scenario_id for s in Dataset.open(out).load()) == ["sd_waymo_v1_a-00", "sd_waymo_v1_b-00"]
