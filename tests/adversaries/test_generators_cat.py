"""CAT: the flattened prior, the selector on hand-built candidates (analytic P3 and scores, fallback, validity),
the vectorised box test against a brute-force polygon test, and the generator end to end in `ScenarioEnv`."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf
import shapely

from seal.adversaries.base import make_generator
from seal.adversaries.cat.generator import CATGenerator
from seal.adversaries.cat.select import _fill_invalid, cat_select, flattened_prior, smoothed_heading
from seal.adversaries.history import RolloutHistory
from seal.core.geometry import box_corners, boxes_overlap, obb_overlap
from seal.core.scenario import CURRENT_STEP, DT_S, N_FUTURE, N_STEPS, X, Y
from seal.envs.behaviors import ReplayBehavior, TrackingBehavior
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation.episodes import run_episode
from seal.experiments.training.egos import ReplayEgo
from seal.models.prior.candidates import Candidates

SIZE = (4.5, 2.0)
STEPS = np.arange(N_STEPS)
FUT_S = DT_S * np.arange(1, N_FUTURE + 1)  # time since the current step of candidate row j


def ego_along_x(speed: float = 10.0, k: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K identical ego roll-outs driving +x at ``speed`` through x = 0 at the current step."""
    xy = np.zeros((k, N_STEPS, 2))
    xy[:, :, 0] = speed * DT_S * (STEPS - CURRENT_STEP)
    return xy, np.zeros((k, N_STEPS)), np.ones((k, N_STEPS), dtype=bool)


def crossing(x_cross: float, t_cross_s: float, speed: float = 10.0) -> np.ndarray:
    """``[N_FUTURE, 2]``: driving +y along x = ``x_cross``, at y = 0 after ``t_cross_s``."""
    return np.stack([np.full(N_FUTURE, x_cross), speed * (FUT_S - t_cross_s)], axis=1)


def select(cands_xy: np.ndarray, probs: np.ndarray, ego: tuple[np.ndarray, np.ndarray, np.ndarray], **kw):
    heading = np.arctan2(np.gradient(cands_xy[..., 1], axis=1), np.gradient(cands_xy[..., 0], axis=1))
    return cat_select(cands_xy, heading, probs, SIZE, *ego, SIZE, **kw)


def test_flattened_prior_gives_modes_after_the_seventh_the_seventh_score() -> None:
    p = np.array([0.3, 0.2, 0.1, 0.1, 0.08, 0.07, 0.05, 0.04, 0.03, 0.02, 0.01])
    p1 = flattened_prior(p)
    expected = np.concatenate([p[:7], np.full(4, p[6])])
    np.testing.assert_allclose(p1, expected / expected.sum(), rtol=1e-12)
    # Rank, not position, decides: a shuffled input gives the shuffled answer; logits take precedence.
    perm = np.random.default_rng(0).permutation(p.size)
    np.testing.assert_allclose(flattened_prior(p[perm]), (expected / expected.sum())[perm], rtol=1e-12)
    logits = np.log(p) + 3.0
    np.testing.assert_allclose(flattened_prior(np.ones(11) / 11, logits=logits), p1, rtol=1e-12)
    np.testing.assert_allclose(flattened_prior(p[:5]), p[:5] / p[:5].sum(), rtol=1e-12)


def test_earlier_crossing_outranks_later_one_with_analytic_p3() -> None:
    ego = ego_along_x(k=3)
    cands = np.stack([crossing(50.0, 5.0), crossing(20.0, 2.0)])  # late one listed first
    sel = select(cands, np.array([0.5, 0.5]), ego)
    assert sel.index == 1 and sel.collided
    assert sel.predicted_step == CURRENT_STEP + 20  # 2 s
    # Samples every 0.5 s from 0.5 s: 2 s is sample 3, 5 s is sample 9; P3 = 0.99^(k+1), same for all roll-outs.
    np.testing.assert_array_equal(sel.first_hit, [[9, 9, 9], [3, 3, 3]])
    np.testing.assert_allclose(sel.p3, [[0.99**10] * 3, [0.99**4] * 3], rtol=1e-12)
    np.testing.assert_allclose(sel.scores, [3 * 0.5 * 0.99**10, 3 * 0.5 * 0.99**4], rtol=1e-12)
    np.testing.assert_array_equal(sel.sample_steps, CURRENT_STEP + 5 * np.arange(1, 17))


