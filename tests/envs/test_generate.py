"""Base-scenario generation: valid scenarios per layout, determinism, resumable builds, argument errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from shapely.geometry import LineString

import seal.envs.generate as gen
from seal.core.dataset import Dataset, DatasetError
from seal.core.geometry import box_corners, box_gap
from seal.core.interaction import CONTEXT_M, EVENT_GAP_M
from seal.core.scenario import CURRENT_STEP, N_STEPS, Scenario
from seal.envs.generate import GenerationInterrupted, RunTask, assign_layouts, generate_dataset, simulate_run
from seal.envs.layouts import LAYOUTS, make_network
from seal.envs.network_topology import describe_network

SHARES = (0.7, 0.15, 0.15)
META_KEYS = {
    "layout",
    "run",
    "group",
    "t0_step",
    "pair_min_gap_m",
    "pair_collision",
    "any_collision",
    "ego_driver",
    "adv_driver",
    "seed",
}


def _build(path: Path, **kw) -> Dataset:
    args = {"n": 12, "seed": 1, "workers": 1, "progress": False} | kw
    return generate_dataset(path, **args)


@pytest.fixture(scope="module")
def base(tmp_path_factory: pytest.TempPathFactory) -> list[Scenario]:
    return _build(tmp_path_factory.mktemp("gen") / "base").load()


def _same(a: list[Scenario], b: list[Scenario]) -> bool:
    return len(a) == len(b) and all(
        x.scenario_id == y.scenario_id
        and np.array_equal(x.tracks, y.tracks)
        and np.array_equal(x.agent_ids, y.agent_ids)
        and x.ego_id == y.ego_id
        and x.adv_id == y.adv_id
        and dict(x.metadata) == dict(y.metadata)
        and x.road.to_json() == y.road.to_json()
        for x, y in zip(a, b, strict=True)
    )


def _pair_gaps(s: Scenario) -> np.ndarray:
    e, a = s.track(s.ego_id), s.track(s.adv_id)
    ce = box_corners(e[:, 0], e[:, 1], e[:, 2], e[:, 5], e[:, 6])
    ca = box_corners(a[:, 0], a[:, 1], a[:, 2], a[:, 5], a[:, 6])
    return box_gap(ce, ca)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_every_layout_gives_valid_interacting_scenarios(layout: str) -> None:
    scenarios = simulate_run(RunTask(run=3, layout=layout, seed=7, kind_shares=SHARES))
    assert 1 <= len(scenarios) <= gen.SCENARIOS_PER_RUN
    assert len({(s.ego_id, s.adv_id) for s in scenarios}) == len(scenarios)  # distinct pairs
    road = scenarios[0].road
    rebuilt = describe_network(make_network(road.layout, road.params), road.layout, road.params)
    assert rebuilt.to_json() == road.to_json()
    for k, s in enumerate(scenarios):
        assert s.scenario_id == f"{layout}-00003-{k:02d}" and s.source == "highway-env"
        assert set(s.metadata) == META_KEYS and json.loads(json.dumps(s.metadata)) == s.metadata
        assert s.metadata["layout"] == layout and s.metadata["seed"] == 7
        assert s.tracks.shape[1] == N_STEPS
        for agent in (s.ego_id, s.adv_id):
            t = s.track(agent)
            assert (t[:, 7] == 1).all()  # ego and adversary exist over the whole window
            speed = np.hypot(t[:, 3], t[:, 4])
            assert speed.mean() > 2.0 and np.hypot(*(t[-1, :2] - t[0, :2])) > 10.0
            np.testing.assert_allclose(np.hypot(t[:, 3], t[:, 4]) * np.cos(t[:, 2]), t[:, 3], atol=1e-4)
        gaps = _pair_gaps(s)[CURRENT_STEP:]
        assert float(gaps.min()) == pytest.approx(s.metadata["pair_min_gap_m"], abs=2e-3)
        e, a = s.track(s.ego_id)[CURRENT_STEP:, :2], s.track(s.adv_id)[CURRENT_STEP:, :2]
        assert gaps.min() < EVENT_GAP_M or LineString(e).intersects(LineString(a))
        assert s.metadata["pair_collision"] <= s.metadata["any_collision"]
        # Context agents come within CONTEXT_M of the ego or the adversary.
        for i in range(2, s.n_agents):
            valid = s.valid[i]
            d = [
                np.linalg.norm(s.tracks[i, valid, :2] - s.tracks[j, valid, :2], axis=1).min() for j in (0, 1)
            ]
            assert min(d) < CONTEXT_M


def test_same_seed_same_dataset_for_any_worker_count(base: list[Scenario], tmp_path: Path) -> None:
    assert len(base) == 12
    assert _same(base, _build(tmp_path / "w2", workers=2).load())


def test_other_seed_other_dataset(base: list[Scenario], tmp_path: Path) -> None:
    other = _build(tmp_path / "s2", seed=2).load()
    assert len(other) == 12
    assert not any(
        np.array_equal(x.tracks, y.tracks) for x in base for y in other if x.tracks.shape == y.tracks.shape
    )


def test_interrupted_build_resumes_to_the_same_dataset(
    base: list[Scenario], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "resume"
    with pytest.raises(GenerationInterrupted):
        _build(out, _stop_after_chunks=1)
    with pytest.raises(DatasetError, match="unfinished build"):
        Dataset.open(out)
    runs_done: list[int] = []
    real = gen.simulate_run
    monkeypatch.setattr(gen, "simulate_run", lambda task: runs_done.append(task.run) or real(task))
    resumed = _build(out).load()
    assert _same(base, resumed)
    assert min(runs_done) >= gen.runs_per_chunk(12)  # the finished chunk was not simulated again
    # Other arguments do not silently mix with the unfinished build; a finished one needs --overwrite.
    with pytest.raises(DatasetError, match="overwrite"):
        _build(out)


def test_manifest_provenance_and_balance(tmp_path: Path) -> None:
    ds = _build(tmp_path / "p", n=40, seed=3, layouts=("roundabout", "highway"), inattentive_share=0.2)
    prov = ds.manifest["provenance"]
    assert prov["seed"] == 3 and prov["layouts"] == ["highway", "roundabout"]
    assert prov["inattentive_share"] == 0.2 and prov["aggressive_share"] == 0.15
    assert {"highway_env", "numpy", "seal"} <= set(prov["versions"])
    assert "workers" not in prov["build_params"]
    counts = ds.manifest["counts"]["per_layout"]
    assert sum(counts.values()) == 40 and set(counts) == {"highway", "roundabout"}
    assert abs(counts["highway"] - counts["roundabout"]) <= gen.SCENARIOS_PER_RUN


def test_layout_assignment_balances_scenarios() -> None:
    layouts = ("highway", "merge", "intersection")
    plan = assign_layouts(layouts, dict.fromkeys(layouts, 0), dict.fromkeys(layouts, 0), 6)
    assert plan == ["highway", "merge", "intersection"] * 2
    # A layout that yields fewer scenarios per run gets more runs.
    plan = assign_layouts(
        layouts,
        {"highway": 50, "merge": 50, "intersection": 25},
        {"highway": 10, "merge": 10, "intersection": 10},
        8,
    )
    assert plan[:5] == ["intersection"] * 5 and plan.count("intersection") > plan.count("highway")


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"layouts": ("highway", "foo")}, r"--layouts: unknown layout 'foo'; choose from highway, merge"),
        ({"layouts": ()}, "--layouts"),
        ({"layouts": ("merge", "merge")}, "--layouts: duplicate"),
        ({"n": 0}, "--n"),
        ({"seed": -1}, "--seed"),
        ({"workers": 0}, "--workers"),
        ({"inattentive_share": 1.5}, "--inattentive-share"),
        ({"aggressive_share": -0.1}, "--aggressive-share"),
        ({"inattentive_share": 0.6, "aggressive_share": 0.6}, "at most 1"),
    ],
)
def test_bad_arguments_name_the_option(tmp_path: Path, kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        _build(tmp_path / "bad", **kwargs)
    assert not (tmp_path / "bad").exists()
