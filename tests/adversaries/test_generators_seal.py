"""SEAL generator: the predicted contact step (analytic cases), the switch step taken from the chosen candidate,
roll-outs with the skill adversary deterministic for a seed, the ablation options, option errors, and the
learned-objective path (when `seal.models.objective` is importable)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from seal.adversaries.base import make_generator
from seal.adversaries.candidate_path import candidate_track
from seal.adversaries.history import RolloutHistory
from seal.adversaries.seal.contact import predict_contact
from seal.adversaries.seal.generator import SEALGenerator
from seal.adversaries.seal.objective import DEFAULT_PRIOR_WEIGHT
from seal.core.geometry import box_corners, boxes_overlap
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, LENGTH, N_FUTURE, N_STEPS, VALID, WIDTH, Scenario, X, Y
from seal.envs.behaviors import ReplayBehavior
from seal.envs.scenario_env import ScenarioEnv
from seal.envs.skill_behavior import SkillSwitchBehavior
from seal.experiments.evaluation.episodes import run_episode
from seal.experiments.evaluation.generators import parse_generators
from seal.experiments.evaluation.protocol import build_generator
from seal.experiments.training.egos import make_ego
from seal.models.prior.candidates import Candidates
from seal.models.skills.policy import SkillPolicy
from seal.models.skills.realnvp import ConditionalRealNVP, RealNVPConfig
from seal.models.skills.vae import SkillVAE, VAEConfig

SIZE = (4.5, 2.0)
STEPS = np.arange(N_STEPS)
PARK_STEP = 50
"""Candidate 1 parks on the ego's logged position of this step."""


