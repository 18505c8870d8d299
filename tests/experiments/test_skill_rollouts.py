"""Adversarial skill demonstrations from closed-loop roll-outs against egos: what is recorded is what the
adversary did, events label the striker's windows, both adversaries run."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf

from seal.envs.kinematics import AgentState, bicycle_step
from seal.experiments.fitting import skill_rollouts as sr
from seal.models.skills.demonstrations import DemoConfig
from seal.models.skills.demos import ADVERSARIAL, EGO_ROLLOUT, WindowSpec


@pytest.fixture(scope="module")
def scenario():
    return sf.highway_scenario(0)


def test_recorded_actions_drive_the_executed_adversary(scenario) -> None:
    (rec, rollout), = sr._episodes(scenario, "heuristic", 0, "heuristic", DemoConfig(seed=1), None, 1)
    adv = rollout.adv_track.astype(np.float64)
    n = len(rec.actions)
    assert n >= 10 and rec.first_step == 10 and len(rec.obs) == n and rec.obs[0].shape == (100,)
    # The adversary's executed state at t + 1 is the bicycle model applied to its state at t and the recorded action.
    for k in range(min(n, 40) - 1):
        t = rec.first_step + k
        if adv[t + 1, 7] < 0.5:
            break
        state = AgentState.from_track_row(adv[t])
        nxt = bicycle_step(state, float(rec.actions[k][0]), float(rec.actions[k][1]))
        assert (nxt.x, nxt.y) == pytest.approx((adv[t + 1, 0], adv[t + 1, 1]), abs=2e-3)


def test_roll_outs_against_egos_are_adversarial_only_demonstrations(scenario) -> None:
    d = sr.roll_out_against_egos(scenario, ["heuristic", "replay"], DemoConfig(seed=2), adversary="cat",
                                 source="constant_velocity", passes=2)
    d.validate()
    assert d.n_segments == 4 and (d.seg_source == EGO_ROLLOUT).all()  # 2 egos x 2 passes
    assert d.params["egos"] == ["heuristic", "replay"] and d.params["adversary"] == "cat"
    w = d.windows(WindowSpec())
    assert (w.label == ADVERSARIAL).all()  # no benign windows from these sources
    struck = d.ev_striker & (d.ev_kind == 0)
    for seg in np.unique(d.ev_seg[struck]):
        assert ((w.segment == seg) & (w.label == ADVERSARIAL)).any() or d.seg_len[seg] < 10
    with pytest.raises(ValueError, match="unknown roll-out adversary"):
        sr.roll_out_against_egos(scenario, ["heuristic"], DemoConfig(), adversary="goose")
