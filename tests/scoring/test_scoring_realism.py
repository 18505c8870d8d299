"""Criticality (f_coll, f_diff) and realism / collision metrics with analytic answers."""

from __future__ import annotations

import numpy as np
import pytest
from scoring_builders import straight_track

from seal.core.geometry import box_corners
from seal.core.scenario import HEADING, VX
from seal.scoring.criticality import f_coll, f_diff
from seal.scoring.realism import (
    ACC_BINS,
    OFFROAD_BINS,
    collision_metrics,
    contact_normal,
    histogram_wasserstein,
    realism_wd,
)


def test_f_coll_and_f_diff() -> None:
    t = np.arange(10, dtype=float)
    ego = np.stack([t, np.zeros(10)], axis=1)
    adv = np.stack([t, np.full(10, 8.0)], axis=1)
    assert f_coll(ego, adv) == pytest.approx(np.exp(-1.0))  # min distance 8 m = b
    assert f_coll(ego, adv, crashed=True) == 1.0
    assert f_diff(ego, ego) == 0.0
    assert f_diff(ego, ego + [0.0, 1.0]) == pytest.approx(1.0 - np.exp(-10.0 / 8.0))  # 10 steps x 1 m
    # Batches broadcast: 3 ego roll-outs x 4 candidates.
    egos = np.broadcast_to(ego, (3, 1, 10, 2))
    advs = np.stack([adv + [0.0, k] for k in range(4)])[None]
    out = f_coll(egos, advs)
    assert out.shape == (3, 4)
    np.testing.assert_allclose(out[0], np.exp(-(8.0 + np.arange(4)) / 8.0))
    valid = np.zeros(10, dtype=bool)
    assert f_coll(ego, adv, valid=valid) == 0.0


def test_histogram_wasserstein() -> None:
    rng = np.random.default_rng(0)
    a = rng.normal(size=1000)
    assert histogram_wasserstein(a, a.copy(), ACC_BINS) == 0.0
    width = ACC_BINS[1] - ACC_BINS[0]
    centres = 0.5 * (ACC_BINS[1:] + ACC_BINS[:-1])
    # All mass in one bin vs three bins further: W1 = 3 bin widths.
    assert histogram_wasserstein(np.full(5, centres[10]), np.full(7, centres[13]), ACC_BINS) == pytest.approx(
        3 * width
    )
    # Out-of-road flags: W1 = difference of the rates.
    assert histogram_wasserstein(np.array([0, 0, 1, 1.0]), np.zeros(4), OFFROAD_BINS) == pytest.approx(0.5)


def test_realism_of_identical_adversaries_is_zero() -> None:
    tracks = np.stack([straight_track(0.0, 10.0 + k) for k in range(3)])
    tracks[1, 40:, VX] += 2.0  # some acceleration
    out = realism_wd(tracks, tracks.copy(), np.array([0, 1, 0]), np.array([0, 1, 0]))
    assert out == {"yaw_wd": 0.0, "acc_wd": 0.0, "road_wd": 0.0, "realism": 0.0}
    shifted = realism_wd(tracks, tracks, np.array([1, 1, 0]), np.array([0, 1, 0]))
    assert shifted["road_wd"] == pytest.approx(1 / 3)
    assert shifted["realism"] == pytest.approx(1 / 9)


def test_head_on_classification() -> None:
    # Ego drives +x at 10 m/s from x = 0, the adversary -x at 10 m/s from x = 40: fronts meet at t ~ 1.78 s.
    ego = straight_track(0.0, 10.0)
    adv = straight_track(40.0, -10.0)
    adv[:, HEADING] = np.pi
    out = collision_metrics([ego], [adv])
    assert out["collisions"] == 1 and out["head_on_rate"] == 1.0 and out["severe_head_on_rate"] == 1.0
    assert out["collision_speed_mps"] == pytest.approx(20.0)
    # Same, but slowly (2 m/s each): head-on, not severe.
    slow_e, slow_a = straight_track(0.0, 2.0), straight_track(12.0, -2.0)
    slow_a[:, HEADING] = np.pi
    out = collision_metrics([ego, slow_e], [adv, slow_a])
    assert out["head_on_rate"] == 1.0 and out["severe_head_on_rate"] == 0.5
    # A rear-end collision is not head-on; no collision at all counts in the rates' denominators only.
    rear = collision_metrics([straight_track(0.0, 20.0), straight_track(0.0, 10.0)],
                             [straight_track(20.0, 10.0), straight_track(0.0, 10.0, y=30.0)])
    assert rear["collisions"] == 1 and rear["head_on_rate"] == 0.0 and rear["collision_rate"] == 0.5
    assert rear["collision_speed_mps"] == pytest.approx(10.0)


def test_contact_normal_of_frontal_overlap() -> None:
    a = box_corners(0.0, 0.0, 0.0, 4.5, 2.0)
    b = box_corners(4.0, 0.3, np.pi, 4.5, 2.0)
    np.testing.assert_allclose(contact_normal(a, b), [1.0, 0.0], atol=1e-9)


def test_jerk_is_the_second_difference_of_the_speed_and_compares_profiles() -> None:
    from seal.scoring.realism import jerk_stats, jerks

    t = np.zeros((6, 8))
    t[:, 3] = [10.0, 10.0, 11.0, 12.0, 12.0, 12.0]  # speed: +1 m/s per step twice, then constant
    t[:, 7] = 1.0
    # Accelerations 0, 10, 10, 0, 0 m/s^2 -> jerks 100, 0, -100, 0 m/s^3.
    np.testing.assert_allclose(jerks(t), [100.0, 0.0, -100.0, 0.0])
    t[3, 7] = 0.0  # an invalid step breaks every triple through it
    np.testing.assert_allclose(jerks(t), [100.0])
    smooth = np.zeros((1, 30, 8))
    smooth[0, :, 3] = np.linspace(10.0, 13.0, 30)  # constant acceleration: jerk 0
    smooth[0, :, 7] = 1.0
    rough = smooth.copy()
    rough[0, ::2, 3] += 0.3
    same = jerk_stats(smooth, smooth)
    assert same["jerk_wd"] == 0.0 and same["jerk_abs_p95"] == pytest.approx(0.0, abs=1e-6)
    diff = jerk_stats(rough, smooth)
    assert diff["jerk_wd"] > 10.0 and diff["jerk_abs_p95"] > 50.0 and diff["logged_jerk_abs_p95"] < 1e-6


def test_acceleration_stats_give_the_direction_of_the_difference() -> None:
    from seal.scoring.realism import acceleration_stats

    brake = np.zeros((5, 8))
    brake[:, 3] = [20.0, 19.0, 18.8, 18.6, 18.4]  # -10, -2, -2, -2 m/s^2
    brake[:, 7] = 1.0
    cruise = brake.copy()
    cruise[:, 3] = [20.0, 20.1, 20.2, 20.2, 20.1]  # +1, +1, 0, -1 m/s^2
    got = acceleration_stats([brake], [cruise])
    assert got["acc_mean_mps2"] == pytest.approx(-4.0)
    assert got["logged_acc_mean_mps2"] == pytest.approx(0.25)
    assert got["hard_brake_share"] == pytest.approx(0.25)  # one of four steps below -3 m/s^2
    assert got["logged_hard_brake_share"] == 0.0
    brake[2, 7] = 0.0  # an invalid step drops both differences through it: -10 and -2 are left
    assert acceleration_stats([brake], [cruise])["acc_mean_mps2"] == pytest.approx(-6.0)
    assert np.isnan(acceleration_stats([brake[:1]], [cruise])["acc_mean_mps2"])
