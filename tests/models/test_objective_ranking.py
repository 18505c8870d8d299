"""pi_score's ranking losses against hand computations, the zero-initialised correction (untrained = closeness),
the ego-only branch (one offset per roll-out, the same for all its candidates) and its features, and reusing a
label folder without simulating."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from seal.core.scenario import DT_S
from seal.models.objective import LabelSet, ObjectiveConfig, ObjectiveModel, ObjectiveTrainConfig
from seal.models.objective.features import EGO_FEATURE_NAMES, ego_features
from seal.models.objective.losses import group_ranks, pairwise_loss, pearson_rank_loss
from seal.models.objective.metrics import average_ranks, spearman

E = {name: i for i, name in enumerate(EGO_FEATURE_NAMES)}


pytestmark = pytest.mark.usefixtures("one_thread")  # tests/models/conftest.py


def _pairs(sums: list[float]) -> torch.Tensor:
    """``[n, 2]`` head values whose sums are ``sums`` (all on the f_coll head)."""
    return torch.tensor([[s, 0.0] for s in sums], dtype=torch.float64)


def test_pairwise_loss_matches_a_hand_computation() -> None:
    # Simulated sums 1.0, 0.5, 0.52 (the last two differ by less than min_gap 0.05: no pair between them).
    target = _pairs([1.0, 0.5, 0.52])
    pred = _pairs([0.2, 0.4, 0.1])
    t = 0.1
    # Pairs (a better than b): (0, 1) gap 0.5, margin (0.2 - 0.4) / t = -2; (0, 2) gap 0.48, margin (0.2 - 0.1) / t = 1.
    by_hand = (0.5 * math.log1p(math.exp(2.0)) + 0.48 * math.log1p(math.exp(-1.0))) / (0.5 + 0.48)
    assert float(pairwise_loss(pred, target, 3, t)) == pytest.approx(by_hand, rel=1e-9)
    # Two groups: one weighted mean over the pairs of both (the second group's two pairs: gap 1, margin 0).
    target2 = torch.cat([target, _pairs([0.0, 1.0, 0.0])])
    pred2 = torch.cat([pred, _pairs([0.3, 0.3, 0.3])])
    two = (0.5 * math.log1p(math.exp(2.0)) + 0.48 * math.log1p(math.exp(-1.0)) + 2 * 1.0 * math.log(2.0)) / 2.98
    assert float(pairwise_loss(pred2, target2, 3, t)) == pytest.approx(two, rel=1e-9)
    # No pair far enough apart: zero, with a gradient of zero.
    flat = pred.clone().requires_grad_(True)
    loss = pairwise_loss(flat, _pairs([0.5, 0.5, 0.51]), 3, t)
    loss.backward()
    assert float(loss.detach()) == 0.0 and flat.grad is not None and float(flat.grad.abs().sum()) == 0.0


def test_group_ranks_are_the_metrics_average_ranks() -> None:
    y = torch.tensor([[0.3, 0.1, 0.3, 0.9, 0.1], [1.0, 2.0, 3.0, 4.0, 5.0]], dtype=torch.float64)
    np.testing.assert_allclose(group_ranks(y).numpy(), average_ranks(y.numpy()))


def test_pearson_rank_loss_matches_a_hand_computation_and_spearman() -> None:
    target = _pairs([0.1, 1.4, 0.4, 1.2])  # ranks 0, 3, 1, 2
    pred = _pairs([0.0, 2.0, 1.0, 3.0])
    r = np.array([0.0, 3.0, 1.0, 2.0]) - 1.5
    s = np.array([0.0, 2.0, 1.0, 3.0]) - 1.5
    corr = float((r * s).sum() / math.sqrt((r * r).sum() * (s * s).sum()))
    assert float(pearson_rank_loss(pred, target, 4)) == pytest.approx(1.0 - corr, rel=1e-9)
    # Predictions that are a rank-preserving linear map of the ranks: loss 0, and it equals 1 - Spearman then.
    perfect = _pairs([5.0, 8.0, 6.0, 7.0])
    assert float(pearson_rank_loss(perfect, target, 4)) == pytest.approx(0.0, abs=1e-12)
    rho = spearman(pred.sum(-1).numpy(), target.sum(-1).numpy())
    assert float(pearson_rank_loss(pred, target, 4)) == pytest.approx(1.0 - float(rho), rel=1e-9)
    # A scenario-wide shift or scale of the predictions does not change it; a constant prediction counts as 0.
    assert float(pearson_rank_loss(pred * 3 + 1, target, 4)) == pytest.approx(1.0 - corr, rel=1e-9)
    assert float(pearson_rank_loss(_pairs([0.5] * 4), target, 4)) == pytest.approx(1.0)
    # ... and its gradient is finite (zero), next to a group that does learn.
    pred2 = torch.cat([_pairs([0.5] * 4), pred]).requires_grad_(True)
    pearson_rank_loss(pred2, torch.cat([target, target]), 4).backward()
    assert pred2.grad is not None and torch.isfinite(pred2.grad).all()
    assert float(pred2.grad[:4].abs().sum()) == 0.0 and float(pred2.grad[4:].abs().sum()) > 0.0


def test_ego_features_of_a_braking_ego_turned_north() -> None:
    # Heading north (pi / 2) from (3, 4) at 10 m/s, braking at 2 m/s^2; the last step is invalid.
    t = np.arange(6) * DT_S
    along = 10.0 * t - t * t
    xy = np.stack([np.full(6, 3.0), 4.0 + along], axis=-1)
    valid = np.array([True] * 5 + [False])
    f = ego_features(torch.as_tensor(xy), torch.full((6,), math.pi / 2, dtype=torch.float64),
                     torch.as_tensor(valid)).numpy()
    assert f.shape == (6, len(EGO_FEATURE_NAMES))
    np.testing.assert_allclose(f[:5, E["x_in_start"]] * 20.0, along[:5], atol=1e-9)  # along the start heading
    np.testing.assert_allclose(f[:5, E["y_in_start"]], 0.0, atol=1e-9)
    np.testing.assert_allclose(f[:5, E["cos_heading_change"]], 1.0)
    speed = np.diff(along) / DT_S  # 9.9, 9.7, ... m/s (finite differences)
    np.testing.assert_allclose(f[1:5, E["speed"]] * 10.0, speed[:4], atol=1e-9)
    np.testing.assert_allclose(f[2:5, E["accel"]] * 5.0, -2.0, atol=1e-9)
    assert f[0, E["accel"]] == 0.0
    np.testing.assert_array_equal(f[:, E["valid"]], valid.astype(float))
    assert np.all(f[5, :6] == 0.0) and f[5, E["time"]] == 1.0


def _tracks(rng: np.random.Generator, n: int, k: int) -> tuple[np.ndarray, ...]:
    t = np.arange(80) * DT_S
    cand = np.stack([10.0 * t[None] + rng.normal(0, 5, (n, 1)), rng.normal(0, 3, (n, 1)) + 0 * t], axis=-1)
    ego = np.stack([8.0 * t[None] + rng.normal(0, 5, (k, 1)), rng.normal(0, 3, (k, 1)) + 0 * t], axis=-1)
    return cand, np.zeros((n, 80)), ego, np.zeros((k, 80)), np.ones((k, 80), dtype=bool)


def test_untrained_zero_init_network_is_closeness_and_the_ego_branch_shifts_a_rollout_alike() -> None:
    from seal.scoring.criticality import f_coll

    rng = np.random.default_rng(0)
    cand, cand_h, ego, ego_h, ego_v = _tracks(rng, 6, 3)
    torch.manual_seed(0)
    model = ObjectiveModel(ObjectiveConfig(zero_init=True, ego_branch=True))
    pred = model.predict(cand, cand_h, ego, ego_h, ego_v)  # [3, 6, 2]
    close = f_coll(ego[:, None], cand[None], valid=ego_v[:, None])
    np.testing.assert_allclose(pred[..., 0], close, atol=1e-4)
    np.testing.assert_allclose(pred[..., 1], close, atol=1e-4)  # diff_on_closeness: gain 1
    # A trained-looking ego branch: one logit offset per roll-out, whatever the candidate.
    with torch.no_grad():
        assert model.net.ego_branch is not None
        model.net.ego_branch.out.bias.copy_(torch.tensor([0.7, -1.3]))
        model.net.ego_branch.out.weight.normal_(0.0, 0.5)
    shifted = model.predict(cand, cand_h, ego, ego_h, ego_v)
    logit = lambda p: np.log(p / (1 - p))  # noqa: E731
    offset = logit(np.clip(shifted, 1e-6, 1 - 1e-6)) - logit(np.clip(pred, 1e-6, 1 - 1e-6))
    np.testing.assert_allclose(offset, offset[:, :1].repeat(6, axis=1), atol=2e-3)
    assert np.abs(offset).max() > 0.1
    # Batched over roll-outs = one roll-out at a time (the branch runs once per roll-out).
    one = model.predict(cand, cand_h, ego[1:2], ego_h[1:2], ego_v[1:2])
    np.testing.assert_allclose(one[0], shifted[1], atol=1e-5)


def test_ranking_and_ego_branch_settings_are_validated_and_saved(tmp_path) -> None:
    with pytest.raises(ValueError, match="rank_loss"):
        ObjectiveTrainConfig(rank_loss="lambdamart")
    cfg = ObjectiveConfig.from_dict({"zero_init": 1, "ego_branch": "true", "hidden": 8})
    assert cfg.zero_init is True and cfg.ego_branch is True
    model = ObjectiveModel(cfg)
    model.save(tmp_path / "m.pt")
    back = ObjectiveModel.load(tmp_path / "m.pt")
    assert back.config == cfg and back.net.ego_branch is not None
    cand, cand_h, ego, ego_h, ego_v = _tracks(np.random.default_rng(1), 4, 2)
    np.testing.assert_allclose(back.predict(cand, cand_h, ego, ego_h, ego_v),
                               model.predict(cand, cand_h, ego, ego_h, ego_v))


def _labels(ids: list[str]) -> LabelSet:
    s, n, t = len(ids), 2, 3
    z = np.zeros
    return LabelSet(scenario_ids=np.array(ids), cand_xy=z((s, n, t, 2), np.float32),
                    cand_heading=z((s, n, t), np.float32),
                    probs=z((s, n), np.float32), ego_xy=z((s, n + 1, t, 2), np.float32),
                    ego_heading=z((s, n + 1, t), np.float32), ego_valid=np.ones((s, n + 1, t), bool),
                    f_coll=np.arange(s * n, dtype=np.float32).reshape(s, n), f_diff=z((s, n + 1, n), np.float32),
                    crashed=z((s, n), bool), cat_score=z((s, n), np.float32),
                    adv_xy=z((s, n + 1, t, 2), np.float32), adv_valid=z((s, n + 1, t), bool),
                    sizes_m=np.ones((s, 2, 2), np.float32))


def test_load_label_folder_reads_chunks_as_they_are_and_checks_the_scenarios(tmp_path) -> None:
    from seal.experiments.fitting.objective_labels import load_label_folder

    folder = tmp_path / "labels" / "train"
    folder.mkdir(parents=True)
    _labels(["a", "b"]).save(folder / "part_00000.npz")
    _labels(["c"]).save(folder / "part_00001.npz")
    (folder / "state.json").write_text('{"fingerprint": "of other settings"}')
    labels = load_label_folder(folder, ["a", "b", "c"])
    assert list(labels.scenario_ids) == ["a", "b", "c"] and labels.f_coll[2, 1] == 1.0
    assert sorted(p.name for p in folder.iterdir()) == ["part_00000.npz", "part_00001.npz", "state.json"]
    with pytest.raises(ValueError, match="not the 2 expected rows"):
        load_label_folder(folder, ["a", "b"])
    with pytest.raises(ValueError, match="expected rows"):
        load_label_folder(folder, ["a", "b", "c"], n_egos=2)
    with pytest.raises(FileNotFoundError, match="no part_"):
        load_label_folder(tmp_path / "empty", ["a"])


def _draw(f_coll: list[list[float]], f_diff_logged: list[list[float]], ids: tuple[str, ...] = ("a", "b")) -> LabelSet:
    """Labels of two scenarios x 4 candidates with the given f_coll and logged-row f_diff (tracks all zero)."""
    s, n, t = len(ids), 4, 3
    z = np.zeros
    f_diff = z((s, n + 1, n), np.float32)
    f_diff[:, 0] = f_diff_logged
    return LabelSet(scenario_ids=np.array(ids), cand_xy=z((s, n, t, 2), np.float32),
                    cand_heading=z((s, n, t), np.float32), probs=z((s, n), np.float32),
                    ego_xy=z((s, n + 1, t, 2), np.float32), ego_heading=z((s, n + 1, t), np.float32),
                    ego_valid=np.ones((s, n + 1, t), bool), f_coll=np.array(f_coll, np.float32), f_diff=f_diff,
                    crashed=z((s, n), bool), cat_score=z((s, n), np.float32),
                    adv_xy=z((s, n + 1, t, 2), np.float32), adv_valid=z((s, n + 1, t), bool),
                    sizes_m=np.ones((s, 2, 2), np.float32))


def test_label_retest_compares_two_draws_of_the_labels_and_ranks_the_scores_against_the_second() -> None:
    from seal.experiments.fitting.objective_eval import label_retest

    first = _draw([[0.1, 0.2, 0.3, 0.4], [0.4, 0.3, 0.2, 0.1]], [[0, 0, 1, 1], [1, 0, 0, 0]])
    # Second draw: scenario a keeps its order (sums 0.1, 0.2, 1.3, 1.4 -> 0.1, 0.25, 1.2, 1.45), scenario b's sums
    # (1.4, 0.3, 0.2, 0.1) are reversed (0.0, 0.1, 0.2, 1.3): Spearman 1 and -1, mean 0.
    second = _draw([[0.1, 0.25, 0.2, 0.45], [0.0, 0.1, 0.2, 0.3]], [[0, 0, 1, 1], [0, 0, 0, 1]])
    score = np.array([[1.0, 2.0, 3.0, 4.0], [1.0, 2.0, 3.0, 4.0]])  # ranks as the second draw in both
    rt = label_retest(first, second, {"score": score})
    assert rt["label_spearman"] == 0.0
    # f_coll: a has ranks (0,1,2,3) vs (0,2,1,3): 1 - 6 * 2 / (4 * 15) = 0.8; b is reversed: -1 -> mean -0.1.
    assert rt["label_spearman_per_head"]["f_coll"] == pytest.approx(-0.1)
    assert rt["f_diff_above_half_agreement"] == 0.75  # b: candidates 0 and 3 flip
    assert rt["scores_on_second_draw"] == {"score": 1.0} and rt["scenarios"] == 2
    assert label_retest(first, first, {})["label_spearman"] == 1.0
    with pytest.raises(ValueError, match="not of the same scenarios"):
        label_retest(first, _draw([[0.1] * 4] * 2, [[0] * 4] * 2, ids=("a", "c")), {})


def test_a_retest_needs_the_seal_label_behaviour_and_another_seed(tmp_path) -> None:
    from seal.experiments.fitting.objective import check_retest, resolve_config

    prior = tmp_path / "prior.pt"
    prior.write_bytes(b"")
    replay = resolve_config("quick", prior=prior)
    check_retest(replay, None)
    with pytest.raises(ValueError, match="do not depend on the seed"):
        check_retest(replay, 1)
    seal = resolve_config("quick", prior=prior, behavior="seal", skills=tmp_path, seed=3)
    check_retest(seal, 4)
    with pytest.raises(ValueError, match="is the labels' own seed"):
        check_retest(seal, 3)


def test_fit_diagnosis_tells_over_from_under_fitting_against_closeness() -> None:
    from seal.models.objective.train import FitResult, fit_diagnosis

    def fit(train: list[float], best_val: float) -> FitResult:
        return FitResult(history=[{"train_spearman": t} for t in train], best_val_spearman=best_val,
                         val_closeness_spearman=0.669, train_closeness_spearman=0.558)

    # decisive3's capacity run: training scenarios 0.545 -> 0.655, validation at best 0.656 (closeness 0.558 / 0.669)
    over = fit_diagnosis(fit([0.545, 0.584, 0.655], 0.656))
    assert over.startswith("over-fits: up to +0.097") and "-0.013 on validation" in over and "all-but-eval" in over
    pooled = fit_diagnosis(fit([0.545, 0.584, 0.655], 0.656), whole_pool=True)
    assert "all-but-eval" not in pooled and "bigger scenario pool" in pooled and pooled.startswith("over-fits")
    under = fit_diagnosis(fit([0.550, 0.560], 0.660))
    assert under.startswith("learns nothing beyond closeness") and "+0.002" in under
    assert fit_diagnosis(fit([0.60], 0.70)) == "ranks validation scenarios better than closeness (+0.031)"
    assert fit_diagnosis(FitResult()).startswith("no diagnosis")