def ego_along_x(speed: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One ego roll-out driving +x at ``speed`` (m/s) through x = 0 at the current step."""
    xy = np.zeros((1, N_STEPS, 2))
    xy[0, :, 0] = speed * DT_S * (STEPS - CURRENT_STEP)
    return xy, np.zeros((1, N_STEPS)), np.ones((1, N_STEPS), dtype=bool)


def parked(x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    return np.tile([x, y], (N_FUTURE, 1)).astype(float), np.zeros(N_FUTURE)


# ----------------------------------------------------------------------------------------- predicted contact step
def test_contact_step_of_a_parked_candidate_is_the_first_box_overlap() -> None:
    # Ego at 10 m/s: x = step - 10. Boxes 4.5 m long meet when the centres are 4.5 m apart: x >= 25.5, step 36.
    xy, h, v = ego_along_x(10.0)
    c = predict_contact(*parked(30.0, 0.0), SIZE, xy, h, v, SIZE)
    assert c.collided and c.step == 36 and c.rollout == 0
    # A slower second roll-out meets it later; the earliest collision over the roll-outs counts.
    slow = ego_along_x(5.0)
    both = [np.concatenate([slow[i], a]) for i, a in enumerate((xy, h, v))]
    c2 = predict_contact(*parked(30.0, 0.0), SIZE, *both, SIZE)
    assert c2.collided and c2.step == 36 and c2.rollout == 1


def test_contact_step_without_collision_is_the_closest_approach() -> None:
    xy, h, v = ego_along_x(10.0)
    c = predict_contact(*parked(30.0, 5.0), SIZE, xy, h, v, SIZE)  # one lane over: 3 m gap, never touching
    assert not c.collided and c.step == 40 and c.min_distance_m == pytest.approx(5.0)
    # Steps after the roll-out ended do not count: a roll-out that stops at step 30 is closest at step 30.
    v[:, 31:] = False
    c = predict_contact(*parked(30.0, 5.0), SIZE, xy, h, v, SIZE)
    assert c.step == 30 and c.min_distance_m == pytest.approx(np.hypot(10.0, 5.0))


def test_contact_step_rejects_bad_shapes() -> None:
    xy, h, v = ego_along_x(10.0)
    with pytest.raises(ValueError, match="cand_xy"):
        predict_contact(np.zeros((5, 3)), np.zeros(5), SIZE, xy, h, v, SIZE)
    with pytest.raises(ValueError, match="ego_xy"):
        predict_contact(*parked(0.0, 0.0), SIZE, xy[0], h, v, SIZE)


# ------------------------------------------------------------------------------------------------- the generator
def _policy() -> SkillPolicy:
    """Untrained skill models whose prior maps noise to state-dependent skills (as in test_skills_behavior)."""
    torch.manual_seed(0)
    vae, prior = SkillVAE(VAEConfig()), ConditionalRealNVP(RealNVPConfig())
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in prior.parameters():
            p.copy_(torch.randn(p.shape, generator=gen) * 0.1)
        prior.z_std.fill_(2.0)
    return SkillPolicy(vae, prior)


def _candidates(scenario: Scenario) -> Candidates:
    """Candidate 0: the adversary keeps its lane at its current velocity (no conflict with the ego in the next
    lane); candidate 1: it parks on the ego's logged position of `PARK_STEP` (a collision the ego drives into)."""
    adv, ego = scenario.tracks[scenario.adv_index], scenario.tracks[scenario.ego_index]
    t = DT_S * np.arange(1, N_FUTURE + 1)[:, None]
    keep = adv[CURRENT_STEP, [X, Y]] + t * adv[CURRENT_STEP, [3, 4]]
    park = np.tile(ego[PARK_STEP, [X, Y]], (N_FUTURE, 1))
    xy = np.stack([keep, park]).astype(np.float64)
    heading = np.stack([np.full(N_FUTURE, adv[CURRENT_STEP, HEADING]), np.full(N_FUTURE, ego[PARK_STEP, HEADING])])
    speed = np.stack([np.full(N_FUTURE, np.hypot(*adv[CURRENT_STEP, [3, 4]])), np.zeros(N_FUTURE)])
    return Candidates(xy=xy, heading=heading, speed=speed, probs=np.array([0.7, 0.3]),
                      agent_index=scenario.adv_index)


def _generator(**options) -> SEALGenerator:
    options = {"objective": "cat", "policy": _policy(), **options}
    return SEALGenerator(candidate_source=_candidates, **options)


def _first_overlap_step(scenario: Scenario) -> int:
    """Brute force (corner-based polygons, every step): where the logged ego first meets candidate 1's box."""
    ego, adv = scenario.tracks[scenario.ego_index], scenario.tracks[scenario.adv_index]
    e = box_corners(ego[:, X], ego[:, Y], ego[:, HEADING], ego[:, LENGTH], ego[:, WIDTH])
    a = box_corners(ego[PARK_STEP, X], ego[PARK_STEP, Y], ego[PARK_STEP, HEADING], adv[CURRENT_STEP, LENGTH],
                    adv[CURRENT_STEP, WIDTH])
    hit = boxes_overlap(e, a[None]) & (ego[:, VALID] > 0.5) & (STEPS > CURRENT_STEP)
    return int(np.argmax(hit))


@pytest.mark.parametrize("offset", [10, 4])
def test_switch_step_comes_from_the_chosen_candidate(highway: list[Scenario], offset: int) -> None:
    scenario = highway[0]
    gen = _generator(switch_offset_steps=offset).generate(
        scenario, RolloutHistory().queue(scenario), np.random.default_rng(0))
    expected = _first_overlap_step(scenario)
    assert CURRENT_STEP + offset < expected < PARK_STEP  # the ego reaches the parked box a few steps early
    assert gen.chosen_candidate == 1 and gen.extra["collision_predicted"]
    assert gen.predicted_step == expected
    assert gen.extra["switch_step"] == expected - offset
    assert isinstance(gen.behavior, SkillSwitchBehavior) and gen.behavior.switch_step == expected - offset
    assert len(gen.extra["scores"]) == 2 and gen.extra["scores"][1] > gen.extra["scores"][0]
    for key in ("candidate_time_s", "rank_time_s", "select_time_s"):
        assert gen.extra[key] >= 0.0


def _roll(scenario: Scenario, generator: SEALGenerator, rng_seed: int, env_seed: int = 0):
    env = ScenarioEnv([scenario], config={"terminate_on_crash": False})
    generation = generator.generate(scenario, RolloutHistory().queue(scenario), np.random.default_rng(rng_seed))
    return generation, run_episode(env, scenario, make_ego("heuristic"), generation.behavior, seed=env_seed)


def test_skill_adversary_roll_out_is_deterministic_for_a_seed(highway: list[Scenario]) -> None:
    scenario = highway[0]
    generator = _generator()
    g1, a = _roll(scenario, generator, rng_seed=3)
    _, b = _roll(scenario, generator, rng_seed=3, env_seed=9)  # the generator's rng fixes the skill noise
    _, c = _roll(scenario, generator, rng_seed=4)
    assert a.last_step == b.last_step and np.array_equal(a.tracks, b.tracks)
    switch = g1.extra["switch_step"]
    # Before the switch the adversary replays the chosen candidate; after it the skills (other noise) differ.
    track = candidate_track(scenario, scenario.adv_index, _candidates(scenario).xy[1])
    assert np.allclose(a.adv_track[: switch + 1, :2], track[: switch + 1, :2], atol=1e-4)
    end = min(a.last_step, c.last_step) + 1
    assert not np.allclose(a.adv_track[switch + 2 : end, :2], c.adv_track[switch + 2 : end, :2], atol=1e-3)


def test_switch_none_is_pure_trajectory_following(highway: list[Scenario]) -> None:
    scenario = highway[0]
    gen, roll = _roll(scenario, _generator(switch="none"), rng_seed=0)
    assert isinstance(gen.behavior, ReplayBehavior) and gen.extra["switch_step"] is None
    track = candidate_track(scenario, scenario.adv_index, _candidates(scenario).xy[1])
    steps = slice(CURRENT_STEP, min(roll.last_step, N_STEPS - 1) + 1)  # the candidate track ends at step 90
    np.testing.assert_allclose(roll.adv_track[steps, :2], track[steps, :2], atol=1e-4)
    # The skill variant of the same generation leaves the candidate after its switch step.
    gen_skill, roll_skill = _roll(scenario, _generator(), rng_seed=0)
    k, end = gen_skill.extra["switch_step"] + 2, min(roll_skill.last_step, N_STEPS - 1) + 1
    assert end > k + 10
    assert np.abs(roll_skill.adv_track[k:end, :2] - track[k:end, :2]).max() > 0.5


def test_bad_options_give_clear_errors(tmp_path) -> None:
    with pytest.raises(ValueError, match="switch must be one of"):
        _generator(switch="sometimes")
    with pytest.raises(ValueError, match="follow must be one of"):
        _generator(follow="teleport")
    with pytest.raises(ValueError, match="switch_offset_steps"):
        _generator(switch_offset_steps=-1)
    with pytest.raises(ValueError, match="'objective' is required"):
        _generator(objective=None)
    with pytest.raises(ValueError, match="neither 'cat' nor an existing"):
        _generator(objective=str(tmp_path / "missing.pt"))
    with pytest.raises(ValueError, match="needs option 'skills'"):
        SEALGenerator(candidate_source=_candidates, objective="cat")
    with pytest.raises(ValueError, match="skills folder .* does not exist"):
        SEALGenerator(candidate_source=_candidates, objective="cat", skills=tmp_path / "nope")
    # Trajectory-only SEAL needs no skill models.
    assert SEALGenerator(candidate_source=_candidates, objective="cat", switch="none").policy is None


def test_configs_name_several_seal_variants() -> None:
    parsed = parse_generators({"seal": {}, "seal_traj": {"generator": "seal", "switch": "none"}})
    assert parsed["seal_traj"] == {"generator": "seal", "switch": "none"}
    generator = build_generator("seal_traj", parsed["seal_traj"], {"candidates": "lanes", "objective": "cat"})
    assert isinstance(generator, SEALGenerator) and generator.switch == "none"
    with pytest.raises(ValueError, match=r"seal_x \(generator: sael\)"):
        parse_generators({"seal_x": {"generator": "sael"}})
    assert isinstance(make_generator("seal", candidates="lanes", objective="cat", switch="none"), SEALGenerator)


def test_learned_objective_ranks_with_the_model(highway: list[Scenario], tmp_path) -> None:
    objective = pytest.importorskip("seal.models.objective", reason="seal.models.objective (learned "
        "objective) not available yet")
    from seal.adversaries.candidate_generator import stack_ego_rollouts

    torch.manual_seed(0)
    model = objective.ObjectiveModel(objective.ObjectiveConfig(hidden=8))
    path = tmp_path / "objective.pt"
    model.save(path)
    scenario = highway[0]
    history = RolloutHistory().queue(scenario)
    gen = _generator(objective=path).generate(scenario, history, np.random.default_rng(0))
    xy, heading, valid = objective.align_ego_rollouts(*stack_ego_rollouts(history))
    cands = _candidates(scenario)
    learned = objective.ObjectiveModel.load(path).rank(cands.xy, cands.heading, xy, heading, valid)
    # Default: the learned score plus DEFAULT_PRIOR_WEIGHT x log prior probability.
    expected = learned + DEFAULT_PRIOR_WEIGHT * np.log(cands.probs)
    np.testing.assert_allclose(gen.extra["scores"], expected, atol=1e-5)
    assert gen.chosen_candidate == int(np.argmax(expected)) and gen.extra["objective"] == "objective.pt"
    assert gen.extra["prior_weight"] == DEFAULT_PRIOR_WEIGHT
    # prior_weight=0: the thesis's score alone.
    thesis = _generator(objective=path, prior_weight=0.0).generate(scenario, history, np.random.default_rng(0))
    np.testing.assert_allclose(thesis.extra["scores"], learned, atol=1e-5)
    assert thesis.chosen_candidate == int(np.argmax(learned)) and "prior_weight" not in thesis.extra
    k = gen.chosen_candidate
    now = scenario.tracks[:, CURRENT_STEP]
    sizes = [(float(now[i, LENGTH]), float(now[i, WIDTH])) for i in (scenario.adv_index, scenario.ego_index)]
    ego_xy, ego_h, ego_v = stack_ego_rollouts(history)
    contact = predict_contact(cands.xy[k], cands.heading[k], sizes[0], ego_xy, ego_h, ego_v, sizes[1])
    assert gen.predicted_step == contact.step


def test_a_prev_adversary_objective_ranks_with_what_the_adversary_drove(highway: list[Scenario], tmp_path) -> None:
    objective = pytest.importorskip("seal.models.objective", reason="seal.models.objective (learned "
        "objective) not available yet")
    from seal.adversaries.candidate_generator import stack_adv_rollouts, stack_ego_rollouts
    from seal.adversaries.seal.objective import LearnedObjective

    torch.manual_seed(0)
    path = tmp_path / "objective.pt"
    objective.ObjectiveModel(objective.ObjectiveConfig(hidden=8, prev_adversary=True)).save(path)
    scenario = highway[0]
    history = RolloutHistory().queue(scenario)
    gen = _generator(objective=path, prior_weight=0.0).generate(scenario, history, np.random.default_rng(0))
    ego = objective.align_ego_rollouts(*stack_ego_rollouts(history))
    adv_xy, _, adv_valid = objective.align_ego_rollouts(*stack_adv_rollouts(history))
    # The history's one roll-out is the logged episode: its adversary is the logged track.
    logged = scenario.tracks[scenario.adv_index, CURRENT_STEP + 1 : CURRENT_STEP + 1 + adv_xy.shape[1]]
    ok = logged[:, VALID] > 0.5
    assert ok.any() and (adv_valid[0, : len(logged)] == ok).all()
    np.testing.assert_allclose(adv_xy[0, : len(logged)][ok], logged[ok][:, [X, Y]], atol=1e-3)
    cands = _candidates(scenario)
    model = objective.ObjectiveModel.load(path)
    expected = model.rank(cands.xy, cands.heading, *ego, adv_xy=adv_xy, adv_valid=adv_valid)
    np.testing.assert_allclose(gen.extra["scores"], expected, atol=1e-5)
    elsewhere = model.rank(cands.xy, cands.heading, *ego, adv_xy=adv_xy + 30.0, adv_valid=adv_valid)
    assert not np.allclose(elsewhere, expected)
    ranker = LearnedObjective(path)
    with pytest.raises(ValueError, match="prev_adv"):
        ranker(cands, (4.5, 2.0), *stack_ego_rollouts(history), (4.5, 2.0))


@pytest.fixture
def untrained_objective(tmp_path) -> Path:
    """An untrained pi_score file (seed 0): its two heads score the candidates differently."""
    objective = pytest.importorskip("seal.models.objective", reason="seal.models.objective (learned "
        "objective) not available yet")
    torch.manual_seed(0)
    path = tmp_path / "objective.pt"
    objective.ObjectiveModel(objective.ObjectiveConfig(hidden=8)).save(path)
    return path


def test_prior_weight_trades_the_learned_score_for_plausibility(highway: list[Scenario], untrained_objective: Path
                                                                ) -> None:
    path, scenario = untrained_objective, highway[0]
    history = RolloutHistory().queue(scenario)
    learned = _generator(objective=path, prior_weight=0.0).generate(scenario, history, np.random.default_rng(0))
    gap = abs(learned.extra["scores"][0] - learned.extra["scores"][1])
    # log(0.7 / 0.3) = 0.847 nats apart: a weight above gap / 0.847 makes the likelier candidate 0 win whatever the
    # learned score prefers; a weight far below it leaves the learned choice.
    strong = _generator(objective=path, prior_weight=2 * gap / np.log(0.7 / 0.3) + 1e-3)
    assert strong.generate(scenario, history, np.random.default_rng(0)).chosen_candidate == 0
    weak = _generator(objective=path, prior_weight=1e-3 * gap)
    chosen = weak.generate(scenario, history, np.random.default_rng(0))
    assert chosen.chosen_candidate == learned.chosen_candidate == chosen.extra["learned_argmax"]
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="prior_weight must be a finite number >= 0"):
            _generator(objective=path, prior_weight=bad)
    # CAT's heuristic weighs candidates by its own flattened prior: the weight does not change its choice.
    cat = [_generator(objective="cat", prior_weight=w).generate(scenario, history, np.random.default_rng(0))
           for w in (0.0, 10.0)]
    assert cat[0].chosen_candidate == cat[1].chosen_candidate and cat[0].extra["scores"] == cat[1].extra["scores"]