def test_prior_trades_against_collision_time() -> None:
    ego = ego_along_x()
    cands = np.stack([crossing(20.0, 2.0), crossing(50.0, 5.0)])
    # 0.48 * 0.99^4 = 0.4611 < 0.52 * 0.99^10 = 0.4703: the more likely, later crossing wins.
    assert select(cands, np.array([0.48, 0.52]), ego).index == 1
    assert select(cands, np.array([0.5, 0.5]), ego).index == 0


def test_scores_sum_over_rollouts() -> None:
    xy, heading, valid = ego_along_x(k=2)
    valid[1, CURRENT_STEP + 15 :] = False  # roll-out 1 ended (e.g. crashed) after 1.5 s
    cands = np.stack([crossing(20.0, 2.0), crossing(10.0, 1.0)])
    sel = select(cands, np.array([0.6, 0.4]), (xy, heading, valid))
    np.testing.assert_array_equal(sel.first_hit, [[3, -1], [1, 1]])
    np.testing.assert_allclose(sel.scores, [0.6 * 0.99**4, 0.4 * 2 * 0.99**2], rtol=1e-12)
    assert sel.index == 1  # hits both roll-outs: 0.784 > 0.576


def test_no_collision_falls_back_to_closest_candidate() -> None:
    ego = ego_along_x()
    # Parallel to the ego, nearest lateral gap at t = 3 s: 6 m + |t - 3| for the middle one, 8 / 10 m otherwise.
    ego_x = 10.0 * FUT_S
    gaps = [10.0 + np.abs(FUT_S - 3.0), 6.0 + np.abs(FUT_S - 3.0), 8.0 + np.abs(FUT_S - 3.0)]
    cands = np.stack([np.stack([ego_x, g], axis=1) for g in gaps])
    sel = select(cands, np.array([0.5, 0.2, 0.3]), ego)
    assert not sel.collided and sel.index == 1
    assert sel.predicted_step == CURRENT_STEP + 30
    np.testing.assert_allclose(sel.min_distance_m, [10.0, 6.0, 8.0], atol=1e-9)
    np.testing.assert_array_equal(sel.scores, 0.0)


def test_box_test_matches_brute_force_polygons() -> None:
    rng = np.random.default_rng(3)
    n_c, n_k = 12, 4
    ego = (rng.normal(0, 3, (n_k, N_STEPS, 2)).cumsum(1) * 0.2, rng.uniform(-3, 3, (n_k, N_STEPS)),
           rng.random((n_k, N_STEPS)) > 0.1)
    ego[2][:, :CURRENT_STEP + 1] = True
    cands = rng.normal(0, 3, (n_c, N_FUTURE, 2)).cumsum(1) * 0.2
    heading = rng.uniform(-3, 3, (n_c, N_FUTURE))
    sel = cat_select(cands, heading, np.full(n_c, 1 / n_c), SIZE, *ego, (4.0, 1.8))
    rows = 5 * np.arange(1, 17) - 1
    steps = CURRENT_STEP + 1 + rows
    c_h = smoothed_heading(cands, heading, rows)
    e_xy = _fill_invalid(ego[0], ego[2])
    e_h = smoothed_heading(ego[0], ego[1], steps, valid=ego[2])
    n_hits = 0
    for j in range(n_c):
        for i in range(n_k):
            first = -1
            for s, (r, t) in enumerate(zip(rows, steps, strict=True)):
                a = shapely.Polygon(box_corners(*cands[j, r], c_h[j, s], *SIZE))
                b = shapely.Polygon(box_corners(*e_xy[i, t], e_h[i, s], 4.0, 1.8))
                if ego[2][i, t] and a.intersects(b):
                    first = s
                    break
            assert sel.first_hit[j, i] == first
            n_hits += first >= 0
    assert n_hits > 5  # the random walk does produce overlaps to compare


