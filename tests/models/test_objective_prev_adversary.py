"""pi_score with the previous roll-out's adversary as an input (`ObjectiveConfig.prev_adversary`)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from seal.core.scenario import DT_S
from seal.models.objective import LabelSet, ObjectiveConfig, ObjectiveModel, ObjectiveTrainConfig, train_objective
from seal.models.objective.features import PREV_ADV_FEATURE_NAMES, prev_adversary_features
from seal.models.objective.metrics import spearman

P = {name: k for k, name in enumerate(PREV_ADV_FEATURE_NAMES)}
T = 20


def test_prev_adversary_features_by_hand() -> None:
    # Candidate at the origin heading +x; previous adversary at (10, 2); previous ego at (0, -5) heading +y.
    cand = torch.zeros(1, 2, 2)
    ego = torch.tensor([[[0.0, -5.0]] * 2])
    adv = torch.tensor([[[10.0, 2.0]] * 2])
    ego_h = torch.full((1, 2), math.pi / 2)
    adv_valid = torch.tensor([[True, False]])  # step 1: the previous adversary was gone
    out = prev_adversary_features(cand, torch.zeros(1, 2), ego, ego_h, torch.ones(1, 2, dtype=torch.bool), adv,
                                  adv_valid)
    assert out.shape == (1, 2, len(PREV_ADV_FEATURE_NAMES))
    f = out[0, 0]
    assert float(f[P["prev_adv_x_in_cand"]]) == pytest.approx(10 / 20)
    assert float(f[P["prev_adv_y_in_cand"]]) == pytest.approx(2 / 20)
    assert float(f[P["prev_adv_to_cand_distance"]]) == pytest.approx(math.sqrt(104) / 20, rel=1e-5)
    # In the ego's frame (heading +y): the adversary is 7 m ahead and 10 m to the right.
    assert float(f[P["prev_adv_x_in_ego"]]) == pytest.approx(7 / 20, abs=1e-6)
    assert float(f[P["prev_adv_y_in_ego"]]) == pytest.approx(-10 / 20, abs=1e-6)
    assert float(f[P["prev_adv_closeness"]]) == pytest.approx(math.exp(-math.sqrt(149) / 8), rel=1e-5)
    assert torch.all(out[0, 1] == 0.0)


def _labels(rng: np.random.Generator, n_scenarios: int, n_cand: int = 8) -> LabelSet:
    """Ego along +x at 10 m/s; candidates and previous adversaries drive beside it at random lateral offsets.
    f_coll = 0 everywhere; f_diff[i, j] = 1 when candidate j drives more than 3 m to either side of the adversary of
    previous roll-out i, else 0: the ego keeps its path only when the adversary drives as before. The candidates
    alone (and the ego, the same in every roll-out) say nothing about it."""
    time = DT_S * np.arange(T)
    m = n_cand + 1
    ego_xy = np.zeros((n_scenarios, m, T, 2))
    ego_xy[..., 0] = 10.0 * time
    cand_lat = rng.uniform(-8, 8, size=(n_scenarios, n_cand))
    adv_lat = rng.uniform(-8, 8, size=(n_scenarios, m))
    cand_xy = np.stack([np.broadcast_to(20 + 10.0 * time, (n_scenarios, n_cand, T)),
                        np.broadcast_to(cand_lat[..., None], (n_scenarios, n_cand, T))], axis=-1)
    adv_xy = np.stack([np.broadcast_to(20 + 10.0 * time, (n_scenarios, m, T)),
                       np.broadcast_to(adv_lat[..., None], (n_scenarios, m, T))], axis=-1)
    diff = (np.abs(cand_lat[:, None, :] - adv_lat[:, :, None]) > 3.0).astype(np.float32)
    z = np.zeros
    return LabelSet(
        scenario_ids=np.array([f"s{i}" for i in range(n_scenarios)]), cand_xy=cand_xy.astype(np.float32),
        cand_heading=z((n_scenarios, n_cand, T), np.float32), probs=np.full((n_scenarios, n_cand), 1 / n_cand,
                                                                             np.float32),
        ego_xy=ego_xy.astype(np.float32), ego_heading=z((n_scenarios, m, T), np.float32),
        ego_valid=np.ones((n_scenarios, m, T), bool), f_coll=z((n_scenarios, n_cand), np.float32), f_diff=diff,
        crashed=z((n_scenarios, n_cand), bool), cat_score=z((n_scenarios, n_cand), np.float32),
        adv_xy=adv_xy.astype(np.float32), adv_valid=np.ones((n_scenarios, m, T), bool),
        sizes_m=np.ones((n_scenarios, 2, 2), np.float32),
    )


def _held_out_spearman(model: ObjectiveModel, labels: LabelSet) -> float:
    rho = []
    for s in range(labels.n_scenarios):
        for i in range(labels.ego_xy.shape[1]):
            adv = {"adv_xy": labels.adv_xy[s, i : i + 1], "adv_valid": labels.adv_valid[s, i : i + 1]}
            score = model.rank(labels.cand_xy[s], labels.cand_heading[s], labels.ego_xy[s, i : i + 1],
                               labels.ego_heading[s, i : i + 1], labels.ego_valid[s, i : i + 1], **adv)
            rho.append(spearman(score, labels.f_diff[s, i]))
    return float(np.mean(rho))


def test_the_previous_adversary_lets_the_network_learn_what_the_ego_track_cannot_tell() -> None:
    rng = np.random.default_rng(0)
    train, held_out = _labels(rng, 40), _labels(rng, 10)
    cfg = ObjectiveTrainConfig(batch_size=64, lr=3e-3, max_epochs=4, pairs_per_epoch=2000, patience=4,
                               max_minutes=None, seed=0)
    with_adv, _ = train_objective(train, ObjectiveConfig(hidden=16, stride=4, prev_adversary=True), cfg)
    without, _ = train_objective(train, ObjectiveConfig(hidden=16, stride=4), cfg)
    rho_with, rho_without = _held_out_spearman(with_adv, held_out), _held_out_spearman(without, held_out)
    assert rho_with > 0.5  # 0.67 measured
    assert rho_with > rho_without + 0.3  # 0.12 without


def test_a_prev_adversary_model_needs_the_adversary_and_keeps_the_option_when_saved(tmp_path) -> None:
    labels = _labels(np.random.default_rng(1), 1)
    torch.manual_seed(0)
    model = ObjectiveModel(ObjectiveConfig(n_steps=T, hidden=8, prev_adversary=True))
    args = (labels.cand_xy[0], labels.cand_heading[0], labels.ego_xy[0, :2], labels.ego_heading[0, :2],
            labels.ego_valid[0, :2])
    with pytest.raises(ValueError, match="pass adv_xy"):
        model.rank(*args)
    with pytest.raises(ValueError, match="adv_xy \\[K, T, 2\\]"):
        model.rank(*args, adv_xy=labels.adv_xy[0, :1], adv_valid=labels.adv_valid[0, :1])
    adv = {"adv_xy": labels.adv_xy[0, :2], "adv_valid": labels.adv_valid[0, :2]}
    model.save(tmp_path / "m.pt")
    back = ObjectiveModel.load(tmp_path / "m.pt")
    assert back.config.prev_adversary
    np.testing.assert_allclose(back.rank(*args, **adv), model.rank(*args, **adv))
    # The previous adversary moves the score; a model without the option ignores it.
    moved = {"adv_xy": adv["adv_xy"] + np.float32(5.0), "adv_valid": adv["adv_valid"]}
    assert not np.allclose(model.rank(*args, **moved), model.rank(*args, **adv))
    plain = ObjectiveModel(replace(model.config, prev_adversary=False))
    np.testing.assert_array_equal(plain.rank(*args, **moved), plain.rank(*args))
