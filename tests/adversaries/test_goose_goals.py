"""GOOSE goals and observation on a hand-built roll-out with known gaps, accelerations and yaw rates."""

from __future__ import annotations

import numpy as np
import pytest

from seal.adversaries.goose.curve import Frame
from seal.adversaries.goose.goals import MAX_GAP_M, achieved_goal, goal_reached, goal_reward, goal_violation, pair_gaps
from seal.adversaries.goose.obs import (
    N_CLOSEST_FEATURES,
    N_ROLLOUT_FEATURES,
    build_observation,
    closest_approach_features,
    observation_size,
    observation_space,
    rollout_features,
)
from seal.adversaries.goose.spec import DECELERATION_GOAL, GooseSpec
from seal.core.scenario import CURRENT_STEP, HEADING, VALID, VX, X, Y
from seal.envs.rollout import Rollout

SPEC = GooseSpec()
T = CURRENT_STEP + 1 + 90
LAST = 60


def _rollout(crash: bool = False, adv_present: bool = True) -> Rollout:
    """Ego (4 x 2 m) drives along y = 0 at 10 m/s; the adversary (4 x 2 m) runs beside it 5 m to the left, except at
    step 30 where it is 3.5 m away (body gap 1.5 m). Its speed jumps 10 -> 10.5 m/s at step 20 and back at 21
    (|acc| 5 m/s^2); its heading is 0.03 rad at step 40 only (|yaw rate| 0.3 rad/s). After the last executed
    step (60) the arrays hold garbage that must be ignored."""
    tracks = np.zeros((2, T, 8), dtype=np.float32)
    t = np.arange(T)
    for i, lateral in ((0, 0.0), (1, 5.0)):
        tracks[i, :, X] = 10.0 * 0.1 * t
        tracks[i, :, Y] = lateral
        tracks[i, :, VX] = 10.0
        tracks[i, :, 5], tracks[i, :, 6], tracks[i, :, VALID] = 4.0, 2.0, 1.0
    tracks[1, 30, Y] = 3.5
    tracks[1, 20, VX] = 10.5
    tracks[1, 40, HEADING] = 0.03
    tracks[1, 70, VX] = 99.0  # beyond last_step
    tracks[1, 75, Y] = 0.0
    if not adv_present:
        tracks[1, CURRENT_STEP + 1 :, :] = 0.0
    return Rollout(
        scenario_id="s", tracks=tracks, agent_ids=np.array([7, 9]), ego_id=7, adv_id=9, last_step=LAST,
        ego_crashes=[(45, 9)] if crash else [],
    )


def test_achieved_goal_measures_gap_acceleration_and_yaw_rate() -> None:
    gaps = pair_gaps(_rollout())
    assert gaps.shape == (LAST - CURRENT_STEP,)
    assert gaps[30 - CURRENT_STEP - 1] == pytest.approx(1.5)
    assert np.nanmax(gaps) == pytest.approx(3.0)
    np.testing.assert_allclose(achieved_goal(_rollout()), [1.5, 5.0, 0.3], rtol=1e-5)
    assert achieved_goal(_rollout(crash=True))[0] == 0.0  # a crash with the adversary is contact
    gone = achieved_goal(_rollout(adv_present=False))
    np.testing.assert_allclose(gone, [MAX_GAP_M, 0.0, 0.0])  # never together; no consecutive valid pair


def test_goal_reached_and_rewards() -> None:
    goal = np.array(DECELERATION_GOAL)
    assert goal_reached(np.array([0.0, 8.0, 0.7]), goal)  # bounds are inclusive
    assert not goal_reached(np.array([0.1, 1.0, 0.1]), goal)
    achieved = np.array([2.0, 9.0, 0.7])
    np.testing.assert_allclose(goal_violation(achieved, goal), [0.2, 0.125, 0.0])
    assert goal_reward(achieved, goal) == pytest.approx(-0.325)
    assert goal_reward(achieved, goal, "sparse") == -1.0
    assert goal_reward(np.array([0.0, 3.0, 0.1]), goal) == 0.0
    assert goal_violation(np.array([50.0, 80.0, 30.0]), goal).tolist() == [5.0, 5.0, 5.0]  # capped terms
    # Batched (HER relabelling): [B, 3] against [B, 3].
    batch_a = np.array([[2.0, 9.0, 0.7], [0.0, 3.0, 0.1], [1.0, 1.0, 1.0]])
    batch_d = np.array([goal, goal, [1.0, 1.0, 1.0]])
    np.testing.assert_allclose(goal_reward(batch_a, batch_d), [-0.325, 0.0, 0.0], atol=1e-6)
    with pytest.raises(ValueError, match="reward kind"):
        goal_reward(achieved, goal, "shaped")


def test_rollout_features_in_the_adversary_frame() -> None:
    r = _rollout()
    frame = Frame(10.0, 5.0, 0.0)  # the adversary at step 10
    feats = rollout_features(r, frame, SPEC)
    assert feats.shape == (SPEC.n_time, N_ROLLOUT_FEATURES)
    steps = CURRENT_STEP + SPEC.obs_stride * np.arange(1, SPEC.n_time + 1)
    inside = steps <= LAST
    np.testing.assert_array_equal(feats[:, -1], inside.astype(np.float32))  # present flag
    assert np.all(feats[~inside] == 0.0)
    i = int(np.flatnonzero(steps == 30)[0])
    # At step 30: ego at (30, 0) world -> (20, -5) local; adversary (30, 3.5) -> (20, -1.5); gap 1.5 m.
    np.testing.assert_allclose(feats[i, :2], np.array([20.0, -5.0]) / 50.0, atol=1e-6)
    np.testing.assert_allclose(feats[i, 2:4], [1.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(feats[i, 5:7], np.array([20.0, -1.5]) / 50.0, atol=1e-6)
    assert feats[i, 4] == pytest.approx(0.5) and feats[i, 7] == pytest.approx(0.5)  # 10 m/s / 20
    assert feats[i, 8] == pytest.approx(0.15)
    closest = closest_approach_features(r, frame, SPEC)
    assert closest.shape == (N_CLOSEST_FEATURES,)
    np.testing.assert_allclose(closest, [20 / 90, 20 / 50, -5 / 50, 20 / 50, -1.5 / 50, 0.5, 0.5], atol=1e-6)


def test_observation_dict_fits_the_space() -> None:
    import scenario_factory as sf

    from seal.adversaries.goose.curve import GooseCurve

    curve = GooseCurve.from_scenario(sf.lane_change_scenario())
    r = _rollout()
    obs = build_observation(SPEC, curve, r, 2, achieved_goal(r))
    space = observation_space(SPEC)
    assert space.contains(obs)
    assert obs["observation"].shape == (observation_size(SPEC),)
    assert obs["observation"][-1] == pytest.approx(2 / SPEC.max_updates)
    np.testing.assert_allclose(obs["desired_goal"], DECELERATION_GOAL)


def test_spec_validation_and_round_trip() -> None:
    spec = GooseSpec(shift_m=3.0, desired_goal=(1.0, 6.0, 0.5))
    assert GooseSpec.from_dict(spec.to_dict()) == spec
    with pytest.raises(ValueError, match="GOOSE spec: unknown key"):
        GooseSpec.from_dict({"shift": 3.0}, where="cfg")
    with pytest.raises(ValueError, match="desired_goal"):
        GooseSpec(desired_goal=(0.0, 8.0))
    with pytest.raises(ValueError, match="reward"):
        GooseSpec(reward="shaped")
    with pytest.raises(ValueError, match="weight bounds"):
        GooseSpec(weight_min=1.5)
