"""pi_score core: the frame transform and features with analytic answers, predict / rank shapes and batching,
save / load, the ranking metrics, and the network learning a synthetic ranking (closer candidates score higher)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from seal.core.scenario import CURRENT_STEP, DT_S
from seal.models.objective import (
    FEATURE_NAMES,
    LabelSet,
    ObjectiveConfig,
    ObjectiveFileError,
    ObjectiveModel,
    ObjectiveTrainConfig,
    align_ego_rollouts,
    pair_features,
    train_objective,
)
from seal.models.objective.features import to_frame
from seal.models.objective.metrics import (
    average_ranks,
    crash_chosen_when_any,
    near_tie_share,
    ranking_report,
    spearman,
    top1_in_topk,
)
from seal.scoring.criticality import f_coll

F = {name: i for i, name in enumerate(FEATURE_NAMES)}
T = 80


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/models/conftest.py


def _t(a: np.ndarray, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    return torch.as_tensor(a, dtype=dtype)


def test_to_frame_rotates_world_vectors_into_the_heading_frame() -> None:
    along, left = to_frame(_t([1.0, 0.0, 3.0]), _t([0.0, 1.0, 4.0]), _t([math.pi / 2] * 3))
    np.testing.assert_allclose(along.numpy(), [0.0, 1.0, 4.0], atol=1e-12)
    np.testing.assert_allclose(left.numpy(), [-1.0, 0.0, -3.0], atol=1e-12)


def test_pair_features_have_the_analytic_values() -> None:
    # Candidate drives north (+y) at 10 m/s along x = 10; the ego moves at (5, 10) m/s (heading east), starting 5 m
    # north of it.
    steps = np.arange(4) * DT_S
    cand_xy = np.stack([np.full(4, 10.0), 10.0 * steps], axis=-1)
    ego_xy = np.stack([10.0 + 5.0 * steps, 10.0 * steps + 5.0], axis=-1)
    cand_h, ego_h = np.full(4, math.pi / 2), np.zeros(4)
    valid = np.array([True, True, True, False])
    f = pair_features(_t(cand_xy), _t(cand_h), _t(ego_xy), _t(ego_h), _t(valid, torch.bool)).numpy()
    assert f.shape == (4, len(FEATURE_NAMES))
    t = 2  # ego - cand = (1, 5) world: 5 m ahead of the candidate, 1 m to its right.
    dist = math.hypot(1.0, 5.0)
    assert f[t, F["ego_x_in_adv"]] == pytest.approx(5.0 / 20)
    assert f[t, F["ego_y_in_adv"]] == pytest.approx(-1.0 / 20)
    assert f[t, F["distance"]] == pytest.approx(dist / 20)
    assert f[t, F["closeness"]] == pytest.approx(math.exp(-dist / 8))
    assert f[t, F["cos_rel_heading"]] == pytest.approx(0.0, abs=1e-12)
    assert f[t, F["sin_rel_heading"]] == pytest.approx(-1.0)
    # The candidate seen from the ego (heading east): 1 m behind, 5 m to its right.
    assert f[t, F["adv_x_in_ego"]] == pytest.approx(-1.0 / 20)
    assert f[t, F["adv_y_in_ego"]] == pytest.approx(-5.0 / 20)
    # Velocities: ego (5, 10), candidate (0, 10); relative (5, 0) world -> 0 along, -5 left of the candidate.
    assert f[t, F["rel_vx_in_adv"]] == pytest.approx(0.0, abs=1e-9)
    assert f[t, F["rel_vy_in_adv"]] == pytest.approx(-0.5)
    assert f[t, F["adv_speed"]] == pytest.approx(1.0)
    assert f[t, F["ego_speed"]] == pytest.approx(math.hypot(5.0, 10.0) / 10)
    assert f[t, F["valid"]] == 1.0 and f[t, F["time"]] == pytest.approx(2 / 3)
    # An invalid step: every feature zero except the time.
    assert np.all(f[3, : F["valid"] + 1] == 0.0) and f[3, F["time"]] == 1.0


def test_pair_features_broadcast_over_rollouts_and_candidates() -> None:
    rng = np.random.default_rng(0)
    cand = rng.normal(size=(3, T, 2))
    ego = rng.normal(size=(2, T, 2))
    ch, eh = rng.normal(size=(3, T)), rng.normal(size=(2, T))
    ev = rng.random((2, T)) > 0.2
    grid = pair_features(_t(cand)[None], _t(ch)[None], _t(ego)[:, None], _t(eh)[:, None], _t(ev, torch.bool)[:, None])
    assert grid.shape == (2, 3, T, len(FEATURE_NAMES))
    one = pair_features(_t(cand[2]), _t(ch[2]), _t(ego[1]), _t(eh[1]), _t(ev[1], torch.bool))
    torch.testing.assert_close(grid[1, 2], one)


def test_align_ego_rollouts_cuts_to_the_candidate_steps_and_pads_invalid() -> None:
    k, t_s = 2, CURRENT_STEP + 1 + 50  # roll-outs shorter than the 80 candidate steps
    xy = np.arange(k * t_s * 2, dtype=float).reshape(k, t_s, 2)
    heading = np.arange(k * t_s, dtype=float).reshape(k, t_s)
    valid = np.ones((k, t_s), dtype=bool)
    axy, ah, av = align_ego_rollouts(xy, heading, valid)
    assert axy.shape == (k, 80, 2) and ah.shape == (k, 80) and av.shape == (k, 80)
    np.testing.assert_array_equal(axy[:, :50], xy[:, CURRENT_STEP + 1 :])
    np.testing.assert_array_equal(ah[:, 0], heading[:, CURRENT_STEP + 1])
    assert av[:, :50].all() and not av[:, 50:].any()


def _tracks(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    start = rng.normal(size=(n, 1, 2)) * 15
    vel = rng.normal(size=(n, 1, 2)) * 5
    xy = start + vel * DT_S * np.arange(T)[None, :, None]
    return xy, np.broadcast_to(np.arctan2(vel[..., 1], vel[..., 0]), (n, T)).copy()


def test_predict_and_rank_shapes_and_batching_consistency() -> None:
    torch.manual_seed(0)
    model = ObjectiveModel(ObjectiveConfig())
    rng = np.random.default_rng(1)
    cand_xy, cand_h = _tracks(rng, 7)
    ego_xy, ego_h = _tracks(rng, 3)
    ego_v = np.ones((3, T), dtype=bool)
    ego_v[1, 40:] = False
    pred = model.predict(cand_xy, cand_h, ego_xy, ego_h, ego_v)
    assert pred.shape == (3, 7, 2) and np.all((pred >= 0) & (pred <= 1))
    rank = model.rank(cand_xy, cand_h, ego_xy, ego_h, ego_v)
    assert rank.shape == (7,)
    np.testing.assert_allclose(rank, pred.sum(-1).mean(0), rtol=1e-6)
    # One candidate and one roll-out at a time gives the same numbers as the batch.
    singles = np.array([model.rank(cand_xy[j : j + 1], cand_h[j : j + 1], ego_xy, ego_h, ego_v)[0] for j in range(7)])
    np.testing.assert_allclose(singles, rank, rtol=1e-5, atol=1e-6)
    for i in range(3):
        np.testing.assert_allclose(
            model.predict(cand_xy, cand_h, ego_xy[i : i + 1], ego_h[i : i + 1], ego_v[i : i + 1])[0], pred[i],
            rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="trained on 80"):
        model.rank(cand_xy[:, :40], cand_h[:, :40], ego_xy[:, :40], ego_h[:, :40], ego_v[:, :40])
    with pytest.raises(ValueError, match=r"cand_xy \[N, T, 2\]"):
        model.rank(cand_xy, cand_h, ego_xy[:, :50], ego_h, ego_v)


def test_save_load_round_trip_and_errors(tmp_path) -> None:
    torch.manual_seed(0)
    model = ObjectiveModel(ObjectiveConfig(hidden=16, stride=4), info={"note": "x"})
    rng = np.random.default_rng(2)
    cand_xy, cand_h = _tracks(rng, 4)
    ego_xy, ego_h = _tracks(rng, 2)
    ego_v = np.ones((2, T), dtype=bool)
    path = tmp_path / "objective.pt"
    model.save(path)
    assert (tmp_path / "objective.json").is_file()
    loaded = ObjectiveModel.load(path)
    assert loaded.config == model.config and loaded.info == {"note": "x"}
    np.testing.assert_array_equal(loaded.rank(cand_xy, cand_h, ego_xy, ego_h, ego_v),
                                  model.rank(cand_xy, cand_h, ego_xy, ego_h, ego_v))
    with pytest.raises(FileNotFoundError, match="seal fit objective"):
        ObjectiveModel.load(tmp_path / "missing.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a model")
    with pytest.raises(ObjectiveFileError, match="bad.pt"):
        ObjectiveModel.load(bad)
    torch.save({"format": "something-else"}, tmp_path / "other.pt")
    with pytest.raises(ObjectiveFileError, match="other.pt.*format"):
        ObjectiveModel.load(tmp_path / "other.pt")


def test_ranking_metrics_on_known_cases() -> None:
    np.testing.assert_array_equal(average_ranks(np.array([3.0, 1.0, 3.0, 2.0])), [2.5, 0.0, 2.5, 1.0])
    target = np.array([[0.1, 0.5, 0.9, 0.3], [0.1, 0.5, 0.9, 0.3]])
    score = np.array([[1.0, 2.0, 3.0, 1.5], [3.0, 2.0, 1.0, 2.5]])  # same order / reversed
    np.testing.assert_allclose(spearman(score, target), [1.0, -1.0])
    assert spearman(np.ones(4), target[0]) == 0.0
    np.testing.assert_array_equal(top1_in_topk(score, target, k=3), [True, False])
    rep = ranking_report(score, target)
    assert rep["spearman_mean"] == 0.0 and rep["top1_in_top3"] == 0.5 and rep["chosen_target_mean"] == 0.5
    assert "crash_chosen_when_any" not in rep


def test_crash_selection_and_near_ties_by_hand() -> None:
    # Row 0 picks its crash, row 1 misses the one it has, row 2 has none (left out): 1 of 2.
    score = np.array([[1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [1.0, 1.0, 0.0]])
    crashed = np.array([[0, 0, 1], [0, 1, 0], [0, 0, 0]], dtype=bool)
    assert crash_chosen_when_any(score, crashed) == 0.5
    assert np.isnan(crash_chosen_when_any(score, np.zeros_like(crashed)))
    assert ranking_report(score, score, crashed=crashed)["crash_chosen_when_any"] == 0.5
    # 4 candidates = 6 pairs; only (0, 0.005) is within 0.01; a second scenario of equal targets: 6 of 6.
    assert near_tie_share(np.array([[0.0, 0.005, 0.5, 1.0]])) == pytest.approx(1 / 6)
    assert near_tie_share(np.array([[0.0, 0.005, 0.5, 1.0], [0.3, 0.3, 0.3, 0.3]])) == pytest.approx(7 / 12)
    assert near_tie_share(np.array([[0.0, 0.005, 0.5, 1.0]]), tolerance=0.001) == 0.0


def _synthetic_labels(rng: np.random.Generator, n_scenarios: int, n_cand: int = 12) -> LabelSet:
    """Ego along +x at 10 m/s; candidates drive +x too, at random lateral offsets, head starts and speeds. Labels:
    f_coll = closeness of candidate and ego (what a non-reactive ego gives); f_diff = the candidate's speed scaled
    to [0, 1] when it drives in the ego's lane (|lateral offset| < 5 m), else 0. Their sum ranks candidates
    differently from plain closeness (Spearman ~0.65), so the network has to learn it."""
    time = DT_S * np.arange(T)
    m = n_cand + 1
    ego_xy = np.zeros((n_scenarios, m, T, 2))
    ego_xy[..., 0] = 10.0 * time
    lateral = rng.uniform(-15, 15, size=(n_scenarios, n_cand, 1))
    head = rng.uniform(-30, 40, size=(n_scenarios, n_cand, 1))
    speed = rng.uniform(6, 14, size=(n_scenarios, n_cand, 1))
    cand_xy = np.stack([head + speed * time, np.broadcast_to(lateral, (n_scenarios, n_cand, T))], axis=-1)
    coll = f_coll(ego_xy[:, :1], cand_xy)
    in_lane = (np.abs(lateral[..., 0]) < 5.0) * (speed[..., 0] - 6.0) / 8.0
    diff = np.broadcast_to(in_lane[:, None], (n_scenarios, m, n_cand))
    return LabelSet(
        scenario_ids=np.array([f"s{i}" for i in range(n_scenarios)]),
        cand_xy=cand_xy.astype(np.float32), cand_heading=np.zeros((n_scenarios, n_cand, T), np.float32),
        probs=np.full((n_scenarios, n_cand), 1 / n_cand, np.float32),
        ego_xy=ego_xy.astype(np.float32), ego_heading=np.zeros((n_scenarios, m, T), np.float32),
        ego_valid=np.ones((n_scenarios, m, T), dtype=bool), f_coll=coll.astype(np.float32),
        f_diff=diff.astype(np.float32), crashed=np.zeros((n_scenarios, n_cand), dtype=bool),
        cat_score=np.zeros((n_scenarios, n_cand), np.float32),
        adv_xy=np.zeros((n_scenarios, m, T, 2), np.float32), adv_valid=np.zeros((n_scenarios, m, T), dtype=bool),
        sizes_m=np.tile(np.float32([[5.0, 2.0]]), (n_scenarios, 2, 1)),
    )


def _ranks(model: ObjectiveModel, labels: LabelSet) -> np.ndarray:
    return np.stack([
        model.rank(labels.cand_xy[s], labels.cand_heading[s], labels.ego_xy[s, :1], labels.ego_heading[s, :1],
                   labels.ego_valid[s, :1])
        for s in range(labels.n_scenarios)
    ])


def test_network_learns_a_synthetic_ranking_closer_candidates_score_higher() -> None:
    rng = np.random.default_rng(0)
    train = _synthetic_labels(rng, 60)
    held_out = _synthetic_labels(rng, 20)
    target = held_out.f_coll + held_out.f_diff[:, 0]
    # 54 training scenarios x 12 candidates = 648 pairs (logged previous roll-out only): ~11 steps per epoch.
    cfg = ObjectiveTrainConfig(batch_size=64, lr=3e-3, max_epochs=30, pairs_per_epoch=4000, patience=30,
                               max_minutes=1.0, prev="logged", seed=0)
    model, fit = train_objective(train, ObjectiveConfig(hidden=32), cfg)
    rho = spearman(_ranks(model, held_out), target)
    assert rho.mean() > 0.8
    assert top1_in_topk(_ranks(model, held_out), target, k=3).mean() >= 0.75
    # Neither an untrained network (whose f_coll is the closeness) nor closeness alone ranks this well.
    torch.manual_seed(1)
    untrained = spearman(_ranks(ObjectiveModel(ObjectiveConfig(hidden=32)), held_out), target).mean()
    closeness = spearman(held_out.f_coll, target).mean()
    assert rho.mean() > max(untrained, closeness) + 0.1


def test_closest_step_takes_the_features_at_the_smallest_valid_distance() -> None:
    from seal.models.objective.network import DISTANCE_FEATURE, VALID_FEATURE, closest_step

    feats = torch.zeros(2, 5, len(FEATURE_NAMES))
    feats[..., VALID_FEATURE] = 1.0
    feats[0, :, DISTANCE_FEATURE] = torch.tensor([3.0, 2.0, 0.5, 1.0, 4.0])
    feats[1, :, DISTANCE_FEATURE] = torch.tensor([3.0, 0.1, 2.0, 1.0, 4.0])
    feats[1, 1, VALID_FEATURE] = 0.0  # the smallest distance of pair 1 is at an invalid step: skipped
    feats[..., F["time"]] = torch.arange(5.0)
    out = closest_step(feats)
    assert out.shape == (2, len(FEATURE_NAMES))
    assert out[0, F["time"]] == 2.0 and out[1, F["time"]] == 3.0 and out[1, DISTANCE_FEATURE] == 1.0


def test_listnet_loss_is_zero_for_the_right_order_and_larger_for_the_wrong_one() -> None:
    from seal.models.objective.losses import listnet_loss

    target = torch.tensor([[0.1, 0.0], [0.9, 0.5], [0.4, 0.0], [0.2, 1.0]])  # sums 0.1, 1.4, 0.4, 1.2
    assert float(listnet_loss(target, target, 4, 0.1)) == pytest.approx(0.0, abs=1e-6)
    reversed_ = torch.tensor([[1.5, 0.0], [0.0, 0.0], [1.0, 0.0], [0.2, 0.0]])
    assert float(listnet_loss(reversed_, target, 4, 0.1)) > 1.0
    # Two groups of two: the loss averages over groups.
    two = listnet_loss(reversed_, target, 2, 0.1)
    one = [listnet_loss(reversed_[g : g + 2], target[g : g + 2], 2, 0.1) for g in (0, 2)]
    assert float(two) == pytest.approx(float(sum(one)) / 2)


def test_mirrored_batches_keep_the_labels_and_mirror_the_tracks() -> None:
    from seal.models.objective.train import PairTensors

    labels = _synthetic_labels(np.random.default_rng(3), 2, n_cand=3)
    tensors = PairTensors(labels)
    torch.manual_seed(0)
    net = ObjectiveModel(ObjectiveConfig(hidden=8)).net
    idx = tensors.pairs(np.array([0, 1]), "logged")
    assert idx.shape == (6, 3) and list(idx[:3, 2]) == [0, 1, 2]  # a group's candidates are consecutive
    flip = np.array([True, False] * 3)
    with torch.inference_mode():
        pred, target = tensors.batch(net, idx, flip)
        plain, plain_target = tensors.batch(net, idx)
        s, i, j = idx[0]
        mirror = torch.tensor([1.0, -1.0])
        by_hand = net.score_pairs(tensors.cand_xy[s, j] * mirror, -tensors.cand_heading[s, j],
                                  tensors.ego_xy[s, i] * mirror, -tensors.ego_heading[s, i], tensors.ego_valid[s, i])
    torch.testing.assert_close(target, plain_target)
    torch.testing.assert_close(pred[0], by_hand)
    torch.testing.assert_close(pred[1::2], plain[1::2])


def test_config_from_dict_casts_types_and_rejects_bad_values() -> None:
    cfg = ObjectiveConfig.from_dict({"hidden": "16", "dropout": "0.25", "diff_on_closeness": 0})
    assert cfg.hidden == 16 and cfg.dropout == 0.25 and cfg.diff_on_closeness is False
    with pytest.raises(ValueError, match="dropout"):
        ObjectiveConfig(dropout=1.0)
    with pytest.raises(ValueError, match="unknown key"):
        ObjectiveConfig.from_dict({"width": 3})
    with pytest.raises(ValueError, match="select"):
        ObjectiveTrainConfig(select="loss")
    with pytest.raises(ValueError, match="rank_weight"):
        ObjectiveTrainConfig(rank_weight=-1.0)


def test_selection_on_validation_spearman_and_correction_penalty_keeps_closeness_order() -> None:
    rng = np.random.default_rng(4)
    train = _synthetic_labels(rng, 20)
    held_out = _synthetic_labels(rng, 10)
    cfg = ObjectiveTrainConfig(batch_size=48, lr=3e-3, max_epochs=3, pairs_per_epoch=480, patience=3,
                               max_minutes=1.0, prev="logged", correction_l2=100.0, rank_weight=0.5, mirror=True,
                               seed=0)
    model, fit = train_objective(train, ObjectiveConfig(hidden=8), cfg)
    rhos = [row["val_spearman"] for row in fit.history]
    assert len(rhos) == 3 and fit.best_epoch == int(np.argmax(rhos)) and fit.best_val_spearman == max(rhos)
    assert model.info["fit"]["best_val_spearman"] == fit.best_val_spearman
    # A heavy penalty on the corrections leaves both heads monotone in closeness: same order as closeness.
    pred = np.stack([
        model.predict(held_out.cand_xy[s], held_out.cand_heading[s], held_out.ego_xy[s, :1],
                      held_out.ego_heading[s, :1], held_out.ego_valid[s, :1])[0]
        for s in range(held_out.n_scenarios)
    ])
    assert spearman(pred[..., 0], held_out.f_coll).mean() > 0.95


def test_fit_records_training_spearman_and_the_closeness_baseline_on_validation() -> None:
    from seal.models.objective.train import _split, closeness_spearman

    rng = np.random.default_rng(5)
    labels = _synthetic_labels(rng, 20)
    cfg = ObjectiveTrainConfig(batch_size=48, lr=3e-3, max_epochs=2, pairs_per_epoch=480, patience=3,
                               max_minutes=1.0, prev="logged", seed=0)
    data = _split(labels, cfg, np.random.default_rng(cfg.seed))
    check_s = np.unique(data.train_check_pairs[:, 0])
    # As many training scenarios as validation ones, none of them a validation scenario.
    assert len(check_s) == len(data.val_s) == 2 and set(check_s) <= set(data.train_s)
    # Closeness's Spearman on the logged-roll-out groups of the validation scenarios, by hand.
    val_s = data.val_s
    close = f_coll(labels.ego_xy[val_s, :1], labels.cand_xy[val_s])
    by_hand = spearman(close, labels.f_coll[val_s] + labels.f_diff[val_s, 0]).mean()
    assert closeness_spearman(labels, data.val_pairs) == pytest.approx(by_hand, abs=1e-9)
    # f_coll is exactly closeness here: the baseline is below 1 only through f_diff, and not constant.
    assert 0.3 < by_hand < 0.99
    model, fit = train_objective(labels, ObjectiveConfig(hidden=8), cfg)
    assert fit.val_closeness_spearman == pytest.approx(by_hand, abs=1e-9)
    assert model.info["fit"]["val_closeness_spearman"] == fit.val_closeness_spearman
    assert fit.train_closeness_spearman == pytest.approx(closeness_spearman(labels, data.train_check_pairs), abs=1e-9)
    assert fit.train_closeness_spearman != fit.val_closeness_spearman
    for row in fit.history:
        assert -1.0 <= row["train_spearman"] <= 1.0 and row["train_spearman"] != row["val_spearman"]


def test_the_training_budget_can_be_switched_off_but_not_set_to_nothing() -> None:
    assert ObjectiveTrainConfig(max_minutes=None).max_minutes is None
    with pytest.raises(ValueError, match="max_minutes"):
        ObjectiveTrainConfig(max_minutes=0.0)


def test_epoch_groups_draw_the_logged_share_from_the_logged_roll_out() -> None:
    from seal.models.objective.train import _epoch_groups

    groups = np.stack([np.repeat(np.arange(10), 5), np.tile(np.arange(5), 10)], axis=1)  # 10 scenarios x M = 5
    rng = np.random.default_rng(0)
    plain = _epoch_groups(groups, 20, None, rng)
    assert len(set(plain.tolist())) == 20  # a sample without repeats
    pick = _epoch_groups(groups, 20, 0.5, rng)
    assert len(pick) == 20 and (groups[pick, 1] == 0).sum() == 10
    # More logged groups asked for than there are (10): drawn again; the others without repeats.
    pick = _epoch_groups(groups, 40, 0.75, rng)
    assert (groups[pick, 1] == 0).sum() == 30 and len(set(pick[groups[pick, 1] != 0].tolist())) == 10
    assert (groups[_epoch_groups(groups, 8, 0.0, rng), 1] != 0).all()
    with pytest.raises(ValueError, match="logged_share"):
        ObjectiveTrainConfig(logged_share=1.5)
