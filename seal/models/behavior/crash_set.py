"""The crash set of the fine-tuning stage (thesis 7.2, 7.3.4), from what this project has instead of TADS.

A scenario enters when its logged (ego, adversary) pair collides or comes within ``near_miss_m`` (box gap) of each
other: collisions and near misses of the generated traffic, near misses and critical situations of imported
recordings. Both agents of the pair become samples, labelled by their role, as TADS-traj's maneuver classes:

* the agent that caused the situation is **unsafe** (TADS: aggressor). Where the log shows it, the cause is read
  from it: generated traffic records each focal agent's driver model (``ego_driver`` / ``adv_driver`` in the
  metadata); when exactly one of the two is ``aggressive`` or ``inattentive``, that one caused it. Otherwise the
  geometry of the last ``window_s`` before the closest approach decides: the agent that moved laterally towards
  the other by more than ``lateral_m`` (a cut-in / lane change into it; the larger such move if both did), else the
  one behind (the other is ahead in its frame: the follower closed the gap).
* the other agent is **safe** if it reacted (braked harder than ``brake_mps2`` or moved laterally away by more than
  ``swerve_m`` in that window; TADS: safe brake / swerve), else **neutral** (it did nothing).

This is a weaker label than TADS's hand annotation; it is documented as such in the fitting report.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from seal.core.geometry import box_gap, track_corners
from seal.core.scenario import CURRENT_STEP, DT_S, HEADING, VALID, VX, VY, Scenario, X, Y
from seal.models.behavior.labels import NEUTRAL, SAFE, UNSAFE

RISKY_DRIVERS = ("aggressive", "inattentive")
"""Driver models of the generated traffic that cause conflicts (`seal.envs.drivers`)."""


@dataclass(frozen=True)
class CrashSetConfig:
    """How crash-set pairs are chosen and labelled (see the module docstring).

    Attributes:
        near_miss_m: largest box gap (m) of the logged pair that still counts as a near miss.
        window_s: the time before the closest approach (s) whose motion decides cause and reaction.
        lateral_m: lateral move (m) towards the other that makes an agent the cause.
        brake_mps2: deceleration (m/s^2) that counts as a reaction.
        swerve_m: lateral move (m) away from the other that counts as a reaction.
    """

    near_miss_m: float = 1.0
    window_s: float = 3.0
    lateral_m: float = 1.0
    brake_mps2: float = 2.0
    swerve_m: float = 0.5

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class CrashSample:
    """One crash-set agent.

    Attributes:
        scenario_id: its scenario.
        agent: its row in the scenario's tracks.
        label: `UNSAFE`, `SAFE` or `NEUTRAL`.
        role: ``"aggressor"`` (caused it) or ``"recipient"``.
        basis: what decided: ``"driver"``, ``"lateral"`` or ``"behind"`` for the aggressor; ``"reacted"`` or
            ``"no reaction"`` for the recipient.
        reason: a readable account with the numbers.
    """

    scenario_id: str
    agent: int
    label: int
    role: str
    basis: str
    reason: str


def closest_approach(scenario: Scenario) -> tuple[int, float]:
    """``(step, gap_m)`` of the smallest box gap between the logged ego and adversary at steps where both exist
    (gap 0 = overlap); ``(-1, inf)`` if they never coexist."""
    e, a = scenario.tracks[scenario.ego_index], scenario.tracks[scenario.adv_index]
    both = (e[:, VALID] > 0.5) & (a[:, VALID] > 0.5)
    if not both.any():
        return -1, float("inf")
    gap = np.where(both, box_gap(track_corners(e.astype(np.float64)), track_corners(a.astype(np.float64))), np.inf)
    step = int(np.argmin(gap))
    return step, float(gap[step])


def _motion(track: np.ndarray, other: np.ndarray, start: int, stop: int) -> tuple[float, float, float]:
    """``(lateral move towards other (m), largest deceleration (m/s^2), other's forward offset (m))`` of ``track``
    over steps ``start..stop`` (both valid there), in its frame at ``start``."""
    h = float(track[start, HEADING])
    fwd, left = np.array([np.cos(h), np.sin(h)]), np.array([-np.sin(h), np.cos(h)])
    rel0 = other[start, [X, Y]] - track[start, [X, Y]]
    side = 1.0 if float(rel0 @ left) >= 0 else -1.0
    lateral = float((track[stop, [X, Y]] - track[start, [X, Y]]) @ left) * side
    speed = np.hypot(track[start:stop + 1, VX], track[start:stop + 1, VY])
    decel = float(max(0.0, -(np.diff(speed) / DT_S).min())) if speed.size > 1 else 0.0
    ahead = float((other[stop, [X, Y]] - track[stop, [X, Y]]) @ fwd)
    return lateral, decel, ahead


def label_pair(scenario: Scenario, step: int, cfg: CrashSetConfig) -> list[CrashSample]:
    """Cause / reaction labels of the logged pair, closest approach at ``step`` (see the module docstring)."""
    rows = (scenario.ego_index, scenario.adv_index)
    tr = scenario.tracks.astype(np.float64)
    both = (tr[rows[0], :, VALID] > 0.5) & (tr[rows[1], :, VALID] > 0.5)
    start = step
    while start > max(0, step - round(cfg.window_s / DT_S)) and both[start - 1]:
        start -= 1
    motion = [_motion(tr[r], tr[o], start, step) for r, o in (rows, rows[::-1])]
    drivers = [str(scenario.metadata.get(k, "")) for k in ("ego_driver", "adv_driver")]
    risky = [d in RISKY_DRIVERS for d in drivers]
    if risky[0] != risky[1]:
        cause = 0 if risky[0] else 1
        basis, reason = "driver", f"driver model {drivers[cause]}"
    elif max(m[0] for m in motion) > cfg.lateral_m:
        cause = int(np.argmax([m[0] for m in motion]))
        basis, reason = "lateral", f"moved {motion[cause][0]:.1f} m laterally towards the other"
    else:
        # The other agent is ahead in this one's frame (forward offset >= 0): this one closed the gap from behind.
        cause = 0 if motion[0][2] >= motion[1][2] else 1
        basis, reason = "behind", "closed the gap from behind"
    other = 1 - cause
    lateral, decel, _ = motion[other]
    reacted = decel > cfg.brake_mps2 or -lateral > cfg.swerve_m
    return [
        CrashSample(scenario.scenario_id, rows[cause], UNSAFE, "aggressor", basis, reason),
        CrashSample(scenario.scenario_id, rows[other], SAFE if reacted else NEUTRAL, "recipient",
                    "reacted" if reacted else "no reaction", f"braked {decel:.1f} m/s^2, moved {-lateral:.1f} m away"),
    ]


def crash_samples(scenarios: list[Scenario], cfg: CrashSetConfig) -> list[CrashSample]:
    """Crash-set samples of every scenario whose logged pair collides or nearly does (closest approach after the
    first step, both agents valid at `CURRENT_STEP` so the encoder can centre on them)."""
    out: list[CrashSample] = []
    for s in scenarios:
        if not (s.valid[s.ego_index, CURRENT_STEP] and s.valid[s.adv_index, CURRENT_STEP]):
            continue
        step, gap = closest_approach(s)
        if step > 0 and gap <= cfg.near_miss_m:
            out.extend(label_pair(s, step, cfg))
    return out
