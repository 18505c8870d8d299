"""pi_score labels: the builder on two tiny scenarios (shapes, label identities, agreement with a direct
roll-out), its resume (finished chunks are skipped, a missing one is rebuilt, other settings start over) and
the held-out evaluation on those labels."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import scenario_factory as sf

from seal.experiments.fitting import objective_labels as ol
from seal.models.objective.labels import LOGGED_ROW, LabelSet

N_CAND = 3


@pytest.fixture(scope="module")
def scenarios():
    return [sf.lane_change_scenario(), sf.highway_scenario(1)]


@pytest.fixture(scope="module")
def built(scenarios, tmp_path_factory) -> tuple[LabelSet, object]:
    out = tmp_path_factory.mktemp("labels")
    spec = ol.source_spec(candidates="constant_velocity")
    labels = ol.build_labels(scenarios, out, spec, n_candidates=N_CAND, workers=1, chunk_size=1, progress=False)
    return labels, out


def test_labels_have_the_documented_shapes_and_identities(built, scenarios) -> None:
    labels, out = built
    assert labels.scenario_ids.tolist() == [s.scenario_id for s in scenarios]
    s, n, t = 2, N_CAND, 80
    assert labels.cand_xy.shape == (s, n, t, 2) and labels.ego_xy.shape == (s, n + 1, t, 2)
    assert labels.f_diff.shape == (s, n + 1, n) and labels.f_coll.shape == (s, n)
    for f in (labels.f_coll, labels.f_diff):
        assert np.all((f >= 0) & (f <= 1))
    # Against its own episode a candidate changes nothing; f_diff between two episodes is symmetric.
    for j in range(n):
        np.testing.assert_allclose(labels.f_diff[:, 1 + j, j], 0.0, atol=1e-6)
    np.testing.assert_allclose(labels.f_diff[:, 1 + 0, 1], labels.f_diff[:, 1 + 1, 0], rtol=1e-5)
    np.testing.assert_array_equal(labels.f_coll[labels.crashed], 1.0)
    # Every episode starts with the ego valid at the first candidate step.
    assert labels.ego_valid[:, :, 0].all()
    assert sorted(p.name for p in out.glob("part_*.npz")) == ["part_00000.npz", "part_00001.npz"]


def test_labels_match_a_direct_rollout(built, scenarios) -> None:
    from seal.adversaries.candidate_path import candidate_track
    from seal.envs.behaviors import ReplayBehavior
    from seal.envs.scenario_env import ScenarioEnv
    from seal.experiments.evaluation.episodes import run_episode
    from seal.experiments.training.egos import HeuristicEgo
    from seal.scoring.criticality import f_coll

    labels, _ = built
    scenario = scenarios[0]
    j = 1
    track = candidate_track(scenario, scenario.adv_index, labels.cand_xy[0, j].astype(np.float64))
    ro = run_episode(ScenarioEnv(scenario), scenario, HeuristicEgo(), ReplayBehavior(track))
    ego = ro.ego_track[11:91]
    np.testing.assert_allclose(labels.ego_xy[0, 1 + j], ego[:, :2], atol=1e-3)
    adv = ro.adv_track[11:91]
    valid = (ego[:, 7] > 0.5) & (adv[:, 7] > 0.5)
    expected = f_coll(ego[:, :2], adv[:, :2], valid=valid, crashed=any(a == ro.adv_id for _, a in ro.ego_crashes))
    assert labels.f_coll[0, j] == pytest.approx(float(expected), abs=1e-5)


def test_hold_last_keeps_the_last_valid_position() -> None:
    xy = np.arange(10, dtype=float).reshape(5, 2)
    valid = np.array([False, True, True, False, False])
    np.testing.assert_array_equal(ol.hold_last(xy, valid), [[2, 3], [2, 3], [4, 5], [4, 5], [4, 5]])


def test_build_resumes_skips_finished_chunks_and_restarts_on_other_settings(built, scenarios, monkeypatch) -> None:
    labels, out = built
    calls: list[str] = []
    real = ol.label_scenario

    def counting(scenario, *args, **kwargs):
        calls.append(scenario.scenario_id)
        return real(scenario, *args, **kwargs)

    monkeypatch.setattr(ol, "label_scenario", counting)
    spec = ol.source_spec(candidates="constant_velocity")
    kw = {"workers": 1, "chunk_size": 1, "progress": False}
    again = ol.build_labels(scenarios, out, spec, n_candidates=N_CAND, **kw)
    assert calls == []  # everything reused
    np.testing.assert_array_equal(again.f_diff, labels.f_diff)
    (out / "part_00001.npz").unlink()
    again = ol.build_labels(scenarios, out, spec, n_candidates=N_CAND, **kw)
    assert calls == [scenarios[1].scenario_id]  # only the missing chunk
    np.testing.assert_allclose(again.f_coll, labels.f_coll)
    calls.clear()
    with pytest.raises(ValueError, match="other scenarios or settings"):  # a folder the caller must not wipe
        ol.build_labels(scenarios[:1], out, spec, n_candidates=2, start_over=False, **kw)
    assert sorted(p.name for p in out.glob("part_*.npz")) == ["part_00000.npz", "part_00001.npz"] and not calls
    other = ol.build_labels(scenarios[:1], out, spec, n_candidates=2, **kw)  # other settings: start over
    assert calls == [scenarios[0].scenario_id] and other.n_candidates == 2
    assert sorted(p.name for p in out.glob("part_*.npz")) == ["part_00000.npz"]


def test_source_spec_needs_exactly_one_source(tmp_path) -> None:
    with pytest.raises(ValueError, match="exactly one candidate source"):
        ol.source_spec()
    with pytest.raises(FileNotFoundError, match="does not exist"):
        ol.source_spec(prior=tmp_path / "none.pt")
    with pytest.raises(ValueError, match="unknown candidate source"):
        ol.source_spec(candidates="nope")


def test_evaluate_reports_metrics_and_baselines(built) -> None:
    import torch

    from seal.experiments.fitting.objective_eval import closeness, evaluate
    from seal.experiments.fitting.objective_report import K_PREV, format_report
    from seal.models.objective import ObjectiveConfig, ObjectiveModel

    labels, _ = built
    torch.manual_seed(0)
    report = evaluate(ObjectiveModel(ObjectiveConfig(hidden=8)), labels)
    assert report["mse"]["all_prev"]["pairs"] == labels.f_diff.size
    assert report["mse"]["logged_prev"]["pairs"] == labels.n_scenarios * N_CAND
    assert set(report["ranking_logged_prev"]) == {"pi_score", "closeness", "cat", "prior_probability"}
    assert report["ranking_k5_prev"]["pi_score"]["scenarios"] == 2
    assert report["labels"]["f_diff_var_all_prev"] == pytest.approx(float(labels.f_diff.var()), abs=1e-5)
    # The closeness baseline with the logged roll-out as previous roll-out is f_coll of that roll-out.
    from seal.scoring.criticality import f_coll

    c = closeness(labels, np.full((2, 1), LOGGED_ROW))[:, 0]
    expected = f_coll(labels.ego_xy[:, :1], labels.cand_xy, valid=labels.ego_valid[:, :1])
    np.testing.assert_allclose(c, expected)
    text = format_report({**report, "eval_split": "x", "dataset": "d",
                          "rank_latency": {"candidates": 32, "rollouts": 5, "median_ms": 1.0, "p95_ms": 2.0},
                          "timings": {}})
    assert K_PREV == 5 and "Spearman" in text and "| f_diff |" in text
    assert set(report["ranking_per_head"]) == {"f_coll", "f_diff"}


def test_cat_scores_against_any_previous_rollouts(built) -> None:
    from seal.experiments.fitting.objective_eval import cat_scores

    labels, _ = built
    logged = np.full((labels.n_scenarios, 1), LOGGED_ROW)
    # Against the logged row it is the score stored when the labels were built (from the full logged track).
    np.testing.assert_allclose(cat_scores(labels, logged), labels.cat_score, rtol=1e-5, atol=1e-7)
    # Roll-out 1's ego moved 30 m to the side, candidate 0 driven exactly where that ego drove: the candidate hits
    # that roll-out's ego box from the first sample on and scores only when that roll-out is among the previous ones.
    ego_xy = labels.ego_xy.copy()
    ego_xy[0, 1, :, 1] += 30.0
    cand_xy = labels.cand_xy.copy()
    cand_xy[0, 0] = ego_xy[0, 1]
    cand_h = labels.cand_heading.copy()
    cand_h[0, 0] = labels.ego_heading[0, 1]
    moved = replace(labels, cand_xy=cand_xy, cand_heading=cand_h, ego_xy=ego_xy)
    with_row1 = cat_scores(moved, np.array([[LOGGED_ROW, 1]] * labels.n_scenarios))
    assert with_row1[0, 0] > 0.0
    assert cat_scores(moved, logged)[0, 0] == 0.0


def test_per_head_ranking_scores_each_head_against_its_own_label(built) -> None:
    from seal.experiments.fitting.objective_eval import per_head_ranking

    labels, _ = built
    s, n = labels.f_coll.shape
    # Head 0 equals its label (Spearman 1 wherever the label varies), head 1 is the reverse of its label (-1).
    pred = np.stack([labels.f_coll, -labels.f_diff[:, LOGGED_ROW]], axis=-1)
    close = np.tile(np.arange(n, dtype=float), (s, 1))
    out = per_head_ranking(pred, close, labels)
    varies = [np.ptp(labels.f_coll, axis=1) > 0, np.ptp(labels.f_diff[:, LOGGED_ROW], axis=1) > 0]
    assert out["f_coll"]["pi_score_head"] == pytest.approx(varies[0].mean(), abs=1e-4)
    assert out["f_diff"]["pi_score_head"] == pytest.approx(-varies[1].mean(), abs=1e-4)
    from seal.models.objective.metrics import spearman

    assert out["f_coll"]["closeness"] == pytest.approx(float(spearman(close, labels.f_coll).mean()), abs=1e-4)


@pytest.fixture(scope="module")
def tiny_skills(tmp_path_factory):
    """A skills folder with untrained default-size models (the labels' mechanics do not depend on the weights)."""
    import torch

    from seal.models.skills.io import VAE_FILE, prior_file, save_model
    from seal.models.skills.realnvp import ConditionalRealNVP
    from seal.models.skills.vae import SkillVAE

    folder = tmp_path_factory.mktemp("skills")
    torch.manual_seed(0)
    save_model(SkillVAE(), folder / VAE_FILE)
    for name in ("benign", "adversarial"):
        save_model(ConditionalRealNVP(), folder / prior_file(name))
    return folder


def test_seal_behaviour_labels_roll_out_follow_then_switch_per_ego(scenarios, tiny_skills, tmp_path) -> None:
    from seal.envs.scenario_env import ScenarioEnv
    from seal.envs.skill_behavior import SkillSwitchBehavior
    from seal.experiments.evaluation.episodes import run_episode
    from seal.experiments.training.egos import HeuristicEgo

    spec = ol.source_spec(candidates="constant_velocity")
    behavior = ol.LabelBehavior(kind="seal", skills=str(tiny_skills), seed=3)
    labels = ol.build_labels(scenarios[:1], tmp_path / "l", spec, n_candidates=N_CAND, workers=1, chunk_size=1,
                             progress=False, egos=["heuristic", "replay"], behavior=behavior)
    sid = scenarios[0].scenario_id
    assert labels.scenario_ids.tolist() == [sid, sid]  # one row per ego
    # The open-loop replayed ego ignores the adversary: its roll-outs agree until one of them ends.
    both = labels.ego_valid[1, 1] & labels.ego_valid[1, 2]
    np.testing.assert_allclose(labels.ego_xy[1, 1][both], labels.ego_xy[1, 2][both], atol=1e-4)
    # Row 0 (heuristic ego), candidate j: the episode of SEAL's follow-then-switch behaviour, reproducible.
    scenario = scenarios[0]
    source = ol._candidate_source(spec)
    cands = source(scenario)
    env = ScenarioEnv(scenario)
    logged = run_episode(env, scenario, HeuristicEgo())
    behaviors = ol._candidate_behaviors(scenario, cands, cands.xy[:N_CAND, :80], logged, behavior, 0)
    assert all(isinstance(b, SkillSwitchBehavior) and b.switch_step >= 10 for b in behaviors)
    ro = run_episode(env, scenario, HeuristicEgo(), behaviors[1])
    np.testing.assert_allclose(labels.ego_xy[0, 2], ro.ego_track[11:91, :2] * (ro.ego_track[11:91, 7:8] > 0.5)
                               + labels.ego_xy[0, 2] * (ro.ego_track[11:91, 7:8] <= 0.5), atol=1e-3)
    replay = ol._candidate_behaviors(scenario, cands, cands.xy[:N_CAND, :80], logged, ol.LabelBehavior(), 0)
    assert not any(isinstance(b, SkillSwitchBehavior) for b in replay)
    with pytest.raises(ValueError, match="needs a skills folder"):
        ol.LabelBehavior(kind="seal")


def test_oracle_bounds_by_hand() -> None:
    from seal.experiments.fitting.objective_eval import oracle_bounds

    # One scenario, 3 candidates: closeness 0.1 / 0.5 / 0.9; the third makes the ego crash (f_coll 1); the first
    # changes its path (f_diff 0.9): targets 1.0 / 0.5 / 1.0.
    t = 2
    labels = LabelSet(
        scenario_ids=np.array(["s"]), cand_xy=np.zeros((1, 3, t, 2), np.float32),
        cand_heading=np.zeros((1, 3, t), np.float32), probs=np.full((1, 3), 1 / 3, np.float32),
        ego_xy=np.zeros((1, 4, t, 2), np.float32), ego_heading=np.zeros((1, 4, t), np.float32),
        ego_valid=np.ones((1, 4, t), dtype=bool), f_coll=np.array([[0.1, 0.5, 1.0]], np.float32),
        f_diff=np.array([[[0.9, 0.0, 0.0]] * 4], np.float32), crashed=np.array([[False, False, True]]),
        cat_score=np.zeros((1, 3), np.float32), adv_xy=np.zeros((1, 4, t, 2), np.float32),
        adv_valid=np.zeros((1, 4, t), dtype=bool), sizes_m=np.ones((1, 2, 2), np.float32),
    )
    out = oracle_bounds(np.array([[0.1, 0.5, 0.9]]), labels)
    # Crashes first keeps closeness's order 0 < 1 < 2, uncorrelated with the target's ranks (1.5, 0, 1.5): 0.
    # Closeness + f_diff = 1.0 / 0.5 / 0.9 ranks (2, 0, 1): centred products sum to 1.5, norms sqrt(2 * 1.5).
    assert out["closeness_plus_true_crash"] == 0.0
    assert out["closeness_plus_true_f_diff"] == pytest.approx(1.5 / math.sqrt(3.0), abs=1e-4)
    # With the crash flag on the first candidate instead, crashes-first ranks (2, 0, 1) too.
    flagged = oracle_bounds(np.array([[0.1, 0.5, 0.9]]), replace(labels, crashed=np.array([[True, False, False]])))
    assert flagged["closeness_plus_true_crash"] == pytest.approx(1.5 / math.sqrt(3.0), abs=1e-4)
