"""``seal eval avoidability``: the plan family, and the search on crashes built to be avoidable or not."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest

from seal.adversaries.base import Generation
from seal.core.scenario import CURRENT_STEP, Scenario
from seal.envs.behaviors import ReplayBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation import avoidability as av

VX, VY, VALID = 3, 4, 7


def test_plan_family_is_the_structured_plans_then_bounded_random_ones() -> None:
    config = av.AvoidabilityConfig(n_plans=40, segments=5, max_accel_offset=1.5, max_steer_offset=0.2, seed=3)
    plans = av.plan_offsets(config, np.random.default_rng(3))
    assert len(plans) == 40 and all(p.shape == (5, 2) for p in plans)
    for first in range(5):  # braking then throttle from each segment on, heuristic steering
        brake, throttle = plans[2 * first], plans[2 * first + 1]
        assert np.all(brake[:first] == 0) and np.all(brake[first:, 1] == -2.0) and np.all(brake[:, 0] == 0)
        assert np.all(throttle[first:, 1] == 2.0)
    rest = np.stack(plans[10:])
    assert np.abs(rest[..., 1]).max() <= 1.5 and np.abs(rest[..., 0]).max() <= 0.2
    steered = (rest[..., 0] != 0).mean()
    assert 0.3 < steered < 0.7  # steer_share 0.5 of the segments
    again = av.plan_offsets(config, np.random.default_rng(3))
    assert all(np.array_equal(a, b) for a, b in zip(plans, again, strict=True))
    assert len(av.plan_offsets(av.AvoidabilityConfig(n_plans=3), np.random.default_rng(0))) == 3
    with pytest.raises(ValueError, match="steer_share"):
        av.AvoidabilityConfig(steer_share=2.0)


def test_plan_ego_adds_its_segment_offset_to_the_heuristic_action(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv])
    obs, info = env.reset(seed=0)
    offsets = np.array([[0.0, 0.0], [0.1, -0.5], [0.0, 5.0]])
    plan = av.PlanEgo(offsets, segment_steps=2)
    plan.reset(stopped_adv)
    driver = HeuristicDriver()
    base = driver.act(obs)
    step = info["step"]
    assert np.array_equal(plan.act(obs, step), np.clip(base, -1, 1))
    assert np.allclose(plan.act(obs, step + 2), np.clip(base + [0.1, -0.5], -1, 1))
    assert plan.act(obs, step + 4)[1] == 1.0 and plan.act(obs, step + 40)[1] == 1.0  # last segment holds; clipped


class _FixedGenerator:
    """A generator stub: every pass replays the same track as the adversary."""

    name: ClassVar[str] = "fixed"

    def __init__(self, track: np.ndarray) -> None:
        self.track = track

    def generate(self, scenario: Scenario, queue: Any, rng: np.random.Generator) -> Generation:
        return Generation(ReplayBehavior(self.track))


class _FullThrottle:
    """A blind ego: straight ahead at full throttle."""

    name = "blind"

    def reset(self, scenario: Scenario) -> None:
        pass

    def act(self, observation: np.ndarray, step: int) -> np.ndarray:
        return np.array([0.0, 1.0])


def _stopped_track(scenario: Scenario) -> np.ndarray:
    track = scenario.track(scenario.adv_id).astype(np.float64).copy()
    track[:] = track[CURRENT_STEP]
    track[:, [VX, VY]] = 0.0
    return track


def test_a_car_stopped_ahead_is_avoidable(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv])
    row = av.probe_scenario(env, stopped_adv, 0, _FullThrottle(), _FixedGenerator(_stopped_track(stopped_adv)),
                            k=2, seed=0, config=av.AvoidabilityConfig(n_plans=8))
    assert row.outcome == "crash" and row.crash_with == "adversary" and row.reproducible
    assert row.heuristic_outcome not in av.FAILED  # the heuristic driver brakes for it
    assert row.avoidable
    # It stops behind the car (the route's end lies beyond it): the search goes on for a plan reaching the goal.
    assert row.heuristic_outcome == "timeout" and row.plans_tried == 8
    assert row.avoidable_reaching_goal is False
    assert row.first_avoiding_plan == "heuristic" and row.first_goal_plan == ""
    assert [av.plan_label(i, av.AvoidabilityConfig(n_plans=14, segments=6)) for i in (0, 1, 2, 11, 12)] == [
        "brake@0", "throttle@0", "brake@1", "throttle@5", "random"]


def test_an_adversary_on_the_ego_itself_is_not_avoidable(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv])
    on_the_ego = stopped_adv.track(stopped_adv.ego_id).astype(np.float64)
    row = av.probe_scenario(env, stopped_adv, 0, _FullThrottle(), _FixedGenerator(on_the_ego), k=1, seed=0,
                            config=av.AvoidabilityConfig(n_plans=6))
    assert row.outcome == "crash" and row.crash_with == "adversary" and row.crash_step == CURRENT_STEP + 1
    assert row.reproducible and row.avoidable is False and row.avoidable_reaching_goal is False
    assert row.plans_tried == 6 and row.first_avoiding_plan == row.first_goal_plan == ""


def test_an_episode_without_crash_is_not_searched(stopped_adv: Scenario) -> None:
    row = av.probe_scenario(ScenarioEnv([stopped_adv]), stopped_adv, 0, av.PlanEgo(np.zeros((1, 2)), 1), None, k=1,
                            seed=0, config=av.AvoidabilityConfig())
    assert row.outcome == "success" and row.crash_with == "" and row.avoidable is None and row.plans_tried == 0


def test_summary_counts_by_whom_the_ego_touched() -> None:
    R = av.ProbeRow
    rows = [R("a", "crash", "adversary", 20, True, "crash", True, True, 3, "brake@0", "throttle@0"),
            R("b", "crash", "adversary", 30, True, "success", True, True, 0, "heuristic", "heuristic"),
            R("c", "crash", "adversary", 30, True, "crash", False, False, 64),
            R("d", "crash", "adversary", 30, False),
            R("e", "crash", "other", 40, True, "crash", True, False, 64),
            R("f", "success")]
    s = av.summarize(rows)
    assert s["scenarios"] == 6 and s["crashes"] == 5
    assert s["adversary"] == {"crashes": 4, "reproducible": 3, "avoidable": 2, "avoidable_reaching_goal": 2,
                              "heuristic_avoids": 1, "first_goal_plan": {"heuristic": 1, "throttle": 1},
                              "avoidable_share": 0.6667, "avoidable_reaching_goal_share": 0.6667}
    assert s["other"]["avoidable"] == 1 and s["other"]["avoidable_reaching_goal"] == 0
    text = av.format_summary(s, "heuristic", "cat")
    assert "5 crashes in 6 scenarios" in text and "2 (66.7 %)" in text
    assert "past the adversary, first by: heuristic 1, throttle 1" in text


def test_command_writes_rows_and_summary(stopped_adv: Scenario, lane_change: Scenario, tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    from seal.cli import main
    from seal.core.dataset import write_dataset

    ds = write_dataset(tmp_path / "ds", [stopped_adv, lane_change])
    ds.update_manifest(splits={"eval": [stopped_adv.scenario_id, lane_change.scenario_id]})
    out = tmp_path / "avo"
    code = main(["eval", "avoidability", "heuristic", "--setting", "normal", "--dataset", str(tmp_path / "ds"),
                 "--plans", "4", "--out", str(out), "--no-progress", "--json", "--workers", "1"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["scenarios"] == 2 and summary["setting"] == "normal" and summary["search"]["n_plans"] == 4
    assert json.loads((out / "summary.json").read_text()) == summary
    lines = (out / "avoidability.csv").read_text().splitlines()
    assert lines[0].startswith("scenario_id,outcome,crash_with") and len(lines) == 3
    assert main(["eval", "avoidability", "heuristic", "--setting", "nope", "--dataset", str(tmp_path / "ds")]) == 2
    assert "unknown setting 'nope'" in capsys.readouterr().err


def test_rows_are_the_same_on_two_workers(stopped_adv: Scenario, lane_change: Scenario, highway: list[Scenario],
                                          tmp_path: Path) -> None:
    from seal.core.dataset import write_dataset
    from seal.experiments.evaluation.evaluate import parse_settings, resolve_eval_config

    scenarios = [stopped_adv, lane_change, *highway]
    ds = write_dataset(tmp_path / "ds", scenarios)
    ds.update_manifest(splits={"eval": [s.scenario_id for s in scenarios]})
    (setting,) = parse_settings(["rule"], tmp_path / "ds")
    config = resolve_eval_config(k=2)
    search = av.AvoidabilityConfig(n_plans=3)
    one = av.run_avoidability("heuristic", setting, config, search, progress=False, workers=1)
    two = av.run_avoidability("heuristic", setting, config, search, progress=False, workers=2)
    strip = [{**av.row_dicts([r])[0], "seconds": 0} for r in one]
    assert [r.scenario_id for r in one] == [s.scenario_id for s in scenarios]
    assert strip == [{**av.row_dicts([r])[0], "seconds": 0} for r in two]
