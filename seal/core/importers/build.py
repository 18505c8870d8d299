"""Scenarios from a recording: cut the windows and attach the provenance every importer records.

A window is kept only when its logged ego stays on the mapped road from the current step on (every box corner
inside the drivable area grown by `seal.core.road_area.OFFROAD_TOLERANCE_M`, the simulator's own test): a logged
ego that drives off the end of the mapped road, or starts beside it, cannot be replayed, and no ego trained on
the window could succeed. Such windows are counted (`FileImport.dropped`) and the next best window is used.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import shapely

from seal.core.geometry import track_corners
from seal.core.importers.tracks import AgentLog
from seal.core.importers.windows import MIN_FUTURE_STEPS, PairWindow, find_windows, window_tracks
from seal.core.road import RoadDescription
from seal.core.road_area import OFFROAD_TOLERANCE_M, drivable_area, lane_borders
from seal.core.scenario import CURRENT_STEP, VALID, Scenario

WINDOWS_EGO_OFF_ROAD = "windows_ego_leaves_mapped_road"
"""`FileImport.dropped` key: windows whose logged ego leaves the mapped road (module docstring)."""


@dataclass
class FileImport:
    """What one file gave: its scenarios and counts of what was repaired or dropped on the way, by reason.

    Attributes:
        scenarios: the scenarios cut from the file.
        repaired: reason -> count of things read in a corrected form (e.g. ``swapped_boxes``).
        dropped: reason -> count of things left out (e.g. ``degenerate_map_features``, `WINDOWS_EGO_OFF_ROAD`).
    """

    scenarios: list[Scenario]
    repaired: dict[str, int] = field(default_factory=dict)
    dropped: dict[str, int] = field(default_factory=dict)


def ego_on_road_test(road: RoadDescription) -> Callable[[np.ndarray], bool]:
    """Test of a window's ego rows ``[91, 8]``: every box corner of its valid steps from the current step on lies
    in the drivable area of ``road`` grown by `OFFROAD_TOLERANCE_M`. The area is built on the first call."""
    area: list[shapely.Geometry] = []

    def on_road(rows: np.ndarray) -> bool:
        if not area:
            grown = shapely.buffer(drivable_area(lane_borders(road)[2]), OFFROAD_TOLERANCE_M)
            shapely.prepare(grown)
            area.append(grown)
        future = rows[CURRENT_STEP:]
        corners = track_corners(future[future[:, VALID] > 0.5].astype(np.float64)).reshape(-1, 2)
        return bool(shapely.contains_xy(area[0], corners[:, 0], corners[:, 1]).all())

    return on_road


def window_metadata(log: AgentLog, w: PairWindow) -> dict[str, Any]:
    """JSON-serialisable facts about one window (keys shared with the generated pool where they mean the same)."""
    return {
        "t0_step": w.t0,
        "logged_steps": w.logged_steps,
        "pair_min_gap_m": round(w.min_gap_m, 3) if math.isfinite(w.min_gap_m) else None,
        "pair_min_gap_step": w.min_gap_step,
        "pair_conflict": w.conflict,
        "lane_change": w.lane_change,
        "pair_collision": w.pair_collision,
        "any_collision": w.any_collision,
        "ego_source_id": log.source_ids[w.ego],
        "adv_source_id": log.source_ids[w.adv],
    }


def scenarios_from_log(
    log: AgentLog,
    road: RoadDescription,
    id_prefix: str,
    source: str,
    metadata: Mapping[str, Any],
    max_windows: int,
    min_future_steps: int = MIN_FUTURE_STEPS,
    ego_row: int | None = None,
    adv_rows: tuple[int, ...] = (),
) -> tuple[list[Scenario], int]:
    """Scenarios ``{id_prefix}-00``, ``-01``, ... of the windows `find_windows` picks (best first), and the number
    of windows dropped because their logged ego leaves the mapped road (module docstring).

    Args:
        log, road: the recording and its road.
        id_prefix: scenario id prefix (unique per file).
        source: `Scenario.source`, e.g. ``"commonroad:FILE"``.
        metadata: provenance shared by the file's scenarios (must hold ``"layout"``).
        max_windows, min_future_steps, ego_row, adv_rows: see `find_windows`.
    """
    windows, off_road = find_windows(
        log, road, max_windows, min_future_steps, ego_row=ego_row, adv_rows=adv_rows, ego_ok=ego_on_road_test(road)
    )
    out = []
    for k, w in enumerate(windows):
        tracks, ids = window_tracks(log, w)
        rows = (w.ego, w.adv, *w.others)
        out.append(
            Scenario(
                scenario_id=f"{id_prefix}-{k:02d}",
                tracks=tracks,
                agent_ids=ids,
                agent_types=tuple(log.agent_types[r] for r in rows),
                ego_id=int(ids[0]),
                adv_id=int(ids[1]),
                road=road,
                source=source,
                # Every window of one recording is one group: splits keep a recording's windows together.
                metadata={"group": source, **metadata, **window_metadata(log, w)},
            )
        )
    return out, off_road
