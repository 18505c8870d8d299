"""Smoke test of the env benchmark (speed is measured by ``seal bench env``, not asserted here)."""

from __future__ import annotations

from pathlib import Path

from seal.core.dataset import write_dataset
from seal.core.scenario import Scenario
from seal.experiments.bench.env import run_env_bench


def test_bench_runs_on_a_dataset(tmp_path: Path, highway: list[Scenario]) -> None:
    write_dataset(tmp_path / "ds", highway)
    result = run_env_bench(tmp_path / "ds", n_steps=60, seed=0)
    assert result["scenarios"] == len(highway) and result["n_steps"] == 60
    assert result["scenario_env_steps_per_s"] > 0 and result["highway_v0_steps_per_s"] > 0
    ours, ref = result["scenario_env_steps_per_s"], result["highway_v0_steps_per_s"]
    # The rates are rounded to 0.1 and the ratio (of the unrounded rates) to 0.01, so the ratio lies between the
    # extreme ratios of rates within 0.05 of the printed ones, give or take 0.005 (wider when rates are small).
    lowest, highest = (ours - 0.05) / (ref + 0.05), (ours + 0.05) / (ref - 0.05)
    assert lowest - 0.005 - 1e-9 <= result["ratio"] <= highest + 0.005 + 1e-9
    assert isinstance(result["meets_target"], bool)


def test_skill_bench_repeats_play_the_same_episodes(tmp_path: Path, highway: list[Scenario]) -> None:
    from seal.core.scenario import CURRENT_STEP
    from seal.envs.scenario_env import ScenarioEnv
    from seal.envs.skill_behavior import SkillSwitchBehavior
    from seal.experiments.bench.skills import _timed_repeat, run_skill_bench, skill_policy_for_bench

    # The min-of-repeats estimate is only valid if every repeat does the same work.
    policy, _ = skill_policy_for_bench(None, seed=0)
    envs = {"replay": ScenarioEnv(highway), "skill": ScenarioEnv(highway, adversary=SkillSwitchBehavior(
        policy, switch_step=CURRENT_STEP))}
    first, second = (_timed_repeat(envs, 120, seed=3, block=25) for _ in range(2))
    for name in envs:
        assert first[name]["episodes"] == second[name]["episodes"] >= 2
        assert first[name]["outcomes"] == second[name]["outcomes"]
        assert first[name]["steps"] == 120
        assert first[name]["obs"].tobytes() == second[name]["obs"].tobytes()
        assert first[name]["scenario_ids"] == second[name]["scenario_ids"]
    # The variants play the same scenario sequence (they differ only in the adversary), in a seeded order.
    replay_ids, skill_ids = first["replay"]["scenario_ids"], first["skill"]["scenario_ids"]
    common = min(len(replay_ids), len(skill_ids))
    assert replay_ids[:common] == skill_ids[:common]
    assert len(set(replay_ids)) >= 2

    write_dataset(tmp_path / "ds", highway)
    result = run_skill_bench(tmp_path / "ds", n_steps=40, seed=0, repeats=2)
    assert len(result["skill_from_start_cost_ratio_per_repeat"]) == 2
    assert result["repeats"] == 2 and result["skill_from_start_steps_per_s"] > 0
    # The reported ratio is of each variant's fastest repeat, so it lies within the per-repeat ratios' hull only
    # loosely; it must at least equal the replay / variant steps/s ratio it is derived from.
    ratio = result["replay_steps_per_s"] / result["skill_from_start_steps_per_s"]
    assert abs(result["skill_from_start_cost_ratio"] - ratio) < 0.01
    assert isinstance(result["meets_target"], bool)
    # The zero-action variant observes like the skill adversary but takes no policy step; the policy's in-env cost
    # is the difference of the two variants' step times.
    assert result["episodes"]["observation_only"] >= 1 and result["observation_only_cost_ratio"] > 0
    in_env = 1e6 / result["skill_from_start_steps_per_s"] - 1e6 / result["observation_only_steps_per_s"]
    assert abs(result["policy_step_in_env_us"] - in_env) < 0.2
    # The zero-action variant observes like the skill adversary but takes no policy step; the policy's in-env cost
    # is the difference of the two variants' step times.
    assert result["episodes"]["observation_only"] >= 1 and result["observation_only_cost_ratio"] > 0
    in_env = 1e6 / result["skill_from_start_steps_per_s"] - 1e6 / result["observation_only_steps_per_s"]
    assert abs(result["policy_step_in_env_us"] - in_env) < 0.2
    # The floor: the replayed step plus the adversary's observation and policy step, each measured alone.
    parts = result["adversary_observation_us"] + result["skill_policy_step_on_recorded_obs_us"]
    # The observation's share is a difference of two timings (two viewers minus one), clamped at 0: on a loaded
    # machine the difference can vanish, so only its sign is checked; the policy step is a timing of its own.
    assert result["adversary_observation_us"] >= 0 and result["skill_policy_step_on_recorded_obs_us"] > 0
    assert abs(result["floor_cost_ratio"] - (result["replay_step_us"] + parts) / result["replay_step_us"]) < 0.01
