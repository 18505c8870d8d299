"""Behavioural labels of futures: paper 000's activity risk, the proximity risk, paper 002's motion classes, on
hand-made trajectories with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from seal.core.scenario import DT_S, N_FUTURE
from seal.models.steering.labels import (
    RiskConfig,
    activity_risk,
    kinematics,
    mean_speed,
    motion_classes,
    proximity_risk,
)

T = DT_S * np.arange(1, N_FUTURE + 1)
START = np.zeros(2)


def _line(speed: float, acc: float = 0.0) -> np.ndarray:
    s = speed * T + 0.5 * acc * T**2
    return np.stack([s, np.zeros_like(s)], axis=-1)


def _arc(speed: float, yaw_rate: float) -> np.ndarray:
    r = speed / yaw_rate
    phi = yaw_rate * T
    return np.stack([r * np.sin(phi), r * (1 - np.cos(phi))], axis=-1)


def _classes(xy: np.ndarray, v0: float) -> dict[str, int]:
    return {k: int(v) for k, v in motion_classes(xy, START, np.array(v0), np.array(0.0)).items()}


def test_activity_risk_of_constant_speed_is_the_speed_term_only() -> None:
    assert activity_risk(_line(15.0), START) == pytest.approx(0.35 * 15.0 / 30.0)
    speed, acc, yaw = kinematics(_line(15.0), START)
    np.testing.assert_allclose(speed, 15.0)
    assert acc.max() == pytest.approx(0.0, abs=1e-9) and yaw.max() == 0.0


def test_activity_risk_saturates_and_counts_acceleration_and_turning() -> None:
    braking = activity_risk(_line(20.0, acc=-2.0), START)  # stops at 10 s: still braking at 8 s
    assert braking == pytest.approx(0.35 * 20.0 / 30.0 + 0.35 * 2.0 / 4.0, abs=0.02)
    turning = activity_risk(_arc(10.0, 0.25), START)
    assert turning == pytest.approx(0.35 * 10 / 30 + 0.30 * 0.25 / 0.5, abs=0.01)
    assert activity_risk(_arc(40.0, 0.9), START) == pytest.approx(0.35 + 0.30, abs=0.02)  # speed, turn saturated


def test_proximity_risk_is_one_through_the_reference_and_decays_with_distance() -> None:
    fut = _line(10.0)
    ego_valid = np.ones(N_FUTURE, dtype=bool)
    assert proximity_risk(fut, fut, ego_valid) == pytest.approx(1.0)
    far = fut + np.array([0.0, 10.0])
    assert proximity_risk(fut, far, ego_valid) == pytest.approx(np.exp(-1.0))
    assert proximity_risk(fut, far, ego_valid, RiskConfig(proximity_m=5.0)) == pytest.approx(np.exp(-2.0))
    assert proximity_risk(fut, fut, np.zeros(N_FUTURE, dtype=bool)) == 0.0  # never valid: infinitely far
    batch = np.stack([fut, far])  # [2, T, 2]
    np.testing.assert_allclose(proximity_risk(batch, fut, ego_valid), [1.0, np.exp(-1.0)])


def test_motion_classes_of_known_trajectories() -> None:
    assert _classes(_line(20.0), 20.0) == {"speed": 2, "acceleration": 1, "direction": 2, "lane_change": 0}
    assert _classes(_line(3.0), 3.0)["speed"] == 0 and _classes(_line(10.0), 10.0)["speed"] == 1
    assert _classes(_line(5.0, acc=1.0), 5.0)["acceleration"] == 2
    assert _classes(_line(15.0, acc=-1.5), 15.0)["acceleration"] == 0
    assert _classes(_arc(10.0, 0.2), 10.0)["direction"] == 1  # counter-clockwise = left
    assert _classes(_arc(10.0, -0.2), 10.0)["direction"] == 3
    assert _classes(np.zeros((N_FUTURE, 2)), 0.0)["direction"] == 0
    shift = np.clip((T - 2.0) / 3.0, 0, 1)[:, None] * np.array([0.0, 3.5])  # 3.5 m to the left over 3 s
    assert _classes(_line(20.0) + shift, 20.0)["lane_change"] == 1
    assert _classes(_line(20.0) - shift, 20.0)["lane_change"] == 2


def test_mean_speed_is_path_length_over_the_horizon() -> None:
    assert mean_speed(_line(12.0), START) == pytest.approx(12.0)
    assert mean_speed(_arc(12.0, 0.3), START) == pytest.approx(12.0, rel=1e-3)
