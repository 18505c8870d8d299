"""ScenarioNet files as they really are: swapped nuScenes boxes, degenerate map features, a parked SDC, and the
pedestrians / cyclists that stay in the scenario as replayed agents (pickles built here in the documented format)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from scenario_factory import SN_T as T
from scenario_factory import dump_pickle as dump
from scenario_factory import scenarionet_scenario as scenario
from scenario_factory import sn_line as _line

from seal.cli import main
from seal.core.dataset import Dataset
from seal.core.importers import ImportFailed, import_files
from seal.core.importers.scenarionet import box_is_swapped, read_scenarionet
from seal.core.scenario import CURRENT_STEP, LENGTH, VALID, WIDTH, X, Y
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.replay_check import replay_check

NUSCENES_EGO = (1.73, 4.08)
"""(length, width) of a nuScenes ego as ScenarioNet's converter writes it: swapped (the car is 4.08 m long)."""


def nuscenes_swapped() -> dict:
    """The SDC's box arrives with length and width swapped; 600 (far away) is parked sideways-wide: no motion, so
    nothing can be decided about it."""
    data = scenario()
    data["metadata"]["dataset"] = "nuscenes"
    for key, value in zip(("length", "width"), NUSCENES_EGO, strict=True):
        data["tracks"]["100"]["state"][key][:] = value
    parked = data["tracks"]["600"]["state"]
    parked["position"][:, 0] = 200.0
    parked["velocity"][:] = 0.0
    parked["length"][:], parked["width"][:] = 1.5, 3.0
    return data


def waymo_single_point_lanes() -> dict:
    """Five lane features and one road line with a single point (or one point repeated) next to good ones."""
    data = scenario()
    for k in range(5):
        pts = np.array([[50.0 + k, 20.0, 0.0]] * (1 if k < 3 else 2))  # one point, or one point twice
        data["map_features"][f"9{k}"] = {"type": "LANE_SURFACE_STREET", "polyline": pts, "exit_lanes": []}
    data["map_features"]["95"] = {"type": "ROAD_LINE_SOLID_SINGLE_WHITE", "polyline": np.zeros((1, 3))}
    return data


def parked_sdc() -> dict:
    data = scenario()
    state = data["tracks"]["100"]["state"]
    state["position"][:, 0] = 0.0
    state["velocity"][:] = 0.0
    return data


def test_a_swapped_box_is_swapped_back_when_the_heading_follows_the_motion() -> None:
    t = np.arange(20) * 0.1
    pos = np.stack([10.0 * t, np.zeros_like(t)], axis=1)
    wide, narrow = np.full(20, 4.0), np.full(20, 1.8)
    valid = np.ones(20, dtype=bool)
    assert box_is_swapped("vehicle", t, pos, np.zeros(20), narrow, wide, valid)
    # Driving backwards along its heading is following the motion too.
    assert box_is_swapped("vehicle", t, pos[::-1].copy(), np.zeros(20), narrow, wide, valid)
    # Heading across the motion: the heading, not the box, may be wrong -> left alone.
    assert not box_is_swapped("vehicle", t, pos, np.full(20, np.pi / 2), narrow, wide, valid)
    # Standing still: no evidence; a long box; a pedestrian: nothing to repair.
    assert not box_is_swapped("vehicle", t, np.zeros((20, 2)), np.zeros(20), narrow, wide, valid)
    assert not box_is_swapped("vehicle", t, pos, np.zeros(20), wide, narrow, valid)
    assert not box_is_swapped("pedestrian", t, pos, np.zeros(20), narrow, wide, valid)


def test_the_nuscenes_ego_box_is_repaired_and_counted(tmp_path: Path) -> None:
    rec = read_scenarionet(dump(tmp_path / "nu.pkl", nuscenes_swapped()))
    ego = rec.log.tracks[rec.sdc_row]
    np.testing.assert_allclose(ego[:, [LENGTH, WIDTH]], [NUSCENES_EGO[::-1]] * T, atol=1e-6)
    far = rec.log.tracks[rec.log.source_ids.index("600")]
    np.testing.assert_allclose(far[0, [LENGTH, WIDTH]], [1.5, 3.0])  # parked: not decided, kept as recorded
    assert rec.repaired == {"swapped_boxes": 1}
    ds, report = import_files([tmp_path / "nu.pkl"], tmp_path / "ds", "scenarionet", progress=False)
    assert report["repaired"] == {"swapped_boxes": 1}
    assert report["per_file"][str(tmp_path / "nu.pkl")]["repaired"] == {"swapped_boxes": 1}
    assert replay_check(ds.load(), progress=False)["success_rate"] == 1.0


