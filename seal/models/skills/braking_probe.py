"""Closed-loop braking probe: does a skill policy brake for a car braking ahead of it?

One hand-built scene (`braking_scenario`): a straight three-lane road, both cars in the middle lane; the leader
(the scenario's ego, replayed from its log) drives at ``speed_mps`` and brakes at ``leader_decel_mps2`` from
``brake_after_s`` after the current step; the follower (the adversary) starts ``gap_m`` behind it (bumper to
bumper) at the same speed and is driven from the current step by the policy under test, from its own observation.
The clean heuristic driver keeps its gap and stops without contact. `probe_braking` reports the follower's mean
acceleration over the ``window_s`` after the leader starts braking, the share of seeds that end in contact and the
speed at which the follower runs into the leader.

Why it exists (issue 16): the SEAL adversary's collision speed is a realism measure of Table 6.2, and against the
heuristic ego its fast contacts are an adversary running into a slower ego from behind. The reach of
`seal.models.skills.reach` measures a skill's first action only and cannot show whether a skill brakes over its
horizon; this probe runs the skills in closed loop, as the adversary drives them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import CURRENT_STEP, DT_S, N_STEPS, Scenario
from seal.core.scenario import speed as track_speed  # 'speed' is a local name below
from seal.envs.behaviors import AdversaryBehavior, Policy, PolicyBehavior
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import recover_actions
from seal.envs.scenario_env import ScenarioEnv
from seal.envs.skill_behavior import SKILL_NOISE_SCALE, SkillSwitchBehavior, StepPolicy
from seal.models.skills.policy import SkillPolicy
from seal.models.skills.realnvp import ConditionalRealNVP
from seal.models.skills.vae import SkillVAE

LANE_WIDTH_M = 4.0
N_LANES = 3
"""Lanes of the probe's road (as the generated highways have 3-4); both cars drive in the middle one, at y = 0."""
CAR_LENGTH_M, CAR_WIDTH_M = 5.0, 2.0


