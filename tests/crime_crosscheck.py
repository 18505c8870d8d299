"""commonroad-crime 0.4.5 side of the following-measure cross-check (tests/scoring/test_following_crosscheck.py).

Imported only where commonroad-crime is installed (the ``crosscheck`` extra). A sample is one (follower i, leader j,
step t) of a recording where seal's `following_per_step` has i following j. For each, crime's measures with
ego = follower, other = leader: THW (s), TTC (s), HW (headway distance, m), ALongReq (required longitudinal
acceleration, m/s^2, <= 0: crime's DRAC), crime's same-lanelet test, and the path gap: both centres projected
on crime's reference path of the ego (its curvilinear frame), minus half of both lengths (m).

Definition differences, read in crime's source (they explain the disagreement the test measures):

1. THW: crime's is the time until the ego's front reaches where the leader's rear was at step t, taken from the
   recorded future (inf when not reached before the recording ends), rounded to 0.1 s. Ours: gap / follower speed.
2. HW: crime shifts the positions by half the lengths with a scalar added to the (x, y) vector: along a road
   heading at angle theta the bumper offsets become L/2 (cos theta + sin theta), not L/2. US-101 heads at about
   -41 deg: 0.10 L/2 instead of L/2, about 4.4 m more gap for two cars. Depends on the world frame.
3. TTC and ALongReq project speeds with cos of the lanelet's absolute orientation (not of the angle between vehicle
   and lane): on US-101 x 0.75. And the speed they project is hypot(velocity, velocity_y), where commonroad-io
   2024.3's ``ExtendedPMState.velocity_y`` is a property, velocity x sin(orientation), of a ``velocity`` that holds
   the speed (crime's own split into x / y parts is skipped because the attribute exists): v sqrt(1 + sin^2 h)
   for heading h, on US-101 x 1.19. Together x 0.90 on US-101; depends on the world frame, like 2.
4. TTC: constant-acceleration model (Jansson 2005, eq. 5.26), constant velocity only where |delta a| <= 0.1 m/s^2;
   the accelerations are finite differences of the speeds and the leader's enters without its sign. Ours:
   constant velocity. TTC takes its gap from HW (item 2).
5. ALongReq (crime's default mode 1): min(a_lead - v_rel^2 / (2 HW), 0), a_lead unsigned; v_rel^2 also where the
   gap opens. Ours: closing^2 / (2 gap), 0 where the gap opens.
6. Same lane: crime's occupancy shapes touch a common lanelet (or a predecessor / successor of one); ours: the
   centres' lanes are the same or connected and the headings within 45 deg.

Items 2 and 3 are why the recording is also evaluated turned so that its road runs along +x ("aligned" frame:
rotated about the origin by minus the mean lanelet direction, written out and read back with commonroad-io,
whose in-place rotation leaves stale lanelet and occupancy indexes).
"""

from __future__ import annotations

import functools
import logging
import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from commonroad.common.file_reader import CommonRoadFileReader
from commonroad.common.file_writer import CommonRoadFileWriter, OverwriteExistingFile
from commonroad.planning.planning_problem import PlanningProblemSet
from commonroad.scenario.scenario import Scenario
from commonroad_crime.data_structure.configuration import CriMeConfiguration
from commonroad_crime.measure.acceleration.a_long_req import ALongReq
from commonroad_crime.measure.distance.hw import HW
from commonroad_crime.measure.time.thw import THW
from commonroad_crime.measure.time.ttc import TTC
from commonroad_crime.utility import solver
from commonroad_crime.utility.general import check_in_same_lanelet

from seal.core.importers.commonroad import read_commonroad
from seal.scoring.frenet import RoadIndex
from seal.scoring.social import PAIR_DIST_M, following_per_step
from seal.scoring.tracks import from_tracks

CONST_VEL_DA = 0.1
"""crime's TTC uses constant velocity where |delta a| <= 0.1 m/s^2 (ttc.py)."""