def test_centre_form_box_test_matches_corner_form() -> None:
    rng = np.random.default_rng(5)
    n = 20000
    a = (rng.uniform(-4, 4, n), rng.uniform(-4, 4, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(1, 6, n),
         rng.uniform(0.5, 2.5, n))
    b = (rng.uniform(-4, 4, n), rng.uniform(-4, 4, n), rng.uniform(-np.pi, np.pi, n), rng.uniform(1, 6, n),
         rng.uniform(0.5, 2.5, n))
    fast = obb_overlap(*a, *b)
    assert 0.2 < fast.mean() < 0.8  # both outcomes well represented
    np.testing.assert_array_equal(fast, boxes_overlap(box_corners(*a), box_corners(*b)))


def test_smoothed_heading_is_the_chord_direction_and_holds_when_still() -> None:
    t = np.arange(20.0)
    xy = np.stack([t, 0.5 * t], axis=1)[None]
    xy[0, 12:] = xy[0, 11]  # stops at row 11
    h = smoothed_heading(xy, np.full((1, 20), 0.7), np.array([5, 16]))
    np.testing.assert_allclose(h, [[np.arctan2(0.5, 1.0), 0.7]])


def _stopping_candidates(scenario) -> Candidates:
    """Adversary of the lane-change scenario: keep 27 m/s (likely) or brake to a stop at 6 m/s^2 (unlikely)."""
    adv = scenario.track(scenario.adv_id)
    x0, y0 = adv[CURRENT_STEP, X], adv[CURRENT_STEP, Y]
    v0 = 27.0
    keep = x0 + v0 * FUT_S
    t_stop = np.minimum(FUT_S, v0 / 6.0)
    brake = x0 + v0 * t_stop - 3.0 * t_stop**2
    xy = np.stack([np.stack([keep, np.full(N_FUTURE, y0)], 1), np.stack([brake, np.full(N_FUTURE, y0)], 1)])
    return Candidates.from_positions(xy, np.array([0.9, 0.1]), np.array([x0, y0]), 0.0, scenario.adv_index)


@pytest.mark.parametrize("follow", ["replay", "track"])
def test_cat_generator_picks_the_colliding_candidate_and_the_ego_hits_it(follow: str) -> None:
    scenario = sf.lane_change_scenario()
    gen = CATGenerator(candidate_source=_stopping_candidates, follow=follow)
    history = RolloutHistory()
    generation = gen.generate(scenario, history.queue(scenario), np.random.default_rng(0))
    assert generation.chosen_candidate == 1 and generation.extra["collision_predicted"]
    assert isinstance(generation.behavior, ReplayBehavior if follow == "replay" else TrackingBehavior)
    assert generation.generation_time_s > 0
    rollout = run_episode(ScenarioEnv(scenario), scenario, ReplayEgo(), generation.behavior)
    assert rollout.outcome == "crash" and rollout.ego_crashes[0][1] == scenario.adv_id
    # The replayed ego meets the braking adversary within one sample (0.5 s) of the predicted step.
    assert abs(rollout.first_crash_step - generation.predicted_step) <= 5


def test_cat_needs_exactly_one_candidate_source() -> None:
    with pytest.raises(ValueError, match="--prior"):
        make_generator("cat")
    with pytest.raises(ValueError, match="exactly one"):
        make_generator("cat", candidates="lanes", prior="x.pt")
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        make_generator("cat", prior="missing.pt")
    with pytest.raises(ValueError, match="unknown candidate source"):
        make_generator("cat", candidates="bogus")
    with pytest.raises(ValueError, match="follow"):
        make_generator("cat", candidates="lanes", follow="teleport")


def test_cat_reads_candidates_from_a_prior_file_and_the_constant_velocity_fan(tmp_path) -> None:
    from seal.models.prior import TrajectoryPrior

    path = tmp_path / "prior.pt"
    TrajectoryPrior.untrained(seed=0).save(path)
    scenario = sf.highway_scenario(1)
    queue = RolloutHistory().queue(scenario)
    cat_prior = make_generator("cat", prior=str(path))
    for gen in (cat_prior, make_generator("cat", candidates="constant_velocity")):
        generation = gen.generate(scenario, queue, np.random.default_rng(0))
        assert generation.extra["n_candidates"] == 32 and 0 <= generation.chosen_candidate < 32
        assert CURRENT_STEP < generation.predicted_step <= CURRENT_STEP + N_FUTURE
        assert generation.extra["candidate_time_s"] < generation.generation_time_s


def test_loading_a_prior_leaves_torch_threads_to_the_entry_point(tmp_path) -> None:
    import torch

    from seal.models.prior import TrajectoryPrior

    path = tmp_path / "prior.pt"
    TrajectoryPrior.untrained(seed=0).save(path)
    before = torch.get_num_threads()
    other = 2 if before != 2 else 3
    torch.set_num_threads(other)
    try:
        make_generator("cat", prior=str(path))  # library code: the process's setting stays (entry points set it)
        assert torch.get_num_threads() == other
    finally:
        torch.set_num_threads(before)
