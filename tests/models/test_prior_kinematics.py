"""Prior building blocks with analytic answers: knot interpolation, control integration, drivability measures,
control recovery and k-means anchors, constant velocity."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scenario_factory as sf
import torch

from seal.core.scenario import CURRENT_STEP, DT_S, N_FUTURE
from seal.models.prior import Candidates, constant_velocity_candidates
from seal.models.prior.anchors import future_controls, kmeans
from seal.models.prior.kinematics import integrate_controls, knot_matrix
from seal.models.prior.metrics import displacement_errors, kinematic_limits, top_k_min


def test_knot_matrix_interpolates_linearly() -> None:
    w = knot_matrix(5, 81)  # knots at steps 0, 20, 40, 60, 80
    assert torch.allclose(w.sum(1), torch.ones(81))
    values = torch.tensor([0.0, 2.0, -2.0, 1.0, 3.0])
    per_step = w @ values
    assert per_step[0] == 0.0 and per_step[20] == pytest.approx(2.0) and per_step[80] == pytest.approx(3.0)
    assert per_step[10] == pytest.approx(1.0)  # halfway between knots 0 and 1
    assert per_step[30] == pytest.approx(0.0)
    with pytest.raises(ValueError):
        knot_matrix(1, 80)


def test_zero_controls_give_constant_velocity() -> None:
    speed, course = torch.tensor([10.0]), torch.tensor([0.3])
    xy = integrate_controls(torch.zeros(1, 80), torch.zeros(1, 80), speed, course)[0].double()
    t = torch.arange(1, 81, dtype=torch.float64) * DT_S
    expected = torch.stack([10 * t * math.cos(0.3), 10 * t * math.sin(0.3)], dim=-1)
    assert torch.allclose(xy, expected, atol=1e-3)


def test_integrated_controls_are_recovered_exactly_from_positions() -> None:
    rng = np.random.default_rng(0)
    acc = torch.from_numpy(rng.uniform(-3, 3, (4, 80))).double()
    yaw = torch.from_numpy(rng.uniform(-0.8, 0.8, (4, 80))).double()
    v0 = torch.tensor([5.0, 12.0, 20.0, 8.0], dtype=torch.float64)
    xy = integrate_controls(acc, yaw, v0, torch.zeros(4, dtype=torch.float64)).numpy()
    cands = Candidates.from_positions(xy, np.full(4, 0.25), np.zeros(2), 0.0, agent_index=0)
    expected_speed = np.maximum(0.0, v0.numpy()[:, None] + np.cumsum(acc.numpy() * DT_S, axis=1))
    expected_heading = np.cumsum(yaw.numpy() * DT_S, axis=1)
    assert np.allclose(cands.speed, expected_speed, atol=1e-9)
    assert np.allclose(cands.heading, expected_heading, atol=1e-9)


def test_kinematic_limits_measure_known_motion() -> None:
    t = np.arange(1, 81) * DT_S
    # Constant acceleration 3 m/s^2 along +x from 5 m/s: speed per step 5 + 3 (j + 1) dt.
    v = 5.0 + 3.0 * t
    x = np.cumsum(v * DT_S)
    straight = np.stack([x, np.zeros_like(x)], axis=-1)[None]
    acc, yaw = kinematic_limits(straight, np.zeros(2), 0.0)
    assert acc[0] == pytest.approx(3.0, abs=1e-6) and yaw[0] == pytest.approx(0.0, abs=1e-9)
    # Constant speed 10 m/s, constant yaw rate 0.5 rad/s.
    xy = integrate_controls(torch.zeros(1, 80), torch.full((1, 80), 0.5), torch.tensor([10.0]), torch.zeros(1))
    acc, yaw = kinematic_limits(xy.double().numpy(), np.zeros(2), 0.0)
    assert acc[0] == pytest.approx(0.0, abs=1e-3) and yaw[0] == pytest.approx(0.5, abs=1e-4)
    # Below 1 m/s heading jitter is ignored: a 0.5 m/s zig-zag has no yaw rate.
    zig = np.stack([np.arange(1, 81) * 0.05, 0.01 * (-1.0) ** np.arange(80)], axis=-1)[None]
    assert kinematic_limits(zig, np.zeros(2), 0.0)[1][0] == 0.0


def test_displacement_errors_and_top_k() -> None:
    fut = torch.zeros(1, 4, 2)
    valid = torch.tensor([[True, True, True, False]])
    pred = torch.zeros(1, 3, 4, 2)
    pred[0, 0, :, 0] = 1.0  # 1 m off everywhere
    pred[0, 1, :, 0] = torch.tensor([0.0, 0.0, 3.0, 100.0])  # last valid step 3 m off; invalid step ignored
    pred[0, 2, :, 0] = 0.5
    ade, fde = displacement_errors(pred, fut, valid)
    assert torch.allclose(ade, torch.tensor([[1.0, 1.0, 0.5]]))
    assert torch.allclose(fde, torch.tensor([[1.0, 3.0, 0.5]]))
    logits = torch.tensor([[2.0, 1.0, 0.0]])
    assert top_k_min(ade, logits, 1).item() == 1.0
    assert top_k_min(ade, logits, 3).item() == 0.5


def test_future_controls_recover_a_known_profile() -> None:
    n_knots = 16
    true = torch.zeros(1, 2, n_knots)
    true[0, 0] = torch.linspace(-2.0, 1.0, n_knots)  # acceleration ramp
    true[0, 1] = 0.2  # steady turn
    w = knot_matrix(n_knots, N_FUTURE)
    per_step = (true @ w.T).double()
    start = torch.tensor([[12.0, 0.0]], dtype=torch.float64)
    xy = integrate_controls(per_step[:, 0], per_step[:, 1], start[:, 0], start[:, 1])
    got = future_controls(xy.numpy(), start.numpy(), n_knots)
    assert np.allclose(got, true.numpy(), atol=1e-6)


def test_kmeans_finds_separated_clusters() -> None:
    rng = np.random.default_rng(1)
    centres = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    x = np.concatenate([c + 0.1 * rng.standard_normal((50, 2)) for c in centres])
    found = kmeans(x, 3, seed=0)
    for c in centres:
        assert np.min(np.linalg.norm(found - c, axis=1)) < 0.1


def test_constant_velocity_is_a_straight_line_from_the_velocity() -> None:
    s = sf.curve_scenario()
    a = s.adv_index
    cv = constant_velocity_candidates(s, a)
    row = s.tracks[a, CURRENT_STEP].astype(np.float64)
    t = np.arange(1, 81) * DT_S
    expected = row[:2] + np.stack([row[3] * t, row[4] * t], axis=-1)
    assert cv.n_candidates == 1 and np.allclose(cv.xy[0], expected)
    assert np.allclose(cv.speed, np.hypot(row[3], row[4]), atol=1e-6)
    fan = constant_velocity_candidates(s, a, n_candidates=32)
    assert fan.xy.shape == (32, 80, 2) and np.allclose(fan.xy[0], expected)
    assert np.all(np.diff(fan.probs) <= 0) and fan.probs.sum() == pytest.approx(1.0)
    acc, yaw = kinematic_limits(fan.xy, row[:2], float(row[2]))
    assert np.all(acc <= 1e-6) and np.all(yaw <= 0.5 + 1e-6)
    with pytest.raises(ValueError, match="n_candidates"):
        constant_velocity_candidates(s, a, n_candidates=33)


def test_stopped_candidates_keep_their_last_heading() -> None:
    # Stands still for 2 steps (start heading), drives +x for 3, stops for 2, then drives +y.
    steps = [(0, 0), (0, 0), (1, 0), (1, 0), (1, 0), (0, 0), (0, 0), (0, 1), (0, 1)]
    xy = np.cumsum(np.array(steps, dtype=np.float64), axis=0)[None]
    c = Candidates.from_positions(xy, np.ones(1), np.zeros(2), 0.4, agent_index=0)
    half_pi = math.pi / 2
    assert np.allclose(c.heading[0], [0.4, 0.4, 0, 0, 0, 0, 0, half_pi, half_pi])
    assert np.allclose(c.speed[0], np.array([0, 0, 1, 1, 1, 0, 0, 1, 1]) / DT_S)
