"""score_dataset / load_scores / make_splits / write_report on a small hand-built dataset."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scoring_builders import following_scenario

from seal.core.dataset import Dataset, DatasetError, write_dataset
from seal.scoring.bench import run_scoring_bench
from seal.scoring.report import write_report
from seal.scoring.splits import SplitError, make_splits
from seal.scoring.store import load_scores, score_dataset


@pytest.fixture(scope="module")
def scored(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("scored") / "ds"
    rng = np.random.default_rng(0)
    # Two windows per group (traffic run), as a generated pool cuts several windows from one run.
    scenarios = [
        following_scenario(f"s{k:03d}", gap_m=float(rng.uniform(8.0, 60.0)), v_follow=float(rng.uniform(8, 25)),
                           v_lead=float(rng.uniform(8, 25)), n_extra=int(rng.integers(1, 4))
                           ).with_metadata(group=f"run{k // 2:02d}")
        for k in range(40)
    ]
    write_dataset(root, scenarios, shard_size=15)
    score_dataset(root, workers=1, progress=False)
    return root


def test_scores_stored_and_loadable(scored: Path) -> None:
    table = load_scores(scored)
    assert len(table) == 40
    assert table.scenario_ids[:2] == ["s000", "s001"]
    entry = json.loads((scored / "manifest.json").read_text())["scores"]
    assert entry["file"] == "scores.npz" and entry["n_scenarios"] == 40 and entry["primary"] == "ac"
    for v in ("gt", "fe", "as", "ac"):
        assert np.all(np.isfinite(table.scene(v))) and np.all(table.scene(v) > 0)
    assert np.all(table.scene("ac") >= table.scene("gt") - 1e-9)  # AC takes the max per trajectory, same weights
    k = 3
    rows = table.agents(k)
    assert table.arrays["focal"][rows].sum() == 2
    assert table.primitives.single_centres.shape[0] > 0


def _group_of_split(root: Path) -> dict[str, set[str]]:
    ds = Dataset.open(root)
    group = {s.scenario_id: s.metadata["group"] for s in ds.load()}
    return {name: {group[sid] for sid in ids} for name, ids in ds.splits.items()}


def test_scene_rule_splits_reproducible_disjoint_and_above_threshold(scored: Path) -> None:
    kw = dict(hard_quantile=0.8, n_train=16, n_eval=8, n_hard=5, seed=7, hard_by="scene")
    first = make_splits(scored, **kw)
    splits1 = Dataset.open(scored).splits
    make_splits(scored, **kw)
    assert Dataset.open(scored).splits == splits1
    train, evl, hard = (set(splits1[k]) for k in ("train", "eval", "hard"))
    assert (len(train), len(evl), len(hard)) == (16, 8, 5)
    assert not (train & evl) and not (train & hard) and not (evl & hard)
    table = load_scores(scored)
    score = dict(zip(table.scenario_ids, table.scene("ac"), strict=True))
    assert min(score[s] for s in hard) > first["threshold"] >= max(score[s] for s in train | evl)
    params = Dataset.open(scored).manifest["split_params"]
    assert params["seed"] == 7 and params["score"] == "ac" and params["hard_by"] == "scene"
    assert Dataset.open(scored).manifest["roles"] == {}  # the scene rule keeps the built roles
    make_splits(scored, **{**kw, "seed": 8})
    assert Dataset.open(scored).splits != splits1
    assert len(Dataset.open(scored).load("hard")) == 5


@pytest.mark.parametrize("hard_by", ["pair", "scene"])
def test_no_group_straddles_splits(scored: Path, hard_by: str) -> None:
    out = make_splits(scored, n_train=12, n_eval=6, n_hard=4, seed=3, hard_by=hard_by, hard_quantile=0.7)
    assert out["shared_groups"] == 0 and out["hard_by"] == hard_by
    groups = _group_of_split(scored)
    assert not (groups["train"] & groups["eval"]) and not (groups["train"] & groups["hard"])
    assert not (groups["eval"] & groups["hard"])
    assert out["groups"] == {name: len(groups[name]) for name in ("train", "eval", "hard")}
    assert Dataset.open(scored).manifest["split_params"]["shared_groups"] == 0
    # Two windows per group: 12 train scenes need at least 6 groups.
    assert out["groups"]["train"] >= 6
    assert set(out["close_calls"]["hard"]) == {"gt_close_call", "gt_collision", "ac_close_call", "ac_collision"}


def test_pair_rule_makes_the_higher_scoring_agent_the_ego(scored: Path) -> None:
    out = make_splits(scored, n_train=16, n_eval=8, n_hard=4, seed=5, hard_by="pair", hard_quantile=0.7)
    table = load_scores(scored)
    traj = table.arrays["traj_ac"]
    row = {sid: k for k, sid in enumerate(table.scenario_ids)}
    ds = Dataset.open(scored)
    hard = ds.load("hard")
    assert len(hard) == 4 and len(ds.manifest["roles"]) == 4
    for s in hard:
        rows = table.agents(row[s.scenario_id])
        score = dict(zip(table.arrays["agent_ids"][rows].tolist(), traj[rows].tolist(), strict=True))
        assert score[s.ego_id] >= score[s.adv_id]  # the higher-scoring agent drives
        assert min(score[s.ego_id], score[s.adv_id]) > out["threshold"]  # both in the top 20 %
    # The threshold is the quantile of all interacting agents' trajectory scores of the pool.
    focal = traj[table.arrays["focal"]].astype(np.float64)
    assert out["threshold"] == pytest.approx(float(np.quantile(focal, 0.7)))
    # following_scenario builds the follower as the ego; the lead scores lower or higher depending on speeds:
    swapped = [s for s in hard if s.metadata.get("roles_swapped")]
    assert out["roles_exchanged"] == len(swapped)
    assert all(s.ego_id == 1 for s in swapped) and all(s.ego_id == 0 for s in hard if s not in swapped)
    # Normal scenes keep their built roles.
    assert all(s.ego_id == 0 for s in ds.load("eval"))


def test_split_errors_name_the_option(scored: Path, tmp_path: Path) -> None:
    with pytest.raises(SplitError, match="--n-hard"):
        make_splits(scored, n_train=5, n_eval=5, n_hard=20)
    with pytest.raises(SplitError, match="--n-train"):
        make_splits(scored, n_train=40, n_eval=5, n_hard=2)
    with pytest.raises(SplitError, match="--n-eval"):
        make_splits(scored, n_train=2, n_eval=40, n_hard=2)
    bare = tmp_path / "bare"
    write_dataset(bare, [following_scenario("x", 20.0, 10.0, 10.0)])
    with pytest.raises(DatasetError, match="run `seal data score"):
        make_splits(bare)


def test_report_and_bench(scored: Path, tmp_path: Path) -> None:
    paths = write_report(scored, tmp_path / "report", n_scenes=2)
    names = [p.name for p in paths]
    assert "score_distributions.png" in names and "feature_correlation.png" in names
    assert sum(n.startswith("scene_top") for n in names) == 2
    assert sum(n.startswith("scene_median") for n in names) == 2
    for p in paths:
        assert p.exists() and p.stat().st_size > 0
        if p.suffix == ".png":
            assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    bench = run_scoring_bench(scored, workers=1, limit=10)
    assert bench["scenarios"] == bench["n_scenarios"] == 10 and bench["ms_per_scenario"] > 0
    assert bench["seconds"] >= bench["score_s"] > 0 and bench["cpu_s"] > 0


def test_process_pool_matches_serial(scored: Path) -> None:
    from seal.scoring.store import score_scenarios

    scenarios = Dataset.open(scored).load()[:30]
    prim = load_scores(scored).primitives
    serial = score_scenarios(scenarios, prim, workers=1)
    pooled = score_scenarios(scenarios, prim, workers=2)
    assert [r.scenario_id for r in pooled] == [s.scenario_id for s in scenarios]
    for a, b in zip(serial, pooled, strict=True):
        assert a.scene == b.scene


def test_corrupt_scores_file_is_named(scored: Path, tmp_path: Path) -> None:
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(scored, copy)
    (copy / "scores.npz").write_bytes(b"garbage")
    with pytest.raises(DatasetError, match="scores.npz is truncated or corrupt"):
        load_scores(copy)


def test_focal_ranking_and_option_errors(scored: Path) -> None:
    table = load_scores(scored)
    focal = table.focal_min("ac")
    k = 5
    rows = table.agents(k)
    expected = table.arrays["traj_ac"][rows][table.arrays["focal"][rows]].min()
    assert focal[k] == pytest.approx(float(expected))
    with pytest.raises(SplitError, match="--hard-by"):
        make_splits(scored, hard_by="focal")
    with pytest.raises(SplitError, match="--score"):
        make_splits(scored, score="xx")


def test_splits_of_one_recording_are_refused_with_the_option_to_change(tmp_path: Path) -> None:
    root = tmp_path / "one"
    one_run = [following_scenario(f"w{k}", 20.0 + k, 12.0, 10.0).with_metadata(group="run0") for k in range(8)]
    write_dataset(root, one_run)
    score_dataset(root, workers=1, progress=False)
    with pytest.raises(SplitError, match="groups .* never go to two splits"):
        make_splits(root, n_train=2, n_eval=2, n_hard=1, hard_by="scene", hard_quantile=0.5)


def test_a_pool_held_out_for_evaluation_only_has_no_train_split(scored: Path) -> None:
    """`seal data split --n-train 0`: eval and hard filled, train empty (a second pool to evaluate trained egos on
    scenarios from traffic runs they never saw)."""
    from seal.cli import main

    assert main(["data", "split", str(scored), "--n-train", "0", "--n-eval", "8", "--n-hard", "4",
                 "--hard-by", "scene", "--hard-quantile", "0.7"]) == 0
    splits = Dataset.open(scored).splits
    assert (len(splits["train"]), len(splits["eval"]), len(splits["hard"])) == (0, 8, 4)
    with pytest.raises(SystemExit):  # argparse: "--n-train must be >= 0, got -1"
        main(["data", "split", str(scored), "--n-train", "-1"])
