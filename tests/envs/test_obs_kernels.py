"""The compiled observation (`seal.envs.obs_kernels`) against the float64 numpy reference it replaced
(`tests/kernel_reference.py`): bit for bit on states recorded from env roll-outs (ego and a reactive skill adversary,
every generated layout), and compiled when the module is imported (no first-call stall)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scenario_factory as sf
from kernel_reference import reference_observation

from seal.core.scenario import CURRENT_STEP, VALID
from seal.envs import obs_kernels
from seal.envs.generate import RunTask, simulate_run
from seal.envs.heuristic import HeuristicDriver
from seal.envs.layouts import LAYOUTS
from seal.envs.observation import ObservationBuilder
from seal.envs.scenario_env import ScenarioEnv
from seal.envs.skill_behavior import SkillSwitchBehavior


class _RandomPolicy:
    """A skill-policy stand-in: seeded random actions (the adversary wanders, so it sees unusual geometry)."""

    def reset(self, seed: int | None = None) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self.rng.uniform(-1.0, 1.0, 2).astype(np.float32)


@pytest.fixture(scope="module")
def generated() -> list:
    """One highway-env traffic run per layout (highway, merge, intersection, roundabout) plus hand-built roads."""
    runs = [simulate_run(RunTask(run=r, layout=LAYOUTS[r], seed=3, kind_shares=(0.7, 0.15, 0.15)))
            for r in range(len(LAYOUTS))]
    return [s for run in runs for s in run] + [sf.curve_scenario(), sf.lane_change_scenario()]


def test_observations_are_bit_identical_to_the_numpy_reference(generated, monkeypatch) -> None:
    """Every observation the env builds in 1500 steps (the ego's and, from the first step, a reactive adversary's)
    equals the reference computed from the same recorded inputs (state, route, projection, box table)."""
    recorded: list[tuple] = []
    build_many = ObservationBuilder.build_many

    def recording(self, states, routes, projections, boxes, self_rows):
        out = build_many(self, states, routes, projections, boxes, self_rows)
        recorded.append((self.geometry, list(states), list(routes), list(projections), boxes.copy(),
                         list(self_rows), out.copy()))
        return out

    monkeypatch.setattr(ObservationBuilder, "build_many", recording)
    env = ScenarioEnv(generated, adversary=SkillSwitchBehavior(_RandomPolicy(), switch_step=CURRENT_STEP))
    driver = HeuristicDriver()
    obs, _ = env.reset(seed=0)
    layouts = set()
    for _ in range(1500):
        layouts.add(env.scenario.road.layout)
        obs, _, terminated, truncated, _ = env.step(driver.predict(obs)[0])
        if terminated or truncated:
            obs, _ = env.reset()
    assert len(layouts) >= 4
    views = 0
    for geom, states, routes, projections, boxes, rows, out in recorded:
        for v, (state, route, proj, row) in enumerate(zip(states, routes, projections, rows, strict=True)):
            present = boxes[:, VALID] > 0.5
            present[row] = False
            ref = reference_observation(geom, state, route, proj, boxes[present, :7])
            np.testing.assert_array_equal(out[v], ref)
            views += 1
    assert views > 2800  # the ego's and the adversary's on nearly every step


def test_box_table_rows_absent_or_the_viewers_own_are_left_out() -> None:
    """A box with valid = 0 or on the viewer's own row never shows in the lidar or the nearest slots."""
    obs = np.zeros(obs_kernels.OBS_DIM, dtype=np.float32)
    segs = np.full((4, 1), np.nan)
    nav = np.array([[-50.0, 500.0], [-50.0, 500.0], [0.0, 0.0], [10.0, 10.0]])
    car = [20.0, 0.0, 0.0, 10.0, 0.0, 5.0, 2.0]
    boxes = np.array([[0.0, 0.0, 0.0, 10.0, 0.0, 5.0, 2.0, 1.0], car + [0.0], car + [1.0]])
    args = (0.0, 0.0, 0.0, 10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, nav, 30.0, segs, segs)
    obs_kernels.observe_viewer(obs, *args, boxes, 0)
    assert obs[obs_kernels.LIDAR_START] == pytest.approx(17.5 / 50.0)
    assert obs[obs_kernels.NEAREST_START] == 1.0 and obs[obs_kernels.NEAREST_START + 5] == 0.0
    boxes[2, 7] = 0.0  # now absent too: nothing left
    obs_kernels.observe_viewer(obs, *args, boxes, 0)
    assert obs[obs_kernels.LIDAR_START] == 1.0 and obs[obs_kernels.NEAREST_START] == 0.0
    boxes[2, 7] = 1.0
    obs_kernels.observe_viewer(obs, *args, boxes[:, :7].copy(), 0)  # no valid column: row 1 counts, nearer first
    assert obs[obs_kernels.NEAREST_START] == 1.0 and obs[obs_kernels.NEAREST_START + 5] == 1.0


def test_kernels_are_compiled_at_import() -> None:
    """Explicit signatures: compiled (or loaded from the cache) when the module is imported, never on a first call;
    a call with other types is refused instead of compiling in the middle of a run."""
    kernel = obs_kernels.observe_viewer
    assert len(kernel.signatures) == 1 and not kernel._can_compile
    obs = np.zeros(obs_kernels.OBS_DIM, dtype=np.float64)  # float64 instead of float32
    segs = np.full((4, 1), np.nan)
    with pytest.raises(TypeError):
        kernel(obs, *(0.0,) * 10, segs, 30.0, segs, segs, np.zeros((0, 7)), -1)
    assert math.isfinite(obs_kernels.LIDAR_REACH2)