def test_degenerate_map_features_are_dropped_not_the_scenario(tmp_path: Path) -> None:
    rec = read_scenarionet(dump(tmp_path / "w.pkl", waymo_single_point_lanes()))
    assert rec.dropped["degenerate_map_features"] == 6
    assert {lane.lane_id for lane in rec.road.lanes} == {"1", "2", "3", "4"}
    ds, report = import_files([tmp_path / "w.pkl"], tmp_path / "ds", "scenarionet", progress=False)
    assert report["scenarios"] == 1 and report["dropped"]["degenerate_map_features"] == 6
    assert replay_check(ds.load(), progress=False)["success_rate"] == 1.0
    # Only degenerate lanes: the file is refused, saying why.
    data = waymo_single_point_lanes()
    data["map_features"] = {k: v for k, v in data["map_features"].items() if k.startswith("9")}
    with pytest.raises(ValueError, match="no lane centre lines .*6 degenerate feature"):
        read_scenarionet(dump(tmp_path / "only.pkl", data))


def test_a_parked_ego_is_reported_as_parked(tmp_path: Path) -> None:
    path = dump(tmp_path / "parked.pkl", parked_sdc())
    with pytest.raises(ImportFailed, match=r"parked.pkl: tracks\['100'\]: the self-driving car \(the ego\) is parked"):
        import_files([path], tmp_path / "ds", "scenarionet", progress=False)
    assert not (tmp_path / "ds").exists()


def test_replay_check_on_real_world_defects_reaches_95_percent(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """The Done-when set: a clean Waymo-like file, the swapped nuScenes box, the single-point lanes, the parked
    SDC (skipped, with its reason), through the CLI with --json."""
    src = tmp_path / "src"
    src.mkdir()
    dump(src / "sd_waymo_clean.pkl", scenario())
    dump(src / "sd_nuscenes_swapped.pkl", nuscenes_swapped())
    dump(src / "sd_waymo_single_point.pkl", waymo_single_point_lanes())
    dump(src / "sd_nuscenes_parked.pkl", parked_sdc())
    out = tmp_path / "ds"
    assert main(["data", "import", "scenarionet", str(src), "--out", str(out), "--no-progress", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert (report["files"], report["imported_files"], report["scenarios"]) == (4, 3, 3)
    assert report["repaired"] == {"swapped_boxes": 1}
    assert report["dropped"] == {"degenerate_map_features": 6}
    (skip,) = report["skipped"]
    assert skip["file"].endswith("sd_nuscenes_parked.pkl") and "is parked" in skip["reason"]
    result = replay_check(Dataset.open(out).load(), progress=False)
    assert result["success_rate"] >= 0.95 and result["success_rate"] == 1.0


def test_pedestrians_stay_as_replayed_agents_that_the_ego_senses_and_hits(tmp_path: Path) -> None:
    ds, _ = import_files([dump(tmp_path / "s.pkl", scenario())], tmp_path / "ds", "scenarionet", progress=False)
    (s,) = ds.load()
    ped = s.agent_ids.tolist().index(300)
    assert s.agent_types[ped] == "pedestrian"
    np.testing.assert_allclose(s.tracks[ped, :, [LENGTH, WIDTH]].T, [[0.5, 0.5]] * T, atol=1e-6)
    # Put the pedestrian on the ego's logged path, 6 m ahead, standing: the ego driven by its log runs into it.
    tracks = s.tracks.copy()
    ego = s.track(s.ego_id)
    tracks[ped, :, X] = ego[CURRENT_STEP, X] + 6.0
    tracks[ped, :, Y] = ego[CURRENT_STEP, Y]
    tracks[ped, :, VALID] = 1.0
    blocked = dataclasses.replace(s, scenario_id="blocked", tracks=tracks)
    result = replay_check([s, blocked], progress=False)
    rows = {r["scenario_id"]: r for r in result["rows"]}
    assert rows[s.scenario_id]["outcome"] == "success"
    assert rows["blocked"]["outcome"] == "crash" and rows["blocked"]["crash_agent_id"] == 300
    # ... and it sees the pedestrian coming: the observations with and without it differ.
    env = ScenarioEnv([s, blocked])
    seen = env.reset(options={"scenario_id": "blocked"})[0]
    unseen = env.reset(options={"scenario_id": s.scenario_id})[0]
    assert not np.allclose(seen, unseen)


def test_line_features_with_one_point_are_dropped_too(tmp_path: Path) -> None:
    data = scenario()
    data["map_features"]["10"]["polyline"] = _line(0.0)[:1]  # the broken line between lanes 1 and 2: one point
    rec = read_scenarionet(dump(tmp_path / "s.pkl", data))
    assert rec.dropped["degenerate_map_features"] == 1
    assert rec.road.lane("1").line_types[0] == "none"  # no paint found there any more
