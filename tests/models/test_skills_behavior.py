"""The SEAL skill adversary in ScenarioEnv: replay until the switch step, then the skill policy on its own
observation; deterministic for a seed."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from seal.core.scenario import CURRENT_STEP, N_STEPS, VX, VY
from seal.envs import observation as ob
from seal.envs.behaviors import PolicyBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.scenario_env import ScenarioEnv
from seal.envs.skill_behavior import SkillSwitchBehavior, switch_step_for
from seal.models.skills.policy import SkillPolicy
from seal.models.skills.realnvp import ConditionalRealNVP, RealNVPConfig
from seal.models.skills.vae import SkillVAE, VAEConfig

SWITCH = CURRENT_STEP + 15


def _policy() -> SkillPolicy:
    torch.manual_seed(0)
    vae, prior = SkillVAE(VAEConfig()), ConditionalRealNVP(RealNVPConfig())
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for p in prior.parameters():  # couplings start as the identity; give the noise a state-dependent map
            p.copy_(torch.randn(p.shape, generator=gen) * 0.1)
        prior.z_std.fill_(2.0)
    return SkillPolicy(vae, prior)


class _Recorder:
    """Wraps a policy and records the observations it is given."""

    def __init__(self, policy: SkillPolicy) -> None:
        self.policy = policy
        self.observations: list[np.ndarray] = []

    def reset(self, seed: int | None = None) -> None:
        self.policy.reset(seed)
        self.observations.clear()

    def act(self, observation: np.ndarray) -> np.ndarray:
        self.observations.append(np.array(observation))
        return self.policy.act(observation)


def _episode(env: ScenarioEnv, seed: int, scenario_id: str):
    driver = HeuristicDriver()
    obs, _ = env.reset(seed=seed, options={"scenario_id": scenario_id})
    done = False
    while not done:
        obs, _, terminated, truncated, info = env.step(driver.predict(obs)[0])
        done = terminated or truncated
    return info["rollout"]


def test_switch_step_for() -> None:
    assert switch_step_for(50) == 40
    assert switch_step_for(50, offset_steps=5) == 45
    assert switch_step_for(12) == CURRENT_STEP
    assert switch_step_for(None) == CURRENT_STEP
    with pytest.raises(ValueError, match="offset_steps"):
        switch_step_for(40, -1)


def test_skill_adversary_follows_the_track_then_acts_on_its_own_observation(highway) -> None:
    scenario = highway[0]
    recorder = _Recorder(_policy())
    behavior = SkillSwitchBehavior(recorder, switch_step=SWITCH)
    env = ScenarioEnv([scenario], config={"terminate_on_crash": False}, adversary=behavior)
    roll = _episode(env, 0, scenario.scenario_id)
    adv = roll.adv_track
    logged = scenario.track(scenario.adv_id)
    # Replay up to and including the switch step's state; the policy decides the moves from SWITCH on.
    assert np.allclose(adv[: SWITCH + 1, :2], logged[: SWITCH + 1, :2], atol=1e-4)
    end = min(roll.last_step, N_STEPS - 1) + 1
    assert roll.last_step > SWITCH + 10
    assert not np.allclose(adv[SWITCH + 2 : end, :2], logged[SWITCH + 2 : end, :2], atol=0.05)
    # One observation per step from the switch on, none before (the env skips building it).
    assert len(recorder.observations) == roll.last_step - SWITCH
    # The observation is the adversary's own: its speed and its position relative to its route (the logged
    # track it was replaying), not the ego's.
    first = recorder.observations[0]
    speed = float(np.hypot(adv[SWITCH, VX], adv[SWITCH, VY]))
    ego_speed = float(np.hypot(roll.ego_track[SWITCH, VX], roll.ego_track[SWITCH, VY]))
    assert abs(first[ob.SPEED] * ob.MAX_SPEED_MPS - speed) < 1e-3 and abs(speed - ego_speed) > 0.1
    assert abs(first[ob.LATERAL]) < 1e-3 and abs(first[ob.HEADING_ERROR]) < 0.02


def test_skill_adversary_roll_out_is_deterministic_for_a_seed(highway) -> None:
    scenario = highway[1]
    env = ScenarioEnv([scenario], config={"terminate_on_crash": False},
                      adversary=SkillSwitchBehavior(_policy(), switch_step=CURRENT_STEP))
    a = _episode(env, 5, scenario.scenario_id)
    b = _episode(env, 5, scenario.scenario_id)
    c = _episode(env, 6, scenario.scenario_id)
    assert a.last_step == b.last_step
    assert np.array_equal(a.tracks, b.tracks)
    assert not np.array_equal(a.adv_track, c.adv_track)
    # A fixed behaviour seed overrides the env's: the same adversary under different env seeds.
    fixed = ScenarioEnv([scenario], config={"terminate_on_crash": False},
                        adversary=SkillSwitchBehavior(_policy(), switch_step=CURRENT_STEP, seed=11))
    d, e = _episode(fixed, 1, scenario.scenario_id), _episode(fixed, 2, scenario.scenario_id)
    assert np.array_equal(d.adv_track, e.adv_track)


def test_tracking_mode_and_given_track(highway) -> None:
    scenario = highway[2]
    track = scenario.track(scenario.adv_id).astype(np.float64).copy()
    track[CURRENT_STEP + 1 :, 1] += np.linspace(0.0, 2.0, track.shape[0] - CURRENT_STEP - 1)  # drift left
    behavior = SkillSwitchBehavior(_policy(), track=track, switch_step=CURRENT_STEP + 20, follow="track")
    env = ScenarioEnv([scenario], config={"terminate_on_crash": False}, adversary=behavior)
    roll = _episode(env, 0, scenario.scenario_id)
    k = CURRENT_STEP + 20
    # Bicycle-model tracking of the given (shifted) track, not the log: within a few decimetres of it.
    assert np.abs(roll.adv_track[CURRENT_STEP + 5 : k, 1] - track[CURRENT_STEP + 5 : k, 1]).max() < 0.3
    with pytest.raises(ValueError, match="follow"):
        SkillSwitchBehavior(_policy(), follow="teleport")
    with pytest.raises(ValueError, match="switch_step"):
        SkillSwitchBehavior(_policy(), switch_step=3)


def test_policy_behaviour_still_observes_every_step(highway) -> None:
    # Backward compatibility of AdversaryBehavior.observes: reactive behaviours keep getting observations.
    seen: list[np.ndarray] = []

    class Spy:
        def predict(self, obs, **kwargs):
            seen.append(obs)
            return HeuristicDriver().predict(obs)

    env = ScenarioEnv([highway[0]], adversary=PolicyBehavior(Spy()))
    roll = _episode(env, 0, highway[0].scenario_id)
    assert len(seen) == roll.n_steps


def _box_edges(boxes: np.ndarray, x: float, y: float) -> tuple[np.ndarray, ...]:
    """Edges of ``[N, 7]`` boxes as segments relative to (x, y): starts ax, ay and vectors ex, ey ``[4N]``."""
    from seal.core.geometry import box_corners

    c = box_corners(boxes[:, 0], boxes[:, 1], boxes[:, 2], boxes[:, 5], boxes[:, 6])  # [N, 4, 2]
    e = np.roll(c, -1, axis=1) - c
    return c[..., 0].ravel() - x, c[..., 1].ravel() - y, e[..., 0].ravel(), e[..., 1].ravel()


def test_build_many_equals_one_build_per_viewer(highway) -> None:
    # The env builds the ego's and the skill adversary's observations in one pass (`build_many`); each row must
    # be exactly what `build` gives that viewer alone, and the lidar must match a ray cast against box edges.
    from kernel_reference import cast_rays

    from seal.envs.kinematics import AgentState
    from seal.envs.observation import ObservationBuilder
    from seal.envs.road_geometry import get_road_geometry
    from seal.envs.route import Route

    scenario = highway[0]
    builder = ObservationBuilder(get_road_geometry(scenario.road))
    rng = np.random.default_rng(0)
    route = Route.from_track(scenario.track(scenario.ego_id))
    for trial in range(40):
        n = int(rng.integers(2, 9))
        boxes = np.column_stack([
            rng.uniform(-30, 90, n), rng.uniform(-3, 11, n), rng.uniform(-0.4, 0.4, n), rng.uniform(-5, 30, n),
            rng.uniform(-2, 2, n), rng.uniform(4, 12, n), rng.uniform(1.8, 2.6, n),
        ])
        rows = [0, 1] if trial % 4 else [0, -1]  # -1: a viewer that is not among the boxes
        if trial % 5 == 0:
            boxes[2, :2] = boxes[0, :2] + [1.0, 0.5]  # viewer 0 overlaps another vehicle: lidar reads from inside
        states = [AgentState(float(b[0]), float(b[1]), float(b[2]), float(np.hypot(b[3], b[4])), float(b[5]),
                             float(b[6]), 0.1, -0.2, 0.05) for b in boxes[:2]]
        projections = [route.project(s.x, s.y) for s in states]
        both = builder.build_many(states, [route, route], projections, boxes, rows)
        for v in range(2):
            others = np.delete(boxes, rows[v], axis=0) if rows[v] >= 0 else boxes
            alone = builder.build(states[v], route, others, projections[v])
            np.testing.assert_array_equal(both[v], alone)
            angles = states[v].heading + 2 * np.pi * np.arange(ob.N_LIDAR_RAYS) / ob.N_LIDAR_RAYS
            expected = cast_rays(np.cos(angles), np.sin(angles), *_box_edges(others, states[v].x, states[v].y),
                                 ob.LIDAR_RANGE_M)
            np.testing.assert_allclose(alone[ob.LIDAR] * ob.LIDAR_RANGE_M, expected, atol=1e-4)
    with pytest.raises(ValueError, match="one entry per viewer"):
        builder.build_many(states, [route], projections, boxes, rows)


def test_policy_clone_has_its_own_episode_state() -> None:
    policy = _policy()
    clone = policy.clone()
    assert clone._decoder._w_obs is policy._decoder._w_obs  # weights shared, not copied
    obs = np.random.default_rng(0).uniform(0, 1, policy.obs_dim).astype(np.float32)
    policy.reset(1)
    clone.reset(2)
    a, b = policy.act(obs), clone.act(obs)
    assert not np.array_equal(a, b) and not np.array_equal(policy.z, clone.z)
    policy.reset(2)
    np.testing.assert_array_equal(policy.act(obs), b)  # same seed, same skill: the clone did not disturb it


def test_skill_adversary_route_is_built_once_per_scenario(highway) -> None:
    """`make_route` is cached per scenario (and once for a given track), with the points `Route.from_track` gives."""
    from seal.envs.route import Route

    behavior = SkillSwitchBehavior(_policy())
    a, b = highway[0], highway[1]
    ra = behavior.make_route(a)
    assert behavior.make_route(a) is ra and behavior.make_route(b) is not ra
    np.testing.assert_array_equal(ra.points, Route.from_track(a.track(a.adv_id)).points)
    given = SkillSwitchBehavior(_policy(), track=b.track(b.adv_id))
    assert given.make_route(a) is given.make_route(b)
    np.testing.assert_array_equal(given.make_route(a).points, behavior.make_route(b).points)


def test_a_second_policy_takes_over_at_its_step_with_its_own_seed(highway) -> None:
    scenario = highway[0]
    first, second = _Recorder(_policy()), _Recorder(_policy())
    then_step = SWITCH + 12
    behavior = SkillSwitchBehavior(first, switch_step=SWITCH, seed=3, then=second, then_step=then_step)
    env = ScenarioEnv([scenario], config={"terminate_on_crash": False}, adversary=behavior)
    roll = _episode(env, 0, scenario.scenario_id)
    assert roll.last_step > then_step + 5
    # The first policy decides the moves of steps SWITCH .. then_step - 1, the second every one after.
    assert len(first.observations) == then_step - SWITCH
    assert len(second.observations) == roll.last_step - then_step
    # Each episode reseeds both, the second apart from the first (seed + 1): they draw different skills.
    behavior.reset(scenario, np.random.default_rng(0))
    assert first.policy.rng.standard_normal() == np.random.default_rng(3).standard_normal()
    assert second.policy.rng.standard_normal() == np.random.default_rng(4).standard_normal()
    with pytest.raises(ValueError, match="then_step"):
        SkillSwitchBehavior(_policy(), switch_step=SWITCH, then=_policy())
    with pytest.raises(ValueError, match="then_step"):
        SkillSwitchBehavior(_policy(), switch_step=SWITCH, then=_policy(), then_step=SWITCH - 1)
