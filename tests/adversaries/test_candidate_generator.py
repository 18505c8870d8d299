"""`CandidateGenerator`: what CAT and SEAL share (candidate source, context with stacked roll-outs and box sizes,
timing, follow behaviour), tested through a minimal subclass that only chooses."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import scenario_factory as sf

from seal.adversaries.base import Generation
from seal.adversaries.candidate_generator import (
    FOLLOW_MODES,
    CandidateContext,
    CandidateGenerator,
    Follow,
    stack_ego_rollouts,
)
from seal.adversaries.candidate_path import candidate_track
from seal.adversaries.cat.generator import CATGenerator
from seal.adversaries.history import RolloutHistory, logged_rollout
from seal.adversaries.seal.generator import SEALGenerator
from seal.core.scenario import CURRENT_STEP, HEADING, LENGTH, N_FUTURE, VALID, WIDTH, Scenario, X, Y
from seal.envs.behaviors import ReplayBehavior, TrackingBehavior
from seal.models.prior.candidates import Candidates


def _straight_candidates(scenario: Scenario) -> Candidates:
    """Three constant-velocity futures of the adversary at 0.5x, 1x and 1.5x its current velocity."""
    now = scenario.tracks[scenario.adv_index, CURRENT_STEP]
    t = 0.1 * np.arange(1, N_FUTURE + 1)[:, None]
    xy = np.stack([now[[X, Y]] + f * t * now[[3, 4]] for f in (0.5, 1.0, 1.5)])
    heading = np.full((3, N_FUTURE), now[HEADING])
    speed = np.linalg.norm(xy[:, 1:] - xy[:, :-1], axis=-1)
    return Candidates(xy=xy, heading=heading, speed=np.pad(speed, ((0, 0), (0, 1)), mode="edge"),
                      probs=np.array([0.2, 0.5, 0.3]), agent_index=scenario.adv_index)


class TakeSecond(CandidateGenerator):
    """Chooses candidate 1 and records the context it was given."""

    name = "take-second"

    def _choose(self, context: CandidateContext, rng: np.random.Generator) -> Generation:
        self.seen = context
        return Generation(behavior=self.follow_behavior(context.scenario, context.cands.xy[1]), chosen_candidate=1,
                          extra={**context.candidate_extra(), "select_time_s": context.since_candidates_s()})


def test_subclass_gets_candidates_sizes_and_stacked_rollouts() -> None:
    scenario = sf.highway_scenario(2)
    history = RolloutHistory().queue(scenario)
    gen = TakeSecond(candidate_source=_straight_candidates)
    generation = gen.generate(scenario, history, np.random.default_rng(0))
    ctx = gen.seen
    now = scenario.tracks[:, CURRENT_STEP]
    assert ctx.adv_size_m == (now[scenario.adv_index, LENGTH], now[scenario.adv_index, WIDTH])
    assert ctx.ego_size_m == (now[scenario.ego_index, LENGTH], now[scenario.ego_index, WIDTH])
    xy, heading, valid = stack_ego_rollouts(history)
    assert np.array_equal(ctx.ego_xy, xy) and np.array_equal(ctx.ego_heading, heading)
    assert np.array_equal(ctx.ego_valid, valid)
    assert generation.chosen_candidate == 1
    assert generation.extra["n_candidates"] == 3 and generation.extra["candidate_fallback"] == ""
    assert 0.0 <= generation.extra["candidate_time_s"] <= generation.generation_time_s
    assert generation.extra["select_time_s"] >= 0.0


def test_follow_modes_give_the_replayed_track_or_the_tracking_controller() -> None:
    scenario = sf.highway_scenario(2)
    history = RolloutHistory().queue(scenario)
    rng = np.random.default_rng(0)
    replay = TakeSecond(candidate_source=_straight_candidates).generate(scenario, history, rng).behavior
    assert isinstance(replay, ReplayBehavior)
    expected = candidate_track(scenario, scenario.adv_index, _straight_candidates(scenario).xy[1])
    assert np.array_equal(replay._given, expected)
    track = TakeSecond(candidate_source=_straight_candidates, follow="track").generate(scenario, history, rng)
    assert isinstance(track.behavior, TrackingBehavior)
    assert FOLLOW_MODES == ("replay", "track") and Follow("track") == "track"


def test_shared_checks_name_the_generator() -> None:
    scenario = sf.highway_scenario(2)
    with pytest.raises(ValueError, match="take-second: empty roll-out history"):
        TakeSecond(candidate_source=_straight_candidates).generate(scenario, (), np.random.default_rng(0))
    with pytest.raises(ValueError, match="take-second: follow must be one of replay, track"):
        TakeSecond(candidate_source=_straight_candidates, follow="teleport")
    with pytest.raises(ValueError, match="exactly one candidate source"):
        TakeSecond()


def test_cat_and_seal_are_candidate_generators() -> None:
    assert issubclass(CATGenerator, CandidateGenerator) and issubclass(SEALGenerator, CandidateGenerator)


def test_stacking_pads_shorter_rollouts_as_invalid() -> None:
    scenario = sf.highway_scenario(3)
    full = logged_rollout(scenario)
    short = replace(full, tracks=full.tracks[:, :60].copy())
    xy, heading, valid = stack_ego_rollouts([short, full])
    ego = full.ego_track
    assert xy.shape == (2, ego.shape[0], 2) and heading.shape == valid.shape == (2, ego.shape[0])
    assert np.array_equal(xy[1], ego[:, [X, Y]]) and np.array_equal(heading[0, :60], ego[:60, HEADING])
    assert not valid[0, 60:].any() and np.array_equal(valid[0, :60], ego[:60, VALID] > 0.5)


def test_uses_prior_file_tells_entry_points_to_set_prior_threads(tmp_path) -> None:
    from seal.adversaries.candidate_generator import uses_prior_file
    from seal.adversaries.replay import ReplayGenerator
    from seal.models.prior import TrajectoryPrior

    path = tmp_path / "prior.pt"
    TrajectoryPrior.untrained(seed=0).save(path)
    with_prior = CATGenerator(prior=path)
    assert with_prior.prior_file == path
    assert uses_prior_file([ReplayGenerator(), with_prior])
    assert not uses_prior_file([ReplayGenerator(), CATGenerator(candidates="lanes")])
