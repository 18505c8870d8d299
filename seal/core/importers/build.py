"""Scenarios from a recording: cut the windows and attach the provenance every importer records."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from seal.core.importers.tracks import AgentLog
from seal.core.importers.windows import MIN_FUTURE_STEPS, PairWindow, find_windows, window_tracks
from seal.core.road import RoadDescription
from seal.core.scenario import Scenario


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
) -> list[Scenario]:
    """Scenarios ``{id_prefix}-00``, ``-01``, ... of the windows `find_windows` picks (best first).

    Args:
        log, road: the recording and its road.
        id_prefix: scenario id prefix (unique per file).
        source: `Scenario.source`, e.g. ``"commonroad:FILE"``.
        metadata: provenance shared by the file's scenarios (must hold ``"layout"``).
        max_windows, min_future_steps, ego_row, adv_rows: see `find_windows`.
    """
    windows = find_windows(log, road, max_windows, min_future_steps, ego_row=ego_row, adv_rows=adv_rows)
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
    return out
