"""CAT's curriculum p(t) = min(1.8 t / T, 0.9) and the callback that pushes it to the env workers."""

from __future__ import annotations

import numpy as np
import pytest

from seal.experiments.training.curriculum import CurriculumCallback, perturb_probability


def test_schedule_values() -> None:
    total = 1_000_000
    assert perturb_probability(0, total) == 0.0
    assert perturb_probability(100_000, total) == pytest.approx(0.18)
    assert perturb_probability(250_000, total) == pytest.approx(0.45)
    assert perturb_probability(500_000, total) == pytest.approx(0.9)  # the cap is reached at half of training
    assert perturb_probability(499_999, total) < 0.9
    assert perturb_probability(750_000, total) == 0.9
    assert perturb_probability(total, total) == 0.9
    assert perturb_probability(2 * total, total) == 0.9


def test_schedule_is_monotone_linear_then_flat() -> None:
    total = 1000
    p = np.array([perturb_probability(t, total) for t in range(total + 1)])
    assert np.all(np.diff(p) >= 0)
    ramp = p[: 500]
    np.testing.assert_allclose(np.diff(ramp), 1.8 / total, rtol=1e-9)
    assert np.all(p[500:] == 0.9)


def test_schedule_options_and_errors() -> None:
    assert perturb_probability(50, 100, slope=1.0, cap=1.0) == 0.5
    assert perturb_probability(100, 100, slope=1.0, cap=1.0) == 1.0
    assert perturb_probability(10, 100, slope=0.0) == 0.0
    with pytest.raises(ValueError, match="total_steps"):
        perturb_probability(1, 0)
    with pytest.raises(ValueError, match="cap"):
        perturb_probability(1, 10, cap=1.5)


class _Env:
    def __init__(self) -> None:
        self.calls: list[float] = []

    def env_method(self, name: str, p: float) -> None:
        assert name == "set_perturb_prob"
        self.calls.append(p)


class _Logger:
    def __init__(self) -> None:
        self.values: dict[str, float] = {}

    def record(self, key: str, value: float) -> None:
        self.values[key] = value


class _Model:
    def __init__(self, env: _Env) -> None:
        self.env, self.logger, self.num_timesteps = env, _Logger(), 0

    def get_env(self) -> _Env:
        return self.env


def test_callback_pushes_schedule_with_bounded_lag() -> None:
    env = _Env()
    model = _Model(env)
    cb = CurriculumCallback(total_steps=1000, resolution=0.01)
    cb.init_callback(model)
    model.num_timesteps = 100  # a resumed run starts where its checkpoint was
    cb.on_training_start({}, {})
    assert env.calls == [pytest.approx(0.18)]
    for t in range(102, 1001, 2):  # two envs: the count moves by 2 per vec step
        model.num_timesteps = t
        cb.on_step()
        assert abs(cb.p - perturb_probability(t, 1000)) < 0.01 + 1e-12
        assert model.logger.values["curriculum/p"] == cb.p
    assert env.calls[-1] == 0.9
    # At most cap / resolution updates (+1 for the start), not one per step.
    assert len(env.calls) <= 0.9 / 0.01 + 2