def test_objective_heads_rank_by_one_predicted_term(highway: list[Scenario], untrained_objective: Path) -> None:
    path, scenario = untrained_objective, highway[0]
    history = RolloutHistory().queue(scenario)
    picks = {heads: _generator(objective=path, prior_weight=0.0, objective_heads=heads).generate(
        scenario, history, np.random.default_rng(0)) for heads in ("coll+diff", "coll", "diff")}
    # the thesis's score is the two heads' scores added; each variant picks its own score's argmax
    np.testing.assert_allclose(picks["coll+diff"].extra["scores"],
                               np.add(picks["coll"].extra["scores"], picks["diff"].extra["scores"]), atol=1e-6)
    assert not np.allclose(picks["coll"].extra["scores"], picks["diff"].extra["scores"])
    assert all(g.chosen_candidate == int(np.argmax(g.extra["scores"])) for g in picks.values())
    with pytest.raises(ValueError, match=r"objective_heads must be one of coll\+diff, coll, diff, got 'both'"):
        _generator(objective=path, objective_heads="both")
    with pytest.raises(ValueError, match="objective_heads='coll' needs a learned objective file, not objective=cat"):
        _generator(objective="cat", objective_heads="coll")


def test_close_call_gap_between_ego_and_adversary_boxes() -> None:
    from seal.experiments.evaluation.generator_metrics import CLOSE_CALL_M, min_box_gap

    t = np.arange(20)
    ego = np.zeros((20, 8))
    ego[:, X], ego[:, LENGTH], ego[:, WIDTH], ego[:, VALID] = t * 1.0, 4.0, 2.0, 1.0
    adv = ego.copy()
    adv[:, X] = 30.0 - t * 0.5  # closing at 1.5 m/step: centres 30 - 1.5 t apart, boxes 4 m shorter
    adv[:, Y] = 3.0  # one lane over: 1 m between the boxes' long sides
    assert min_box_gap(ego, adv) == pytest.approx(1.0) and min_box_gap(ego, adv) <= CLOSE_CALL_M
    adv[:, Y] = 6.0
    assert min_box_gap(ego, adv) == pytest.approx(4.0)
    adv[:, VALID] = 0.0
    assert min_box_gap(ego, adv) == float("inf")