@dataclass(frozen=True)
class BrakingProbe:
    """The probe's scene and statistics.

    Attributes:
        gap_m: initial bumper-to-bumper gap between follower and leader (m); 20 m at 20 m/s is a 1 s headway.
        speed_mps: initial speed of both cars (m/s).
        leader_decel_mps2: the leader's braking (m/s^2, > 0), held until it stops.
        brake_after_s: time after the current step at which the leader starts braking (s).
        window_s: the follower's acceleration is averaged over this long after the leader starts braking (s).
        seeds: episodes per policy (the skill noise differs between them).
    """

    gap_m: float = 20.0
    speed_mps: float = 20.0
    leader_decel_mps2: float = 4.0
    brake_after_s: float = 1.0
    window_s: float = 2.0
    seeds: int = 10

    def __post_init__(self) -> None:
        for name in ("gap_m", "speed_mps", "leader_decel_mps2", "window_s"):
            if float(getattr(self, name)) <= 0:
                raise ValueError(f"BrakingProbe: {name} must be > 0, got {getattr(self, name)}")
        if self.brake_after_s < 0 or int(self.seeds) < 1:
            raise ValueError(f"BrakingProbe: brake_after_s must be >= 0 and seeds >= 1, got {self.brake_after_s}, "
                             f"{self.seeds}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _straight_track(x0_m: float, speed_mps: float, decel_mps2: float, brake_step: int) -> np.ndarray:
    """``[N_STEPS, 8]`` log of a car along +x at y = 0: constant speed, braking from ``brake_step`` until it stops."""
    track = np.zeros((N_STEPS, 8), dtype=np.float32)
    x, v = float(x0_m), float(speed_mps)
    for t in range(N_STEPS):
        track[t] = (x, 0.0, 0.0, v, 0.0, CAR_LENGTH_M, CAR_WIDTH_M, 1.0)
        a = -decel_mps2 if t >= brake_step else 0.0
        v_next = max(0.0, v + a * DT_S)
        x += 0.5 * (v + v_next) * DT_S
        v = v_next
    return track


def braking_scenario(probe: BrakingProbe | None = None) -> Scenario:
    """The probe's scene (module docstring): agent 0 is the braking leader (the ego), agent 1 the follower."""
    p = probe or BrakingProbe()
    lanes = tuple(
        LaneSpec(lane_id=f"a:b:{i}", centerline=np.array([[-100.0, y], [900.0, y]]), width_m=LANE_WIDTH_M,
                 line_types=("continuous" if i == N_LANES - 1 else "striped", "continuous" if i == 0 else "striped"))
        for i, y in enumerate(LANE_WIDTH_M * (np.arange(N_LANES) - 1))
    )
    road = RoadDescription(layout="polylines", lanes=lanes, params={"probe": "braking"})
    brake_step = CURRENT_STEP + round(p.brake_after_s / DT_S)
    leader = _straight_track(150.0, p.speed_mps, p.leader_decel_mps2, brake_step)
    follower = _straight_track(150.0 - CAR_LENGTH_M - p.gap_m, p.speed_mps, 0.0, N_STEPS)
    return Scenario(scenario_id="braking_probe", tracks=np.stack([leader, follower]), agent_ids=np.arange(2),
                    agent_types=("vehicle", "vehicle"), ego_id=0, adv_id=1, road=road, source="probe",
                    metadata={"layout": "probe"})


def _episode(scenario: Scenario, behavior: AdversaryBehavior, seed: int, leader_actions: np.ndarray) -> Any:
    # The leader stops at the end of its logged route: no arrival, so a follower that closes in later still counts.
    env = ScenarioEnv([scenario], config={"terminate_on_crash": True, "success_completion": 2.0}, adversary=behavior)
    env.reset(seed=seed, options={"scenario_id": scenario.scenario_id})
    t, done = CURRENT_STEP, False
    info: dict[str, Any] = {}
    while not done:
        _, _, terminated, truncated, info = env.step(leader_actions[min(t, len(leader_actions) - 1)])
        t += 1
        done = terminated or truncated
    return info["rollout"]


def probe_braking(policy: StepPolicy | Policy, probe: BrakingProbe | None = None) -> dict[str, float]:
    """Run the probe with ``policy`` driving the follower: a skill policy (``reset(seed)`` / ``act(obs)``, driven
    from the current step by `SkillSwitchBehavior`) or any ``predict(obs)`` policy such as the heuristic driver.

    Returns:
        ``accel_mps2``: the follower's mean acceleration over ``window_s`` after the leader starts braking (m/s^2,
        mean over seeds); ``contact_share``: share of seeds ending in contact with the leader; ``contact_speed_mps``:
        mean closing speed at contact (m/s; 0 without contact); ``seeds``.
    """
    p = probe or BrakingProbe()
    scenario = braking_scenario(p)
    leader_actions = recover_actions(scenario.tracks[0], start_step=CURRENT_STEP)
    k0 = CURRENT_STEP + round(p.brake_after_s / DT_S)
    k1 = k0 + round(p.window_s / DT_S)
    accel, contact, closing = [], [], []
    for seed in range(int(p.seeds)):
        behavior: AdversaryBehavior
        if hasattr(policy, "reset"):  # a skill policy: seeded per episode by the behaviour
            behavior = SkillSwitchBehavior(policy, switch_step=CURRENT_STEP, seed=seed)  # type: ignore[arg-type]
        else:
            behavior = PolicyBehavior(policy)
        roll = _episode(scenario, behavior, seed, leader_actions)
        speed, lead = track_speed(roll.adv_track), track_speed(roll.ego_track)
        end = max(min(k1, roll.last_step), k0 + 1)
        accel.append((speed[end] - speed[k0]) / ((end - k0) * DT_S))
        hit = [step for step, other in roll.ego_crashes if other == scenario.adv_id]
        contact.append(bool(hit))
        closing.append(float(speed[hit[0]] - lead[hit[0]]) if hit else 0.0)
    hits = np.asarray(contact)
    return {"accel_mps2": round(float(np.mean(accel)), 3), "contact_share": round(float(hits.mean()), 3),
            "contact_speed_mps": round(float(np.mean(np.asarray(closing)[hits])) if hits.any() else 0.0, 3),
            "seeds": int(p.seeds)}


def braking_report(vae: SkillVAE, priors: dict[str, ConditionalRealNVP], probe: BrakingProbe | None = None,
                   noise_scale: float = SKILL_NOISE_SCALE) -> dict[str, Any]:
    """The probe for each prior's skill policy (at the SEAL adversary's default noise scale) and, for reference,
    the clean heuristic driver (deterministic: one seed)."""
    p = probe or BrakingProbe()
    report: dict[str, Any] = {"probe": p.to_dict(), "noise_scale": noise_scale,
                              "heuristic_driver": probe_braking(HeuristicDriver(), replace(p, seeds=1))}
    for name, prior in priors.items():
        report[f"{name}_prior"] = probe_braking(SkillPolicy(vae, prior, noise_scale=noise_scale), p)
    return report


def format_braking(report: dict[str, Any]) -> str:
    """One line: per policy the mean acceleration after the leader brakes, contact share and contact speed."""
    p = report["probe"]
    cells = [f"{name.replace('_', ' ')} {r['accel_mps2']:+.2f} m/s^2, contact {r['contact_share']:.0%}"
             + (f" at {r['contact_speed_mps']:.1f} m/s" if r["contact_share"] else "")
             for name, r in report.items() if isinstance(r, dict) and "accel_mps2" in r]
    return (f"braking probe (leader {p['gap_m']:g} m ahead at {p['speed_mps']:g} m/s brakes at "
            f"{p['leader_decel_mps2']:g} m/s^2; follower's mean acceleration over {p['window_s']:g} s): "
            + "; ".join(cells))