def memoise_crime_smoothing() -> None:
    """Cache crime's lanelet smoothing (a pure B-spline fit that TTC and ALongReq redo for every sample: ~90 % of
    their time). Performance only: the same arrays come back."""
    if getattr(solver.smoothing_reference_path, "seal_memo", False):
        return
    original = solver.smoothing_reference_path

    @functools.lru_cache(maxsize=512)
    def cached(key: bytes, shape: tuple[int, ...], smooth: float, weight: float) -> np.ndarray:
        return original(np.frombuffer(key).reshape(shape), smooth, weight)

    def smoothing(path: np.ndarray, smooth_factor: float, weight_coefficient: float) -> np.ndarray:
        arr = np.ascontiguousarray(path, dtype=np.float64)
        return cached(arr.tobytes(), arr.shape, smooth_factor, weight_coefficient).copy()

    smoothing.seal_memo = True  # type: ignore[attr-defined]
    solver.smoothing_reference_path = smoothing


def load(path: Path, aligned_dir: Path | None) -> Scenario:
    """The recording as commonroad-io reads it; turned road-aligned (module docstring) when ``aligned_dir`` is set."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sce, _ = CommonRoadFileReader(str(path)).open(lanelet_assignment=True)
        if aligned_dir is None:
            return sce
        ends = [ll.center_vertices[-1] - ll.center_vertices[0] for ll in sce.lanelet_network.lanelets]
        dirs = [math.atan2(d[1], d[0]) for d in ends]
        sce.translate_rotate(np.zeros(2), -float(np.mean(dirs)))
        out = aligned_dir / path.name
        CommonRoadFileWriter(sce, PlanningProblemSet()).write_to_file(str(out), OverwriteExistingFile.ALWAYS)
        sce, _ = CommonRoadFileReader(str(out)).open(lanelet_assignment=True)
    return sce


def ours(path: Path) -> dict[str, np.ndarray]:
    """seal's following samples of a recording: ids, step and measures, one entry per (follower, leader, step)."""
    rec = read_commonroad(path)
    index = RoadIndex(rec.road)
    tracks = from_tracks(rec.log.tracks, index)
    n = tracks.n_agents
    I, J = np.nonzero(~np.eye(n, dtype=bool))
    st = following_per_step(tracks, tracks, I, J, index)
    r, t = np.nonzero(st.ok & st.j_leads)  # i follows j; (j, i) is the same pair seen from the leader
    p = st.rows[r]
    with np.errstate(divide="ignore"):
        return {
            "ego": rec.log.agent_ids[I[p]], "other": rec.log.agent_ids[J[p]], "step": t,
            "gap": st.gap[r, t], "thw": 1.0 / st.inv_thw[r, t], "ttc": 1.0 / st.inv_ttc[r, t], "drac": st.drac[r, t],
            "v_follow": st.v_follow[r, t], "v_lead": st.v_lead[r, t],
            "length_follow": tracks.length[I[p]], "length_lead": tracks.length[J[p]],
        }


def _safe(obj: Any, other: int, step: int, failures: dict[str, int]) -> float:
    """``obj.compute`` or NaN where crime raises (counted by measure and error)."""
    try:
        return float(obj.compute(other, step, verbose=False))
    except (TypeError, ValueError, IndexError, AttributeError) as exc:
        key = f"{type(obj).__name__}: {type(exc).__name__}: {str(exc)[:60]}"
        failures[key] = failures.get(key, 0) + 1
        return math.nan


def _lane_terms(ttc: TTC, step: int) -> tuple[float, float, float, float]:
    """Accelerations along the lanelet (m/s^2) of ego and other and the lanelet orientations (rad, [0, 2 pi)) at
    both, exactly as crime's TTC / ALongReq form them (both looked up on the ego's lanelet); NaN where crime finds
    none."""
    nan4 = (math.nan,) * 4
    ego, oth = ttc.ego_vehicle.state_at_time(step), ttc.other_vehicle.state_at_time(step)
    ids = ttc.sce.lanelet_network.find_lanelet_by_position([ego.position])[0]
    if not ids:
        return nan4
    lanelet = ttc.sce.lanelet_network.find_lanelet_by_id(ids[0])
    o_e = solver.compute_lanelet_width_orientation(lanelet, ego.position)[1]
    o_o = solver.compute_lanelet_width_orientation(lanelet, oth.position)[1]
    if o_e is None or o_o is None:
        return nan4
    a_e = np.sign(ego.acceleration) * math.hypot(ego.acceleration, ego.acceleration_y) * math.cos(o_e)
    return float(a_e), math.hypot(oth.acceleration, oth.acceleration_y) * math.cos(o_o), float(o_e), float(o_o)