@pytest.mark.parametrize("switch", ["adversarial", "benign"])
def test_switch_names_from_a_config_load_that_prior_at_noise_1(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, switch: str,
) -> None:
    """A config names the switch as text; the generator loads the skills folder with that prior and the default skill
    noise (`SKILL_NOISE_SCALE`, 0.5), the adversarial one also the benign prior (`ADVERSARIAL_STEPS`);
    `load_skill_policy` alone defaults to the prior itself (noise 1)."""
    from seal.adversaries.seal.generator import load_skill_policy

    loaded: list[dict] = []
    monkeypatch.setattr(SkillPolicy, "load", classmethod(lambda cls, folder, **kw: loaded.append(kw) or "policy"))
    generator = SEALGenerator(candidate_source=_candidates, objective="cat", skills=tmp_path, switch=switch)
    assert generator.switch == switch and generator.policy == "policy"
    assert load_skill_policy(tmp_path, switch) == "policy"
    # The adversarial switch also loads the benign prior its adversary drives with after `adversarial_steps`.
    hand_over = [{"prior": "benign", "noise_scale": 0.5, "horizon": None}] if switch == "adversarial" else []
    assert loaded == [{"prior": switch, "noise_scale": 0.5, "horizon": None}, *hand_over,
                      {"prior": switch, "noise_scale": 1.0, "horizon": None}]


