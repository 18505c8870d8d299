"""The closed-loop braking probe of `seal fit skills`: the scene, and its numbers for drivers whose answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from seal.core.scenario import CURRENT_STEP
from seal.envs.heuristic import HeuristicDriver
from seal.models.skills.braking_probe import BrakingProbe, braking_scenario, format_braking, probe_braking


class _Constant:
    """A skill-policy stand-in (``reset`` / ``act``) that always applies one normalised action."""

    def __init__(self, accel: float) -> None:
        self.action = np.array([0.0, accel], dtype=np.float32)

    def reset(self, seed: int | None = None) -> None:
        pass

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self.action


def test_the_scene_brakes_the_leader_from_the_given_time() -> None:
    probe = BrakingProbe(gap_m=15.0, speed_mps=18.0, leader_decel_mps2=3.0, brake_after_s=1.5)
    sc = braking_scenario(probe)
    leader, follower = sc.tracks[0], sc.tracks[1]
    assert leader[CURRENT_STEP, 0] - follower[CURRENT_STEP, 0] == pytest.approx(15.0 + 5.0)  # bumper gap + length
    speed = leader[:, 3]
    k = CURRENT_STEP + 15
    assert speed[k] == pytest.approx(18.0) and speed[k + 10] == pytest.approx(15.0, abs=1e-4)
    assert np.all(follower[:, 3] == 18.0) and np.all(sc.tracks[:, :, 1] == 0.0)


def test_a_follower_that_never_brakes_hits_at_the_closing_speed_of_the_kinematics() -> None:
    result = probe_braking(_Constant(0.0), BrakingProbe(seeds=2))
    assert result["contact_share"] == 1.0 and abs(result["accel_mps2"]) < 0.05
    # The 20 m gap closes after sqrt(2 * 20 / 4) = 3.16 s of braking, at 4 * 3.16 = 12.6 m/s.
    assert result["contact_speed_mps"] == pytest.approx(12.6, abs=0.8)


def test_a_follower_braking_too_little_still_hits_after_the_leader_has_stopped() -> None:
    # -1.2 m/s^2 from the start: contact ~5.3 s in, after the leader stopped at the end of its route (no arrival
    # may end the episode first), at a closing speed of 20 - 1.2 * 5.3 = 13.6 m/s minus the leader's last ~0.
    result = probe_braking(_Constant(-0.2), BrakingProbe(seeds=1))
    assert result["contact_share"] == 1.0 and result["accel_mps2"] == pytest.approx(-1.2, abs=0.1)
    assert 11.0 < result["contact_speed_mps"] < 15.0


def test_hard_braking_and_the_heuristic_driver_avoid_contact() -> None:
    hard = probe_braking(_Constant(-1.0), BrakingProbe(seeds=1))
    assert hard["contact_share"] == 0.0 and hard["contact_speed_mps"] == 0.0
    heuristic = probe_braking(HeuristicDriver(), BrakingProbe(seeds=1))
    assert heuristic["contact_share"] == 0.0 and heuristic["accel_mps2"] < -1.0
    line = format_braking({"probe": BrakingProbe().to_dict(), "heuristic_driver": heuristic})
    assert "heuristic driver" in line and "contact 0%" in line


def test_bad_probe_settings_are_named() -> None:
    with pytest.raises(ValueError, match="gap_m"):
        BrakingProbe(gap_m=0.0)
    with pytest.raises(ValueError, match="seeds"):
        BrakingProbe(seeds=0)
