"""The skill-space plans of ``seal eval avoidability``: their family, a ReSkill ego driven by a plan, and a search in
its skill space on a crash one of its skills avoids."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from seal.core.scenario import Scenario
from seal.envs.observation import OBS_DIM
from seal.envs.scenario_env import ScenarioEnv
from seal.experiments.evaluation import avoidability as av
from seal.experiments.evaluation.avoidance_plans import PLAN_SPACES, ego_plans
from seal.experiments.training.egos import ReSkillEgo
from seal.experiments.training.reskill_policy import ReSkillPolicy

from .test_avoidability import _FixedGenerator, _stopped_track


class _AccelSkills:
    """Toy skills of latent size 2 and horizon 3: the skill is the prior noise itself and decodes to steering 0,
    acceleration ``z[1]`` (clipped), whatever the observation."""

    latent_dim, horizon, obs_dim = 2, 3, OBS_DIM

    def __init__(self) -> None:
        self.z = np.zeros(2, dtype=np.float32)
        self.calls = 0

    def skill(self, noise: np.ndarray, obs: np.ndarray) -> np.ndarray:
        assert obs.shape == (OBS_DIM,)
        self.z = np.asarray(noise, dtype=np.float32).copy()
        self.calls += 1
        return self.z

    def action(self, obs: np.ndarray) -> np.ndarray:
        return np.array([0.0, np.clip(self.z[1], -1, 1)], dtype=np.float32)

    def clone(self) -> _AccelSkills:
        return copy.copy(self)


class _ConstantHigh:
    """A high-level agent that always picks ``u``."""

    observation_space = None

    def __init__(self, u: list[float]) -> None:
        self.u = np.array(u, dtype=np.float32)

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, Any]:
        return self.u, None


def _reskill_ego(u: list[float], noise_bound: float = 1.0) -> ReSkillEgo:
    return ReSkillEgo(ReSkillPolicy(_ConstantHigh(u), _AccelSkills(), None, 0.0, noise_bound, 0.2), "toy-reskill")


def test_skill_plan_family_is_the_extremes_then_bounded_offsets() -> None:
    config = av.AvoidabilityConfig(n_plans=20, segments=4, max_skill_offset=0.5, skill_candidates=5,
                                   plan_space="skills")
    plans, candidates = av.skill_plans(config, 3, np.random.default_rng(1))
    assert len(plans) == 20 and all(o.shape == (4, 3) and e.shape == (4,) for o, e in plans)
    for first in range(4):  # brake then throttle from each segment on, no offsets
        (ob, eb), (ot, et) = plans[2 * first], plans[2 * first + 1]
        assert list(eb) == [0] * first + [-1] * (4 - first) and list(et) == [0] * first + [1] * (4 - first)
        assert not ob.any() and not ot.any()
    rest = plans[8:]
    assert all(not e.any() for _, e in rest)
    offsets = np.stack([o for o, _ in rest])
    assert np.abs(offsets).max() <= 0.5 and np.abs(offsets).max() > 0.3
    # all 8 corners of the 3-d box, the centre, 5 draws inside it
    assert candidates.shape == (14, 3) and np.abs(candidates).max() <= 1.0
    assert {tuple(c) for c in candidates[:8]} == {(a, b, c) for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)}
    assert not candidates[8].any()
    again, cands2 = av.skill_plans(config, 3, np.random.default_rng(1))
    assert all(np.array_equal(a[0], b[0]) for a, b in zip(plans, again, strict=True))
    assert np.array_equal(candidates, cands2)
    assert av.skill_plans(config, 8, np.random.default_rng(0))[1].shape == (32 + 1 + 5, 8)  # 32 drawn corners
    assert PLAN_SPACES == ("actions", "skills")
    with pytest.raises(ValueError, match="plan_space"):
        av.AvoidabilityConfig(plan_space="pixels")


def test_skill_plan_ego_follows_its_segments_and_leaves_the_ego_alone(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv])
    obs, info = env.reset(seed=0)
    ego = _reskill_ego([0.0, 0.25], noise_bound=2.0)
    candidates = np.array([[1.0, -1.0], [0.0, 0.9]], dtype=np.float32)
    offsets = np.array([[0.0, 0.5], [0.0, 0.0], [0.0, 0.0]], dtype=np.float32)
    plan = av.SkillPlanEgo(ego, offsets, np.array([0, 1, -1]), segment_steps=3, candidates=candidates)
    plan.reset(stopped_adv)
    step = info["step"]
    # segment 0: the ego's u (0.25) + 0.5, times noise_bound 2 -> acceleration 1.5, clipped to 1
    assert plan.act(obs, step)[1] == 1.0
    # segment 1 (a new skill every 3 steps): the highest first acceleration among u and the candidates: 0.9 x 2
    plan.act(obs, step + 1), plan.act(obs, step + 2)
    assert plan.act(obs, step + 3)[1] == 1.0 and plan.policy.skills.z[1] == pytest.approx(1.8)
    # segment 2: the hardest braking one, candidate (1, -1)
    plan.act(obs, step + 4), plan.act(obs, step + 5)
    assert plan.act(obs, step + 6)[1] == -1.0 and list(plan.policy.skills.z) == [2.0, -2.0]
    # the reference ego is untouched: its own skills were never asked, and it still drives its u
    assert ego.policy.skills.calls == 0 and ego.policy.steps == 0
    ego.reset(stopped_adv)
    assert ego.act(obs, step)[1] == pytest.approx(0.5)


def test_a_full_throttle_reskill_ego_could_have_braked_within_its_skills(stopped_adv: Scenario) -> None:
    env = ScenarioEnv([stopped_adv])
    ego = _reskill_ego([0.0, 1.0])  # always the full-throttle skill: into the car stopped ahead
    config = av.AvoidabilityConfig(n_plans=6, plan_space="skills", skill_candidates=0)
    row = av.probe_scenario(env, stopped_adv, 0, ego, _FixedGenerator(_stopped_track(stopped_adv)), k=1, seed=0,
                            config=config)
    assert row.outcome == "crash" and row.crash_with == "adversary" and row.reproducible
    assert row.heuristic_outcome not in av.FAILED  # recorded, but not one of the skill plans
    assert row.avoidable and row.first_avoiding_plan == "brake@0"
    assert row.plans_tried == 6 and row.avoidable_reaching_goal is False  # it stops short of the route's end


def test_skill_space_needs_a_reskill_ego() -> None:
    config = av.AvoidabilityConfig(plan_space="skills")
    with pytest.raises(ValueError, match="needs a ReSkill ego, got 'blind'"):
        next(ego_plans(config, type("Blind", (), {"name": "blind"})(), 0, 10))
    labels = [label for label, _ in ego_plans(config, _reskill_ego([0.0, 0.0]), 0, 10)]
    assert labels[:3] == ["brake@0", "throttle@0", "brake@1"] and len(labels) == 64


def test_command_refuses_the_skill_space_for_another_ego(tmp_path: Any, stopped_adv: Scenario,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    from seal.cli import main
    from seal.cli.avoidability import PLAN_SPACES as CLI_SPACES
    from seal.core.dataset import write_dataset

    assert CLI_SPACES == PLAN_SPACES
    write_dataset(tmp_path / "ds", [stopped_adv]).update_manifest(splits={"eval": [stopped_adv.scenario_id]})
    out = tmp_path / "avo"
    code = main(["eval", "avoidability", "heuristic", "--setting", "normal", "--dataset", str(tmp_path / "ds"),
                 "--plan-space", "skills", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "--plan-space skills: heuristic is not a ReSkill ego" in err and len(err.splitlines()) == 1
    assert not out.exists()