def test_option_bounds_are_inclusive() -> None:
    """0 noise (the prior's mean skill), a 1-step skill horizon and a switch at the predicted contact itself are
    valid; one below each is not."""
    generator = _generator(noise_scale=0.0, skill_horizon=1, switch_offset_steps=0)
    assert generator.switch_offset_steps == 0
    assert _generator(noise_scale=0.5).switch == "adversarial"
    for bad, message in (({"noise_scale": -0.1}, "noise_scale must be >= 0"),
                         ({"skill_horizon": 0}, "skill_horizon must be >= 1"),
                         ({"switch_offset_steps": -1}, "switch_offset_steps must be >= 0")):
        with pytest.raises(ValueError, match=message):
            _generator(**bad)


def test_generation_record_and_a_fresh_policy_per_generation(highway: list[Scenario]) -> None:
    """What a generation records (the values the evaluation stores) and that each skill behaviour gets its own
    copy of the policy (two adversaries driven at once must not share its state)."""
    scenario = highway[0]
    queue = RolloutHistory().queue(scenario)
    generator = _generator()
    first = generator.generate(scenario, queue, np.random.default_rng(0))
    second = generator.generate(scenario, queue, np.random.default_rng(0))
    chosen = first.chosen_candidate
    assert first.extra["switch"] == "adversarial" and isinstance(first.extra["skill_seed"], int)
    assert first.extra["score"] == pytest.approx(first.extra["scores"][chosen], abs=1e-6)
    assert first.extra["prior_prob"] == pytest.approx(0.3) and chosen == 1
    assert first.extra["min_distance_m"] >= 0.0
    assert first.behavior.policy is not generator.policy and first.behavior.policy is not second.behavior.policy
    trajectory_only = _generator(switch="none").generate(scenario, queue, np.random.default_rng(0))
    assert trajectory_only.extra["switch"] == "none" and trajectory_only.extra["skill_seed"] is None


