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
    scenarios = [
        following_scenario(f"s{k:03d}", gap_m=float(rng.uniform(8.0, 60.0)), v_follow=float(rng.uniform(8, 25)),
                           v_lead=float(rng.uniform(8, 25)), n_extra=int(rng.integers(1, 4)))
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


def test_splits_reproducible_disjoint_and_above_threshold(scored: Path) -> None:
    kw = dict(hard_quantile=0.8, n_train=20, n_eval=10, n_hard=6, seed=7)
    first = make_splits(scored, **kw)
    splits1 = Dataset.open(scored).splits
    make_splits(scored, **kw)
    assert Dataset.open(scored).splits == splits1
    train, evl, hard = (set(splits1[k]) for k in ("train", "eval", "hard"))
    assert (len(train), len(evl), len(hard)) == (20, 10, 6)
    assert not (train & evl) and not (train & hard) and not (evl & hard)
    table = load_scores(scored)
    score = dict(zip(table.scenario_ids, table.scene("ac"), strict=True))
    assert min(score[s] for s in hard) > first["threshold"] >= max(score[s] for s in train | evl)
    params = Dataset.open(scored).manifest["split_params"]
    assert params["seed"] == 7 and params["variant"] == "ac"
    make_splits(scored, **{**kw, "seed": 8})
    assert Dataset.open(scored).splits != splits1
    assert len(Dataset.open(scored).load("hard")) == 6


def test_split_errors_name_the_option(scored: Path, tmp_path: Path) -> None:
    with pytest.raises(SplitError, match="--n-hard"):
        make_splits(scored, n_train=5, n_eval=5, n_hard=20)
    with pytest.raises(SplitError, match="--n-train"):
        make_splits(scored, n_train=40, n_eval=5, n_hard=2)
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
    assert bench["n_scenarios"] == 10 and bench["ms_per_scenario"] > 0


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


def test_focal_ranking(scored: Path) -> None:
    table = load_scores(scored)
    focal = table.focal_min("ac")
    k = 5
    rows = table.agents(k)
    expected = table.arrays["traj_ac"][rows][table.arrays["focal"][rows]].min()
    assert focal[k] == pytest.approx(float(expected))
    out = make_splits(scored, n_train=10, n_eval=5, n_hard=4, by="focal")
    assert out["params"]["by"] == "focal"
    with pytest.raises(SplitError, match="--by"):
        make_splits(scored, by="pair")
