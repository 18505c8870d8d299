"""Dataset store: round trip, atomic/resumable builds, corrupt and truncated shards."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from seal.core.dataset import (
    BUILD_STATE,
    MANIFEST,
    Dataset,
    DatasetBuilder,
    DatasetError,
    read_shard,
    summarize,
    write_dataset,
)
from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import N_STEPS, VALID, Scenario, X


def _scenario(i: int, n_agents: int = 4, layout: str = "highway") -> Scenario:
    rng = np.random.default_rng(i)
    tr = np.zeros((n_agents, N_STEPS, 8), np.float32)
    tr[:, :, X] = np.arange(N_STEPS) * 2.0 + rng.uniform(0, 100, size=(n_agents, 1))
    tr[:, :, 1] = rng.uniform(-4, 4, size=(n_agents, 1))
    tr[:, :, 3] = 20.0
    tr[:, :, 5:7] = (5.0, 2.0)
    tr[:, :, VALID] = 1.0
    tr[-1, 70:, VALID] = 0.0
    tr[-1, 70:, :VALID] = 0.0
    lane = LaneSpec(f"{layout}:0", np.array([[0.0, 0.0], [400.0, 0.0]]), 4.0)
    road = RoadDescription(layout, (lane,), params={"lanes": 1})
    return Scenario(
        f"s{i:04d}", tr, np.arange(n_agents) + 100, ["vehicle"] * n_agents, 100, 101, road,
        source="test", metadata={"layout": layout, "k": i},
    )


def test_round_trip_preserves_everything(tmp_path: Path) -> None:
    scenarios = [_scenario(i, n_agents=3 + i % 4, layout=("highway", "merge")[i % 2]) for i in range(25)]
    write_dataset(tmp_path / "ds", scenarios, provenance={"who": "test"}, shard_size=10)
    ds = Dataset.open(tmp_path / "ds")
    assert len(ds) == 25
    assert len(ds.manifest["shards"]) == 3
    assert ds.manifest["counts"]["per_layout"] == {"highway": 13, "merge": 12}
    assert ds.manifest["provenance"]["who"] == "test"
    loaded = ds.load()
    for a, b in zip(scenarios, loaded, strict=True):
        assert a.scenario_id == b.scenario_id
        np.testing.assert_array_equal(a.tracks, b.tracks)
        np.testing.assert_array_equal(a.agent_ids, b.agent_ids)
        assert (a.ego_id, a.adv_id, a.agent_types, a.source) == (b.ego_id, b.adv_id, b.agent_types, b.source)
        assert a.road.to_json() == b.road.to_json()
        assert dict(a.metadata) == dict(b.metadata)
    assert [s.scenario_id for s in ds.load(ids=["s0003", "s0017"])] == ["s0003", "s0017"]
    assert [s.scenario_id for s in ds.load(limit=12)] == [s.scenario_id for s in scenarios[:12]]


def test_read_shard_decodes_only_the_wanted_scenarios(tmp_path: Path) -> None:
    scenarios = [_scenario(i, n_agents=3 + i % 3) for i in range(8)]
    ds = write_dataset(tmp_path / "ds", scenarios, shard_size=8)
    entry = ds.manifest["shards"][0]
    picked = read_shard(ds.root / entry["file"], entry, wanted={"s0006", "s0001", "absent"})
    assert [s.scenario_id for s in picked] == ["s0001", "s0006"]  # shard order, unknown ids ignored
    np.testing.assert_array_equal(picked[1].tracks, scenarios[6].tracks)  # offsets of the skipped ones respected
    assert read_shard(ds.root / entry["file"], entry, wanted=set()) == []


def test_splits_recorded_in_manifest(tmp_path: Path) -> None:
    ds = write_dataset(tmp_path / "ds", [_scenario(i) for i in range(6)])
    ds.update_manifest(splits={"train": ["s0000", "s0002"], "eval": ["s0005"]})
    again = Dataset.open(tmp_path / "ds")
    assert [s.scenario_id for s in again.load("train")] == ["s0000", "s0002"]
    with pytest.raises(DatasetError, match="no split 'hard'"):
        again.load("hard")


def test_load_split_is_the_one_split_loader(tmp_path: Path) -> None:
    """`load_split`: a split name, all / None, all-but-eval (outside eval and hard), limits and clear errors."""
    from seal.core.dataset import ALL, ALL_BUT_EVAL, load_split

    ds = write_dataset(tmp_path / "ds", [_scenario(i) for i in range(6)])
    ds.update_manifest(splits={"train": ["s0000", "s0002"], "eval": ["s0005"], "hard": ["s0001"], "empty": []})
    ids = lambda scenarios: [s.scenario_id for s in scenarios]  # noqa: E731
    assert ids(load_split(tmp_path / "ds", "train")) == ["s0000", "s0002"]
    assert ids(load_split(tmp_path / "ds", "train", limit=1)) == ["s0000"]
    assert ids(load_split(tmp_path / "ds", None)) == ids(load_split(tmp_path / "ds", ALL)) == ids(ds.load())
    assert ids(load_split(tmp_path / "ds", ALL_BUT_EVAL)) == ["s0000", "s0002", "s0003", "s0004"]
    assert ids(load_split(tmp_path / "ds", ALL_BUT_EVAL, limit=2)) == ["s0000", "s0002"]
    with pytest.raises(ValueError, match=r"has no split 'nope' for the training scenarios; splits: \['empty'"):
        load_split(tmp_path / "ds", "nope", what="training")
    with pytest.raises(ValueError, match="no eval scenarios in split 'empty'"):
        load_split(tmp_path / "ds", "empty", what="eval")
    assert load_split(tmp_path / "ds", "empty", allow_empty=True) == []
    with pytest.raises(ValueError, match="no dataset given"):
        load_split(None, "train")
    ds.update_manifest(splits={"train": ["s0000"]})
    with pytest.raises(ValueError, match="no eval / hard split to leave out"):
        load_split(tmp_path / "ds", ALL_BUT_EVAL)


def test_truncated_shard_names_the_file(tmp_path: Path) -> None:
    write_dataset(tmp_path / "ds", [_scenario(i) for i in range(6)], shard_size=3)
    shard = tmp_path / "ds" / "shards" / "shard-00001.npz"
    shard.write_bytes(shard.read_bytes()[:500])
    with pytest.raises(DatasetError, match=r"shard-00001\.npz is truncated or corrupt"):
        Dataset.open(tmp_path / "ds").load()


def test_corrupt_shard_without_manifest_check_names_the_file(tmp_path: Path) -> None:
    write_dataset(tmp_path / "ds", [_scenario(i) for i in range(3)])
    shard = tmp_path / "ds" / "shards" / "shard-00000.npz"
    data = bytearray(shard.read_bytes())
    shard.write_bytes(bytes(data[: len(data) // 2]))
    with pytest.raises(DatasetError, match="shard-00000.npz is truncated or corrupt"):
        read_shard(shard)
    data[len(data) // 2] ^= 0xFF
    shard.write_bytes(bytes(data))
    with pytest.raises(DatasetError, match="shard-00000.npz is corrupt: its sha256"):
        Dataset.open(tmp_path / "ds").load()


def test_missing_or_bad_manifest(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="not a seal dataset"):
        Dataset.open(tmp_path)
    (tmp_path / MANIFEST).write_text("{not json")
    with pytest.raises(DatasetError, match="manifest.json is not valid JSON"):
        Dataset.open(tmp_path)
    (tmp_path / MANIFEST).write_text(json.dumps({"format": "seal-dataset"}))
    with pytest.raises(DatasetError, match="missing field"):
        Dataset.open(tmp_path)


def _edit_manifest(root: Path, edit) -> None:
    manifest = json.loads((root / MANIFEST).read_text())
    (root / MANIFEST).write_text(json.dumps(edit(manifest)))


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda m: 42, "expected a JSON object of manifest fields, got int"),
        (lambda m: {**m, "shards": m["shards"][1:]},
         r"counts.scenarios is 6 but the shards hold 3; the manifest is damaged"),
        (lambda m: {**m, "shards": []}, "field 'shards' must be a non-empty list"),
        (lambda m: {**m, "shards": [{k: v for k, v in e.items() if k != "sha256"} for e in m["shards"]]},
         r"shards\[0\] lacks field\(s\) \['sha256'\]"),
        (lambda m: {**m, "counts": {"scenarios": "six"}}, "field 'counts' must hold the integer 'scenarios'"),
    ],
)
def test_damaged_manifest_is_refused(tmp_path: Path, edit, message: str) -> None:
    """Counts are cross-checked against the shards: a lost shard entry no longer loads fewer scenarios silently."""
    write_dataset(tmp_path / "ds", [_scenario(i) for i in range(6)], shard_size=3)
    assert len(Dataset.open(tmp_path / "ds")) == 6
    _edit_manifest(tmp_path / "ds", edit)
    with pytest.raises(DatasetError, match=message):
        Dataset.open(tmp_path / "ds")


def test_interrupted_build_is_not_loadable_and_resumes(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    scenarios = [_scenario(i) for i in range(12)]
    params = {"n": 10, "seed": 3}

    builder = DatasetBuilder(root, params)
    builder.write_shard(0, scenarios[0:4])
    builder.write_shard(1, scenarios[4:8])
    # "Killed" here: a build state but no manifest.
    assert (root / BUILD_STATE).exists() and not (root / MANIFEST).exists()
    with pytest.raises(DatasetError, match="unfinished build"):
        Dataset.open(root)

    with pytest.raises(DatasetError, match="other parameters"):
        DatasetBuilder(root, {"n": 11, "seed": 3})

    resumed = DatasetBuilder(root, params)
    assert resumed.is_done(0) and resumed.is_done(1) and not resumed.is_done(2)
    assert resumed.n_done_scenarios == 8
    resumed.write_shard(2, scenarios[8:12])
    ds = resumed.finalize(10)
    assert not (root / BUILD_STATE).exists()
    assert len(ds) == 10
    assert [s.scenario_id for s in Dataset.open(root).load()] == [s.scenario_id for s in scenarios[:10]]

    with pytest.raises(DatasetError, match="already holds a finished dataset"):
        DatasetBuilder(root, params)


def test_summary_counts() -> None:
    info = summarize([_scenario(i, n_agents=3 + i % 2, layout=("highway", "roundabout")[i % 2]) for i in range(4)])
    assert info["per_layout"] == {"highway": 2, "roundabout": 2}
    assert info["agents_per_scenario"]["mean"] == pytest.approx(3.5)
    assert info["track_length_steps"]["max"] == N_STEPS
    assert info["track_length_steps"]["min"] == 70


def test_all_but_eval_leaves_out_every_window_of_a_held_out_group(tmp_path: Path) -> None:
    """A fit on `all-but-eval` must not see another window of a recording whose scene is held out."""
    from seal.core.dataset import ALL_BUT_EVAL, load_split

    scenarios = [_scenario(i).with_metadata(group=f"run{i // 2}") for i in range(6)]  # 3 groups of 2 windows
    ds = write_dataset(tmp_path / "ds", scenarios)
    ds.update_manifest(splits={"train": ["s0000", "s0001"], "eval": ["s0002"], "hard": ["s0005"]})
    assert [s.scenario_id for s in load_split(tmp_path / "ds", ALL_BUT_EVAL)] == ["s0000", "s0001"]


def test_safeshift_splits_drawn_before_groups_are_refused(tmp_path: Path) -> None:
    from seal.core.dataset import load_split

    ds = write_dataset(tmp_path / "ds", [_scenario(i) for i in range(3)])
    ds.update_manifest(splits={"train": ["s0000"], "eval": ["s0001"]}, split_params={"method": "safeshift"})
    with pytest.raises(ValueError, match="seal data split .* again"):
        load_split(tmp_path / "ds", "train")
    ds.update_manifest(split_params={"method": "safeshift", "shared_groups": 0})
    assert len(load_split(tmp_path / "ds", "train")) == 1


def test_roles_in_the_manifest_apply_to_every_load(tmp_path: Path) -> None:
    scenario = _scenario(0).with_metadata(ego_driver="careful", adv_driver="aggressive")
    ds = write_dataset(tmp_path / "ds", [scenario, _scenario(1)])
    ds.update_manifest(roles={"s0000": [101, 100]})
    swapped, plain = Dataset.open(tmp_path / "ds").load()
    assert (swapped.ego_id, swapped.adv_id) == (101, 100) and (plain.ego_id, plain.adv_id) == (100, 101)
    assert swapped.metadata["ego_driver"] == "aggressive" and swapped.metadata["adv_driver"] == "careful"
    assert swapped.metadata["roles_swapped"] is True
    np.testing.assert_array_equal(swapped.tracks, scenario.tracks)  # the tracks are untouched
    ds.update_manifest(roles={"s0000": [100, 999]})
    with pytest.raises(DatasetError, match="field 'roles' of scenario 's0000' is invalid"):
        Dataset.open(tmp_path / "ds").load()


def test_group_of_reads_or_derives_the_recording() -> None:
    from seal.core.scenario import GroupError, group_of

    assert group_of(_scenario(0).with_metadata(group="run7")) == "run7"
    generated = _scenario(0).with_metadata(run=12, seed=3)
    assert group_of(generated) == "test:seed3:run00012"
    imported = _scenario(0).with_metadata(source_file="a.xml")
    assert group_of(imported) == "test"
    with pytest.raises(GroupError, match="no 'group' in its metadata"):
        group_of(_scenario(0))