def test_the_generator_and_the_model_default_to_the_same_heads() -> None:
    objective = pytest.importorskip("seal.models.objective.model", reason="seal.models.objective not available")
    from seal.adversaries.seal.objective import DEFAULT_HEADS

    assert DEFAULT_HEADS == objective.DEFAULT_RANK_HEADS and DEFAULT_HEADS in objective.RANK_HEADS


def _benign_policy() -> SkillPolicy:
    """Other skill weights than `_policy`'s: a hand-over to it changes the adversary's moves."""
    torch.manual_seed(7)
    return SkillPolicy(SkillVAE(VAEConfig()), ConditionalRealNVP(RealNVPConfig()))


def test_adversarial_steps_hand_the_adversary_over_to_the_benign_skills(highway: list[Scenario]) -> None:
    scenario = highway[0]
    to_the_end = _generator(adversarial_steps=None)
    handed = _generator(adversarial_steps=6, benign_policy=_benign_policy())
    g1, a = _roll(scenario, to_the_end, rng_seed=3)
    g2, b = _roll(scenario, handed, rng_seed=3)
    switch = g2.extra["switch_step"]
    assert g1.extra["benign_step"] is None and g2.extra["benign_step"] == switch + 6
    assert g2.behavior.then_step == switch + 6 and g2.behavior.then is not handed.benign_policy  # a copy each
    # The same adversary up to the hand-over (its move of step benign_step shows in the state after it), other
    # moves after it.
    k = switch + 6
    np.testing.assert_allclose(a.adv_track[: k + 1, :2], b.adv_track[: k + 1, :2], atol=1e-9)
    end = min(a.last_step, b.last_step) + 1
    assert end > k + 5 and not np.allclose(a.adv_track[k + 2 : end, :2], b.adv_track[k + 2 : end, :2], atol=1e-3)


def test_adversarial_steps_bounds_and_when_they_apply() -> None:
    with pytest.raises(ValueError, match="adversarial_steps must be >= 0"):
        _generator(adversarial_steps=-1)
    assert _generator(adversarial_steps=0, benign_policy=_benign_policy()).adversarial_steps == 0
    # A ready policy without its benign one drives to the end; the benign and trajectory-only ablations never hand
    # over.
    assert _generator(adversarial_steps=10).adversarial_steps is None
    assert _generator(adversarial_steps=10, benign_policy=_benign_policy(), switch="benign").adversarial_steps is None
    assert _generator(adversarial_steps=10, switch="none").benign_policy is None
