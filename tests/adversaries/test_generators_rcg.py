"""RCG selection (eq. 7.7): KNN distance by hand, collision closeness, the choice on a hand-built embedding set
(nearest to the unsafe cache among the N_int closest candidates), the prototype ablation, and the ``cat-rcg`` /
``seal-rcg`` generators end to end with a small real behaviour model."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import tests.scenario_factory as sf
from seal.adversaries.base import GENERATORS, make_generator, pipeline_names
from seal.adversaries.history import RolloutHistory
from seal.adversaries.rcg.select import (
    RCGObjective,
    closeness_m,
    ego_tracks,
    knn_distance,
    perturbed_scenes,
    ranking_scores,
    rcg_select,
)
from seal.core.scenario import CURRENT_STEP, DT_S, N_FUTURE, N_STEPS, VALID, X, Y
from seal.envs.behaviors import ReplayBehavior
from seal.models.behavior.features import BehaviorFeatureConfig
from seal.models.behavior.losses import Prototypes
from seal.models.behavior.model import BehaviorModel
from seal.models.behavior.network import BehaviorConfig
from seal.models.prior.candidates import Candidates

FUT_S = DT_S * (1 + np.arange(N_FUTURE))


def test_knn_distance_is_the_mean_of_the_nearest_cache_distances() -> None:
    cache = np.array([[0.0, 0.0], [3.0, 0.0], [0.0, 4.0], [10.0, 10.0]])
    q = np.array([[0.0, 0.0], [1.0, 0.0]])
    np.testing.assert_allclose(knn_distance(q, cache, 2), [(0 + 3) / 2, (1 + 2) / 2])
    np.testing.assert_allclose(knn_distance(q, cache, 3), [(0 + 3 + 4) / 3, (1 + 2 + np.hypot(1, 4)) / 3])
    np.testing.assert_allclose(knn_distance(q, cache[:1], 8), [0.0, 1.0])  # fewer cached than N_KNN: all of them
    with pytest.raises(ValueError, match="empty"):
        knn_distance(q, np.zeros((0, 2)), 3)


def test_closeness_averages_the_minimum_distance_over_rollouts() -> None:
    ego_xy = np.zeros((2, N_STEPS, 2))
    ego_xy[1, :, 1] = 3.0  # second roll-out 3 m to the side
    valid = np.ones((2, N_STEPS), dtype=bool)
    cand = np.zeros((2, N_FUTURE, 2))
    cand[0, :, 0] = np.linspace(10.0, 1.0, N_FUTURE)  # comes within 1 m of roll-out 0
    cand[1, :, 0] = 20.0
    close = closeness_m(cand, ego_xy, valid)
    np.testing.assert_allclose(close, [(1.0 + np.hypot(1.0, 3.0)) / 2, (20.0 + np.hypot(20.0, 3.0)) / 2])
    valid[1, :] = False  # an empty roll-out does not count
    np.testing.assert_allclose(closeness_m(cand, ego_xy, valid), [1.0, 20.0])


class EndpointModel:
    """A stand-in embedding: the adversary's final position in the perturbed scene (so the test controls it), an
    unsafe cache around ``(x_unsafe, 0)`` and an unsafe prototype at ``(x_proto, 0)``."""

    def __init__(self, x_unsafe: float, x_proto: float) -> None:
        self.unsafe_cache = np.array([[x_unsafe, 0.0], [x_unsafe + 1.0, 0.0], [x_unsafe, 1.0]])
        self.x_proto = x_proto

    def embed_scenes(self, bank: np.ndarray, scenes: np.ndarray, target_col: int) -> np.ndarray:
        return bank[scenes[:, target_col], -1][:, [X, Y]]

    def unsafe_prototype(self) -> np.ndarray:
        return np.array([self.x_proto, 0.0])


def _fan(scenario, ends_x: list[float]) -> Candidates:
    """Straight candidates of the adversary ending at x = ``ends_x`` (its y kept)."""
    adv = scenario.tracks[scenario.adv_index]
    x0, y0 = float(adv[CURRENT_STEP, X]), float(adv[CURRENT_STEP, Y])
    xy = np.stack([np.stack([x0 + (e - x0) * FUT_S / FUT_S[-1], np.full(N_FUTURE, y0)], 1) for e in ends_x])
    return Candidates.from_positions(xy, np.full(len(ends_x), 1.0 / len(ends_x)), np.array([x0, y0]), 0.0,
                                     scenario.adv_index)


def test_rcg_picks_the_kept_candidate_nearest_the_unsafe_cache() -> None:
    from seal.adversaries.candidate_generator import stack_ego_rollouts

    s = sf.stopped_adversary_scenario()
    ego_xy, ego_h, ego_v = stack_ego_rollouts(RolloutHistory().queue(s))  # the logged ego, K = 1
    x0 = float(s.tracks[s.adv_index, CURRENT_STEP, X])
    y0 = float(s.tracks[s.adv_index, CURRENT_STEP, Y])
    ends = [x0 + 5.0, x0 + 20.0, x0 + 55.0, x0 + 62.0, x0 + 300.0]
    model = EndpointModel(x_unsafe=x0 + 60.0, x_proto=x0 + 20.0)
    cands = _fan(s, ends)
    close = closeness_m(cands.xy, ego_xy, ego_v)
    expected_d = [np.sort(np.linalg.norm(model.unsafe_cache - [e, y0], axis=1))[:2].mean() for e in ends]
    sel = rcg_select(model, s, cands, ego_xy, ego_h, ego_v, n_knn=2, n_int=5)  # type: ignore[arg-type]
    assert sel.index == int(np.argmin(expected_d)) == 3  # ends at x0 + 62: 1 m and ~1.4 m from two cached points
    np.testing.assert_allclose(sel.closeness_m, close)
    np.testing.assert_allclose(np.sort(sel.distance), np.sort(expected_d))
    # With N_int = 2 only the two candidates closest to the ego are kept; the nearer-to-unsafe of those wins.
    sel2 = rcg_select(model, s, cands, ego_xy, ego_h, ego_v, n_knn=2, n_int=2)  # type: ignore[arg-type]
    kept = np.argsort(close, kind="stable")[:2]
    assert sel2.kept.tolist() == kept.tolist()
    assert sel2.index == kept[int(np.argmin(np.array(expected_d)[kept]))]
    scores = ranking_scores(sel2)
    assert int(np.argmax(scores)) == sel2.index and (scores[kept] > np.delete(scores, kept).max()).all()
    # The prototype ablation measures the distance to the unsafe centroid instead: x0 + 20 is candidate 1.
    proto = rcg_select(model, s, cands, ego_xy, ego_h, ego_v, n_knn=2, n_int=5,  # type: ignore[arg-type]
                       distance="prototype")
    assert proto.index == 1


def test_prior_weight_prefers_the_likelier_kept_candidate() -> None:
    from dataclasses import replace

    from seal.adversaries.candidate_generator import stack_ego_rollouts

    s = sf.stopped_adversary_scenario()
    ego_xy, ego_h, ego_v = stack_ego_rollouts(RolloutHistory().queue(s))
    x0 = float(s.tracks[s.adv_index, CURRENT_STEP, X])
    ends = [x0 + 5.0, x0 + 20.0, x0 + 55.0, x0 + 62.0, x0 + 300.0]
    model = EndpointModel(x_unsafe=x0 + 60.0, x_proto=x0 + 20.0)
    probs = np.array([0.05, 0.05, 0.6, 0.05, 0.25])  # candidate 2 (x0 + 55) is the prior's likeliest
    cands = replace(_fan(s, ends), probs=probs)
    thesis = rcg_select(model, s, cands, ego_xy, ego_h, ego_v, n_knn=2, n_int=5,  # type: ignore[arg-type]
                        prior_weight=0.0)
    assert thesis.index == 3 and np.array_equal(thesis.score, thesis.distance)  # nearest the unsafe cache
    d = dict(zip(thesis.kept.tolist(), thesis.distance.tolist(), strict=True))
    # Candidate 2 wins once weight * log(0.6 / 0.05) exceeds its extra distance d_2 - d_3.
    flip = (d[2] - d[3]) / np.log(0.6 / 0.05)
    for weight, chosen in ((0.5 * flip, 3), (2.0 * flip, 2)):
        sel = rcg_select(model, s, cands, ego_xy, ego_h, ego_v, n_knn=2, n_int=5,  # type: ignore[arg-type]
                         prior_weight=weight)
        assert sel.index == chosen
        np.testing.assert_allclose(sel.score, sel.distance - weight * np.log(probs[sel.kept]))
        np.testing.assert_allclose(sel.distance, thesis.distance)  # eq. 7.7's d itself is unchanged
        assert int(np.argmax(ranking_scores(sel))) == chosen
    with pytest.raises(ValueError, match="prior_weight must be a finite number >= 0"):
        RCGObjective(model, n_knn=2, prior_weight=-1.0)  # type: ignore[arg-type]


def test_perturbed_scenes_replace_ego_and_adversary_only() -> None:
    s = sf.lane_change_scenario()
    cands = _fan(s, [300.0, 320.0])
    ego = s.tracks[s.ego_index].astype(float)
    egos = ego_tracks(s, (ego[:, [X, Y]] + [0.0, 1.0])[None], ego[None, :, 2], ego[None, :, VALID] > 0.5)
    scenes = perturbed_scenes(s, cands.xy, egos)
    assert scenes.shape == (2, s.n_agents, N_STEPS, 8)
    np.testing.assert_allclose(scenes[1, s.adv_index, -1, [X, Y]], cands.xy[1, -1])
    np.testing.assert_allclose(scenes[0, s.ego_index, :, Y], s.tracks[s.ego_index, :, Y] + 1.0, atol=1e-5)
    np.testing.assert_allclose(scenes[:, 2:], np.repeat(s.tracks[None, 2:], 2, 0))  # the others keep their log
    np.testing.assert_allclose(scenes[0, s.adv_index, :CURRENT_STEP + 1], s.tracks[s.adv_index, :CURRENT_STEP + 1])


def small_model(seed: int = 0) -> BehaviorModel:
    torch.manual_seed(seed)
    cfg = BehaviorConfig(features=BehaviorFeatureConfig(n_agents=4, stride_steps=10), d_model=16, n_heads=2,
                         n_layers=1, latent_dim=24, proj_dim=4, lora_rank=4, n_modes=2)
    model = BehaviorModel(cfg, prototypes=Prototypes(torch.eye(3, 4), torch.ones(3), torch.ones(3, dtype=torch.bool)))
    model.set_unsafe_cache(np.random.default_rng(seed).normal(size=(20, 4)))
    return model


def test_registry_lists_cat_rcg_and_seal_rcg_as_pipelines() -> None:
    assert {"cat-rcg", "seal-rcg"} <= set(pipeline_names())
    assert GENERATORS["cat-rcg"].model_files() == ("prior", "behavior")
    assert set(GENERATORS["seal-rcg"].model_files()) == {"prior", "behavior", "skills"}


def test_cat_rcg_generates_the_rcg_choice_and_checks_options(tmp_path) -> None:
    s = sf.highway_scenario(3)
    model = small_model()
    path = model.save(tmp_path / "behavior.pt")
    gen = make_generator("cat-rcg", candidates="constant_velocity", behavior=str(path))
    queue = RolloutHistory().queue(s)
    generation = gen.generate(s, queue, np.random.default_rng(0))
    assert isinstance(generation.behavior, ReplayBehavior)
    assert generation.chosen_candidate in generation.extra["rcg_kept"] and len(generation.extra["rcg_kept"]) == 6
    # The same choice as the selection function on the same inputs.
    from seal.adversaries.candidate_generator import stack_ego_rollouts
    from seal.adversaries.candidate_sources import adversary_candidates

    cands = adversary_candidates(gen.candidate_source, s, "cat-rcg")
    sel = rcg_select(BehaviorModel.load(path), s, cands, *stack_ego_rollouts(queue), n_knn=15)
    assert generation.chosen_candidate == sel.index
    # In the env the adversary drives the chosen candidate (replayed open loop, as CAT).
    from seal.envs.scenario_env import ScenarioEnv
    from seal.experiments.evaluation.episodes import run_episode
    from seal.experiments.training.egos import ReplayEgo

    rollout = run_episode(ScenarioEnv(s), s, ReplayEgo(), generation.behavior)
    steps = np.arange(CURRENT_STEP + 1, rollout.last_step + 1)
    adv = rollout.tracks[s.adv_index, steps][:, [X, Y]]
    np.testing.assert_allclose(adv, cands.xy[sel.index, steps - CURRENT_STEP - 1], atol=1e-3)
    with pytest.raises(ValueError, match="behavior"):
        make_generator("cat-rcg", candidates="constant_velocity")
    with pytest.raises(ValueError, match="does not exist"):
        make_generator("cat-rcg", candidates="constant_velocity", behavior=str(tmp_path / "none.pt"))
    with pytest.raises(ValueError, match="distance"):
        make_generator("cat-rcg", candidates="constant_velocity", behavior=str(path), distance="cosine")


def test_seal_rcg_ranks_with_rcg_and_keeps_seals_follow_and_switch(tmp_path) -> None:
    s = sf.highway_scenario(4)
    rcg = RCGObjective(small_model(1), n_knn=8)
    gen = make_generator("seal-rcg", candidates="constant_velocity", behavior=rcg, switch="none")
    queue = RolloutHistory().queue(s)
    generation = gen.generate(s, queue, np.random.default_rng(0))
    assert generation.extra["objective"] == "rcg" and generation.extra["switch"] == "none"
    assert generation.chosen_candidate in generation.extra["rcg_kept"]
    assert int(np.argmax(generation.extra["scores"])) == generation.chosen_candidate
    with pytest.raises(ValueError, match="scenario"):
        rcg(None, (4.0, 2.0), np.zeros((1, 91, 2)), np.zeros((1, 91)), np.ones((1, 91), bool),  # type: ignore[arg-type]
            (4.0, 2.0))


def test_the_shared_frame_bank_embeds_like_the_written_out_scenes() -> None:
    s = sf.highway_scenario(5)
    cands = _fan(s, [400.0, 420.0, 380.0])
    ego = s.tracks[s.ego_index].astype(float)
    egos = ego_tracks(s, np.stack([ego[:, [X, Y]], ego[:, [X, Y]] + [3.0, 0.5]]), np.stack([ego[:, 2]] * 2),
                      np.stack([ego[:, VALID] > 0.5] * 2))
    from seal.adversaries.rcg.select import scene_bank
    from seal.models.behavior.features import shared_frame_inputs, target_inputs

    bank, scenes = scene_bank(s, cands.xy, egos)
    model = small_model()
    shared = shared_frame_inputs(bank, scenes, s.adv_index, model.config.features)
    full = target_inputs(perturbed_scenes(s, cands.xy, egos), np.full(6, s.adv_index), model.config.features)
    for field in ("agents", "target_xy"):
        np.testing.assert_allclose(getattr(shared, field), getattr(full, field), atol=1e-5)
    np.testing.assert_array_equal(shared.mask, full.mask)
    np.testing.assert_allclose(model.embed_scenes(bank, scenes, s.adv_index),
                               model.embed_tracks(perturbed_scenes(s, cands.xy, egos), np.full(6, s.adv_index)),
                               atol=1e-5)