def _path_gap(thw: THW, step: int) -> float:
    """Centre distance along crime's reference path of the ego minus half of both lengths (m); NaN off the path."""
    try:
        s_e = thw.clcs.convert_to_curvilinear_coords(*thw.ego_vehicle.state_at_time(step).position)[0]
        s_o = thw.clcs.convert_to_curvilinear_coords(*thw.other_vehicle.state_at_time(step).position)[0]
    except ValueError:
        return math.nan
    return s_o - s_e - 0.5 * (thw.ego_vehicle.obstacle_shape.length + thw.other_vehicle.obstacle_shape.length)


def crime_measures(sce: Scenario, samples: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, int]]:
    """crime's values at every sample of `ours` (arrays aligned with it) and its failures by kind; also crime's
    lanelet orientations (``dir_*``), accelerations along them (``a_*``, `_lane_terms`) and the vehicles' headings
    (``h_*``) in the scenario's frame."""
    memoise_crime_smoothing()
    logging.disable(logging.WARNING)  # crime logs every sample
    names = ("thw", "ttc", "hw", "a_req", "same", "path_gap", "a_ego", "a_other", "dir_ego", "dir_other")
    names += ("h_ego", "h_other")
    out = {k: np.full(samples["step"].size, np.nan) for k in names}
    failures: dict[str, int] = {}
    measures: tuple[Any, ...] = ()
    current = None
    try:
        for k, (ego, other, step) in enumerate(zip(samples["ego"], samples["other"], samples["step"], strict=True)):
            ego, other, step = int(ego), int(other), int(step)
            if ego != current:  # one set of measure objects per ego (each builds the ego's reference path)
                config = CriMeConfiguration()
                config.update(ego_id=ego, sce=sce)
                measures, current = (THW(config), TTC(config), HW(config), ALongReq(config)), ego
            for name, obj in zip(("thw", "ttc", "hw", "a_req"), measures, strict=True):
                out[name][k] = _safe(obj, other, step, failures)
            thw, ttc = measures[0], measures[1]
            out["same"][k] = check_in_same_lanelet(sce.lanelet_network, thw.ego_vehicle, thw.other_vehicle, step)
            out["path_gap"][k] = _path_gap(thw, step)
            out["h_ego"][k] = thw.ego_vehicle.state_at_time(step).orientation  # headings in this frame (rad)
            out["h_other"][k] = thw.other_vehicle.state_at_time(step).orientation
            if ttc.other_vehicle is not None and ttc.other_vehicle.obstacle_id == other:
                terms = _lane_terms(ttc, step)
                out["a_ego"][k], out["a_other"][k], out["dir_ego"][k], out["dir_other"][k] = terms
    finally:
        logging.disable(logging.NOTSET)
    return out, failures


def crime_only(path: Path, sce: Scenario, samples: dict[str, np.ndarray]) -> tuple[int, int]:
    """Samples crime counts as following that seal does not: (ego, other, step) within `PAIR_DIST_M` where crime's
    same-lanelet test holds and the other is ahead on the ego's reference path (0 <= HW < inf). Returns (how many,
    how many of them seal puts in different, unconnected lanes or in no lane)."""
    rec = read_commonroad(path)
    index = RoadIndex(rec.road)
    tracks = from_tracks(rec.log.tracks, index)
    ids = [int(x) for x in rec.log.agent_ids]
    ours_set = set(zip(samples["ego"].tolist(), samples["other"].tolist(), samples["step"].tolist(), strict=True))
    logging.disable(logging.WARNING)
    found = other_lane = 0
    try:
        for i, ego in enumerate(ids):
            config = CriMeConfiguration()
            config.update(ego_id=ego, sce=sce)
            hw = HW(config)
            for j, other in enumerate(ids):
                both = tracks.valid[i] & tracks.valid[j]
                near = both & (np.hypot(*(tracks.pos[i] - tracks.pos[j]).T) < PAIR_DIST_M)
                for step in np.flatnonzero(near).tolist():
                    if i == j or (ego, other, step) in ours_set:
                        continue
                    h = hw.compute(other, step, verbose=False)
                    if not (0.0 <= h < math.inf):
                        continue
                    if check_in_same_lanelet(sce.lanelet_network, hw.ego_vehicle, hw.other_vehicle, step):
                        found += 1
                        li, lj = tracks.lane[i, step], tracks.lane[j, step]
                        other_lane += int(li < 0 or lj < 0 or not index.connected[li, lj])
    finally:
        logging.disable(logging.NOTSET)
    return found, other_lane
