"""pi_score with the candidates' prior probabilities as an input (`ObjectiveConfig.candidate_prior`)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from seal.core.scenario import DT_S
from seal.models.objective import LabelSet, ObjectiveConfig, ObjectiveModel, ObjectiveTrainConfig, train_objective
from seal.models.objective.features import CAND_PRIOR_FEATURE_NAMES, LOG_PROB_SCALE, candidate_prior_features
from seal.models.objective.metrics import spearman

T = 20


def test_candidate_prior_features_by_hand() -> None:
    probs = torch.tensor([[0.5, 0.25, 0.25, 0.0]])
    out = candidate_prior_features(probs)
    assert out.shape == (1, 4, len(CAND_PRIOR_FEATURE_NAMES))
    gap, rank = out[0, :, 0], out[0, :, 1]
    np.testing.assert_allclose(gap[:3].numpy(), [0.0, -np.log(2) / LOG_PROB_SCALE, -np.log(2) / LOG_PROB_SCALE],
                               rtol=1e-6)
    assert float(gap[3]) == pytest.approx(-5.0)  # probability 0: clipped 50 nats below the best
    # Ranks: the best is 0, the two tied share rank 1 (of 3), the last is 3 / 3.
    np.testing.assert_allclose(rank.numpy(), [0.0, 1 / 3, 1 / 3, 1.0])
    # Relative to the scenario's own candidates: a sharper or flatter prior with the same order changes the gaps,
    # never the ranks, and scaling all probabilities changes nothing.
    np.testing.assert_allclose(candidate_prior_features(probs * 0.1).numpy(), out.numpy(), atol=1e-6)


def _labels(rng: np.random.Generator, n_scenarios: int, n_cand: int = 8) -> LabelSet:
    """Ego along +x at 10 m/s; every candidate passes through the ego's path at the same distance, so the tracks
    say nothing about the label. f_coll = 1 for the three most probable candidates, else 0 (as if the adversary's
    controller could follow only plausible modes); probabilities are random per scenario."""
    time = DT_S * np.arange(T)
    m = n_cand + 1
    ego_xy = np.zeros((n_scenarios, m, T, 2))
    ego_xy[..., 0] = 10.0 * time
    cand_xy = np.zeros((n_scenarios, n_cand, T, 2))
    cand_xy[..., 0] = 20 + 10.0 * time
    cand_xy[..., 1] = rng.uniform(-0.5, 0.5, size=(n_scenarios, n_cand, 1))
    probs = rng.dirichlet(np.ones(n_cand), size=n_scenarios)
    top3 = np.argsort(-probs, axis=1)[:, :3]
    f_coll = np.zeros((n_scenarios, n_cand), np.float32)
    np.put_along_axis(f_coll, top3, 1.0, axis=1)
    z = np.zeros
    return LabelSet(
        scenario_ids=np.array([f"s{i}" for i in range(n_scenarios)]), cand_xy=cand_xy.astype(np.float32),
        cand_heading=z((n_scenarios, n_cand, T), np.float32), probs=probs.astype(np.float32),
        ego_xy=ego_xy.astype(np.float32), ego_heading=z((n_scenarios, m, T), np.float32),
        ego_valid=np.ones((n_scenarios, m, T), bool), f_coll=f_coll, f_diff=z((n_scenarios, m, n_cand), np.float32),
        crashed=z((n_scenarios, n_cand), bool), cat_score=z((n_scenarios, n_cand), np.float32),
        adv_xy=ego_xy.astype(np.float32), adv_valid=np.ones((n_scenarios, m, T), bool),
        sizes_m=np.ones((n_scenarios, 2, 2), np.float32),
    )


def _held_out_spearman(model: ObjectiveModel, labels: LabelSet) -> float:
    rho = []
    for s in range(labels.n_scenarios):
        score = model.rank(labels.cand_xy[s], labels.cand_heading[s], labels.ego_xy[s, :1], labels.ego_heading[s, :1],
                           labels.ego_valid[s, :1], cand_probs=labels.probs[s])
        rho.append(spearman(score, labels.f_coll[s]))
    return float(np.mean(rho))


def test_the_candidate_prior_lets_the_network_learn_what_the_tracks_cannot_tell() -> None:
    rng = np.random.default_rng(0)
    train, held_out = _labels(rng, 40), _labels(rng, 10)
    cfg = ObjectiveTrainConfig(batch_size=64, lr=3e-3, max_epochs=4, pairs_per_epoch=2000, patience=4,
                               max_minutes=None, seed=0)
    with_prior, _ = train_objective(train, ObjectiveConfig(n_steps=T, hidden=16, stride=4, candidate_prior=True), cfg)
    without, _ = train_objective(train, ObjectiveConfig(n_steps=T, hidden=16, stride=4), cfg)
    rho_with, rho_without = _held_out_spearman(with_prior, held_out), _held_out_spearman(without, held_out)
    assert rho_with > 0.6  # 0.85 measured
    assert rho_with > rho_without + 0.4  # 0.09 without


def test_a_candidate_prior_model_needs_the_probabilities_and_keeps_the_option_when_saved(tmp_path) -> None:
    labels = _labels(np.random.default_rng(1), 1)
    torch.manual_seed(0)
    model = ObjectiveModel(ObjectiveConfig(n_steps=T, hidden=8, candidate_prior=True))
    args = (labels.cand_xy[0], labels.cand_heading[0], labels.ego_xy[0, :2], labels.ego_heading[0, :2],
            labels.ego_valid[0, :2])
    with pytest.raises(ValueError, match="prior probabilities"):
        model.rank(*args)
    with pytest.raises(ValueError, match="cand_probs \\[N\\]"):
        model.rank(*args, cand_probs=labels.probs[0, :3])
    probs = labels.probs[0]
    model.save(tmp_path / "m.pt")
    back = ObjectiveModel.load(tmp_path / "m.pt")
    assert back.config.candidate_prior
    np.testing.assert_allclose(back.rank(*args, cand_probs=probs), model.rank(*args, cand_probs=probs))
    # The probabilities move the score; a model without the option ignores them.
    other = probs[::-1].copy()
    assert not np.allclose(model.rank(*args, cand_probs=other), model.rank(*args, cand_probs=probs))
    plain = ObjectiveModel(replace(model.config, candidate_prior=False))
    np.testing.assert_array_equal(plain.rank(*args, cand_probs=other), plain.rank(*args))
