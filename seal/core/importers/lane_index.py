"""Which lane a point is on, and whether a path changes lane (used to rank and orient imported windows).

A move from one lane to another counts as a lane change unless the two are connected: pieces of the same recorded
lane (`seal.core.importers.lanes`), or of two recorded lanes one of which continues into the other.
"""

from __future__ import annotations

import numpy as np
import shapely

from seal.core.importers.lanes import chunked_lines, lane_of_piece
from seal.core.road import RoadDescription


class LaneIndex:
    """Nearest lane centre line of points on one road (an R-tree over short pieces of the centre lines: recorded
    maps can hold thousands of lanes)."""

    def __init__(self, road: RoadDescription) -> None:
        geoms, self._owner = chunked_lines([lane.centerline for lane in road.lanes])
        self._tree = shapely.STRtree(geoms)
        ids = [lane.lane_id for lane in road.lanes]
        # Connections between recorded lanes (pieces of one lane share a group), so a path through the pieces of
        # a lane and on into its successor never counts as a lane change, however sparse its points are.
        groups = sorted({lane_of_piece(i) for i in ids})
        gindex = {g: k for k, g in enumerate(groups)}
        group = np.array([gindex[lane_of_piece(i)] for i in ids])
        gconn = np.eye(len(groups), dtype=bool)
        for lane in road.lanes:
            for s in lane.successors:
                a, b = gindex[lane_of_piece(lane.lane_id)], gindex[lane_of_piece(s)]
                gconn[a, b] = gconn[b, a] = True
        self._connected = gconn[group[:, None], group[None, :]]

    def nearest(self, xy: np.ndarray) -> np.ndarray:
        """``[K]`` index (into ``road.lanes``) of the lane whose centre line is closest to each point ``[K, 2]``."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        out = np.empty(len(xy), dtype=np.int64)
        if len(xy):
            pts, chunks = self._tree.query_nearest(shapely.points(xy), all_matches=False)
            out[pts] = self._owner[chunks]
        return out

    def changes_lane(self, xy: np.ndarray) -> bool:
        """True when the path ``[K, 2]`` moves between two lanes that are not connected."""
        return self.changes_in(self.nearest(xy)) if len(xy) >= 2 else False

    def changes_in(self, lanes: np.ndarray) -> bool:
        """True when a sequence of lane indices (`nearest` of consecutive path points) holds a lane change."""
        lanes = np.asarray(lanes, dtype=np.int64)
        moves = lanes[1:] != lanes[:-1]
        return bool((~self._connected[lanes[:-1][moves], lanes[1:][moves]]).any())


class AgentLanes:
    """Nearest lane of every logged step of an agent, computed once per agent on first use (a recording's agents
    take part in many candidate pairs)."""

    def __init__(self, index: LaneIndex, xy: np.ndarray, valid: np.ndarray) -> None:
        self.index = index
        self._xy = xy
        self._valid = valid
        self._rows: dict[int, np.ndarray] = {}

    def changes_lane(self, row: int, steps: np.ndarray) -> bool:
        """Lane change of agent ``row`` over the (valid) recording ``steps``."""
        lanes = self._rows.get(row)
        if lanes is None:
            lanes = np.full(self._valid.shape[1], -1, dtype=np.int64)
            v = self._valid[row]
            lanes[v] = self.index.nearest(self._xy[row, v])
            self._rows[row] = lanes
        return self.index.changes_in(lanes[steps]) if len(steps) >= 2 else False
