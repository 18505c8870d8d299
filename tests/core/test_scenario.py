"""Scenario data model validation: every error names the scenario, the field and the agent."""

from __future__ import annotations

import numpy as np
import pytest

from seal.core.road import LaneSpec, RoadDescription, RoadError
from seal.core.scenario import CURRENT_STEP, HEADING, N_STEPS, VALID, Scenario, ScenarioError, X


def _road() -> RoadDescription:
    lane = LaneSpec("a:b:0", np.array([[0.0, 0.0], [300.0, 0.0]]), 4.0, ("continuous", "continuous"), 30.0)
    return RoadDescription("polylines", (lane,))


def _tracks(n_agents: int = 3) -> np.ndarray:
    tr = np.zeros((n_agents, N_STEPS, 8), np.float32)
    tr[:, :, X] = np.arange(N_STEPS) * 2.0 + 10.0 * np.arange(n_agents)[:, None]
    tr[:, :, 3] = 20.0
    tr[:, :, 5] = 5.0
    tr[:, :, 6] = 2.0
    tr[:, :, VALID] = 1.0
    return tr


def _make(tracks: np.ndarray | None = None, **kw) -> Scenario:
    args = dict(
        scenario_id="sc-1",
        tracks=_tracks() if tracks is None else tracks,
        agent_ids=[7, 8, 9],
        agent_types=["vehicle"] * 3,
        ego_id=7,
        adv_id=8,
        road=_road(),
    )
    args.update(kw)
    return Scenario(**args)


def test_valid_scenario_accessors() -> None:
    s = _make()
    assert s.n_agents == 3
    assert s.ego_index == 0 and s.adv_index == 1
    assert s.tracks.dtype == np.float32
    assert s.valid.all()
    np.testing.assert_allclose(s.track(9)[:, X], np.arange(N_STEPS) * 2.0 + 20.0)
    s2 = s.with_metadata(split="train")
    assert s2.metadata["split"] == "train" and "split" not in s.metadata


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda t: t.__setitem__((1, 40, X), np.nan), "field 'x' of agent 8 is NaN or inf at step 40"),
        (lambda t: t.__setitem__((2, 5, HEADING), np.inf), "field 'heading' of agent 9 is NaN or inf at step 5"),
        (lambda t: t[2, 30:35, VALID].__setitem__(slice(None), 0.0), "field 'valid' of agent 9 has a gap"),
        (lambda t: t.__setitem__((0, 3, 5), -1.0), "field 'length'/'width' of agent 7"),
        (lambda t: t.__setitem__((1, 3, VALID), 0.5), "field 'valid' of agent 8 must be 0 or 1"),
    ],
)
def test_bad_track_values_name_field_and_agent(mutate, expected: str) -> None:
    tr = _tracks()
    mutate(tr)
    with pytest.raises(ScenarioError, match="scenario 'sc-1'") as exc:
        _make(tr)
    assert expected in str(exc.value)


def test_nan_where_invalid_is_allowed() -> None:
    tr = _tracks()
    tr[2, 60:, VALID] = 0.0  # agent 9 leaves at step 60 ...
    tr[2, 60:, X] = np.nan  # ... and its values there are ignored
    assert _make(tr).valid[2].sum() == 60


def test_wrong_shapes_and_ids() -> None:
    with pytest.raises(ScenarioError, match=r"field 'tracks' must have shape \[A, 91, 8\]"):
        _make(_tracks()[:, :50])
    with pytest.raises(ScenarioError, match="field 'agent_ids' must have 3 entries"):
        _make(agent_ids=[1, 2])
    with pytest.raises(ScenarioError, match="field 'agent_ids' has duplicates"):
        _make(agent_ids=[1, 1, 2], ego_id=1, adv_id=2)
    with pytest.raises(ScenarioError, match="field 'adv_id' equals 'ego_id'"):
        _make(adv_id=7)
    with pytest.raises(ScenarioError, match="field 'ego_id' = 42 is not among 'agent_ids'"):
        _make(ego_id=42)
    with pytest.raises(ScenarioError, match="field 'agent_types' of agent 9 is 'tank'"):
        _make(agent_types=["vehicle", "vehicle", "tank"])


def test_ego_and_adv_must_exist_at_current_step() -> None:
    tr = _tracks()
    tr[1, : CURRENT_STEP + 1, VALID] = 0.0  # adversary appears only after the current step
    with pytest.raises(ScenarioError, match="agent 8 \\(adv_id\\) must be valid at the current step 10"):
        _make(tr)


def test_road_validation_names_lane_and_field() -> None:
    with pytest.raises(RoadError, match="lane 'x': field 'width_m'"):
        LaneSpec("x", np.array([[0.0, 0.0], [1.0, 0.0]]), -1.0)
    with pytest.raises(RoadError, match="lane 'x': field 'centerline'"):
        LaneSpec("x", np.array([[0.0, 0.0]]), 3.5)
    with pytest.raises(RoadError, match="lane 'x': field 'line_types'"):
        LaneSpec("x", np.array([[0.0, 0.0], [1.0, 0.0]]), 3.5, ("dotted", "none"))
    lane = LaneSpec("x", np.array([[0.0, 0.0], [1.0, 0.0]]), 3.5, successors=("nope",))
    with pytest.raises(RoadError, match="lane 'x' has unknown successors"):
        RoadDescription("polylines", (lane,))


def test_road_json_round_trip() -> None:
    road = _road()
    back = RoadDescription.from_json(road.to_json())
    assert back.to_json() == road.to_json()
    assert back.lanes[0].length_m == pytest.approx(300.0)
