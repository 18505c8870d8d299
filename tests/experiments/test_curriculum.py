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


# ------------------------------------------------------------- edges that mutation testing found untested
def test_schedule_edges_and_warmup() -> None:
    assert perturb_probability(1, 1, slope=1.0, cap=1.0) == 1.0  # a one-step run is a run
    assert perturb_probability(5, 10, cap=0.0) == 0.0  # cap 0: never perturbed, and allowed
    # Warm-up: nothing before warmup * T, then the ramp starts there.
    assert perturb_probability(400, 1000, warmup=0.5) == 0.0
    assert perturb_probability(600, 1000, warmup=0.5) == pytest.approx(1.8 * 0.1)
    for bad in ({"warmup": 1.0}, {"warmup": -0.1}, {"slope": -1.0}, {"cap": -0.1}):
        with pytest.raises(ValueError, match="curriculum: need slope >= 0"):
            perturb_probability(1, 10, **bad)


def test_callback_default_resolution_and_the_exact_step() -> None:
    """The default resolution (0.005) pushes a change of 0.005; a change of exactly ``resolution`` is pushed; the
    callback never stops training."""
    env = _Env()
    model = _Model(env)
    cb = CurriculumCallback(total_steps=1800)  # p moves by 0.001 per step
    cb.init_callback(model)
    cb.on_training_start({}, {})
    model.num_timesteps = 4
    assert cb.on_step() is True and env.calls == [0.0]
    model.num_timesteps = 5
    cb.on_step()
    assert env.calls == [0.0, pytest.approx(0.005)]
    exact = CurriculumCallback(total_steps=4, slope=1.0, cap=1.0, resolution=0.25)
    exact_env = _Env()
    exact.init_callback(_Model(exact_env))
    exact.on_training_start({}, {})
    exact.model.num_timesteps = 1  # p = 0.25: exactly one resolution away
    exact.on_step()
    assert exact_env.calls == [0.0, 0.25]
