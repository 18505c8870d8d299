"""Adversarial-window labelling on hand-built logs: collisions and near misses, striker vs victim, the 2H window
start, and the clean log-replay demonstrations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scenario_factory as sf

from seal.core.scenario import DT_S, N_STEPS
from seal.envs.multi_agent import COLLISION, HORIZON
from seal.models.skills.demonstrations import DemoConfig, roll_out_demonstrations, roll_out_log_demonstrations
from seal.models.skills.demos import ADVERSARIAL, BENIGN, HEURISTIC, LOG, Demonstrations, WindowSpec
from seal.models.skills.events import (
    COLLISION_EVENT,
    NEAR_MISS_EVENT,
    EventSpec,
    adversarial_start_mask,
    closing_contributions,
    find_events,
    strikers,
)


def _track(x: np.ndarray, y: float = 0.0, heading: float = 0.0) -> np.ndarray:
    """A log along the x axis through positions ``x [N_STEPS]`` (5 m x 2 m box), velocities from the positions."""
    track = np.zeros((N_STEPS, 8), dtype=np.float64)
    track[:, 0], track[:, 1], track[:, 2] = x, y, heading
    track[:, 3] = np.gradient(x, DT_S)
    track[:, 5], track[:, 6], track[:, 7] = 5.0, 2.0, 1.0
    return track


def _constant(x0: float, speed: float, y: float = 0.0) -> np.ndarray:
    return _track(x0 + speed * np.arange(N_STEPS) * DT_S, y)


def _rear_end() -> np.ndarray:
    """Follower at 20 m/s from x = 0 behind a leader at 10 m/s from x = 50.3 (45.3 m between the boxes)."""
    return np.stack([_constant(0.0, 20.0), _constant(50.3, 10.0)])


def test_rear_end_the_follower_strikes_the_leader_is_struck() -> None:
    ev = find_events(_rear_end())
    collide = math.floor(45.3 / 1.0) + 1  # closing 10 m/s = 1 m per step: first overlap at step 46
    coll = ev.kind == COLLISION_EVENT
    assert sorted(zip(ev.agent[coll].tolist(), ev.step[coll].tolist(), ev.striker[coll].tolist(), strict=True)) == [
        (0, collide, True), (1, collide, False)]
    # The follower closes the gap at its own 20 m/s; the leader drives away from it (-10 m/s).
    assert ev.contribution_mps[coll & (ev.agent == 0)][0] == pytest.approx(20.0, abs=0.2)
    assert ev.contribution_mps[coll & (ev.agent == 1)][0] == pytest.approx(-10.0, abs=0.2)
    # On the way in, the gap fell to 0.3 m at 10 m/s closing: one near miss, struck by the follower too.
    near = ev.kind == NEAR_MISS_EVENT
    assert sorted(zip(ev.agent[near].tolist(), ev.striker[near].tolist(), strict=True)) == [(0, True), (1, False)]
    assert (ev.step[near] == collide - 1).all()


def test_a_stopped_car_hit_from_behind_is_not_the_striker_and_a_head_on_has_two() -> None:
    parked = _track(np.full(N_STEPS, 60.0))
    ev = find_events(np.stack([parked, _constant(0.0, 15.0)]))
    first = ev.step == ev.step.min()
    assert dict(zip(ev.agent[first].tolist(), ev.striker[first].tolist(), strict=True)) == {0: False, 1: True}
    # Head-on (both at 10 m/s towards each other): equal contributions, both caused it.
    a = _constant(0.0, 10.0)
    b = _track(100.0 - 10.0 * np.arange(N_STEPS) * DT_S, heading=math.pi)
    b[:, 3] = -10.0
    ev = find_events(np.stack([a, b]))
    assert ev.striker[ev.kind == COLLISION_EVENT].tolist() == [True, True]


def test_rules_on_contributions() -> None:
    c_i, c_j = closing_contributions(np.array([0.0, 0.0]), np.array([20.0, 0.0]), np.array([10.0, 0.0]),
                                     np.array([10.0, 0.0]))
    assert (c_i, c_j) == (20.0, -10.0)
    assert [s.item() for s in strikers(c_i, c_j, 0.5)] == [True, False]
    assert [s.item() for s in strikers(3.0, 3.4, 0.5)] == [True, True]  # within the margin: both
    # Sideswipe: the merging car's lateral motion closes the gap, the other keeps its lane.
    c_i, c_j = closing_contributions(np.array([0.0, 3.0]), np.array([10.0, -2.0]), np.array([0.0, 0.0]),
                                     np.array([10.0, 0.0]))
    assert c_i == pytest.approx(2.0) and c_j == pytest.approx(0.0)


def test_near_miss_needs_a_closing_approach_and_counts_once() -> None:
    # The follower brakes from 10 m/s at 5 m/s^2 to stop 0.3 m behind a parked car: a near miss, no collision.
    v = np.maximum(0.0, 10.0 - 5.0 * np.arange(N_STEPS) * DT_S)
    x = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * DT_S)])
    stop = x[-1]
    parked = _track(np.full(N_STEPS, stop + 5.3))
    follower = _track(x)
    follower[:, 3] = v
    ev = find_events(np.stack([follower, parked]), EventSpec(near_miss_gap_m=0.5, near_miss_closing_mps=0.1))
    assert set(ev.kind.tolist()) == {NEAR_MISS_EVENT} and len(ev) == 2  # one encounter, one row per agent
    assert dict(zip(ev.agent.tolist(), ev.striker.tolist(), strict=True)) == {0: True, 1: False}
    # Two parked cars 0.3 m apart: never closing, no event.
    assert len(find_events(np.stack([_track(np.full(N_STEPS, 0.0)), _track(np.full(N_STEPS, 5.3))]))) == 0
    # Same approach, but arriving at under the closing threshold: no near miss.
    assert len(find_events(np.stack([follower, parked]), EventSpec(near_miss_closing_mps=5.0))) == 0


def test_adversarial_windows_start_within_2h_before_the_struck_event() -> None:
    starts = np.arange(0, 60)
    mask = adversarial_start_mask(starts, np.full(60, 46), horizon=10)
    assert starts[mask].tolist() == list(range(26, 46))
    assert starts[adversarial_start_mask(starts, np.full(60, 46), 10, lead_steps=5)].tolist() == list(range(41, 46))


def _demos(seg_len: list[int], sources: list[int], events: list[tuple[int, int, int, bool]],
           starts: list[int] | None = None, reasons: list[int] | None = None) -> Demonstrations:
    n = len(seg_len)
    rows = np.concatenate([[0], np.cumsum(seg_len)[:-1]]).astype(np.int64)
    ev = np.array(events, dtype=np.int64).reshape(-1, 4)
    return Demonstrations(
        obs=np.zeros((sum(seg_len), 100), np.float16), actions=np.zeros((sum(seg_len), 2), np.float32),
        seg_row=rows, seg_len=np.array(seg_len, np.int32), seg_scenario=np.zeros(n, np.int32),
        seg_agent=np.arange(n, dtype=np.int64), seg_start_step=np.array(starts or [0] * n, np.int32),
        seg_end_reason=np.array(reasons or [HORIZON] * n, np.int8), seg_impaired=np.zeros(n, bool),
        seg_source=np.array(sources, np.int8), ev_seg=ev[:, 0], ev_step=ev[:, 1].astype(np.int32),
        ev_kind=ev[:, 2].astype(np.int8), ev_striker=ev[:, 3].astype(bool), scenario_ids=np.array(["s"]), params={})


def test_window_labels_striker_victim_sources_and_near_misses() -> None:
    # Segment 0 (log) struck a collision at step 46 and ended there; segment 1 (log) was hit; segment 2 (heuristic)
    # struck a near miss at step 30 (it starts at step 5); segment 3 (heuristic) has no event.
    d = _demos([46, 46, 60, 60], [LOG, LOG, HEURISTIC, HEURISTIC],
               [(0, 46, COLLISION_EVENT, 1), (1, 46, COLLISION_EVENT, 0), (2, 30, NEAR_MISS_EVENT, 1)],
               starts=[0, 0, 5, 0], reasons=[COLLISION, COLLISION, HORIZON, HORIZON])
    w = d.windows(WindowSpec(horizon=10))
    rows = lambda seg, label: (w.row[(w.segment == seg) & (w.label == label)] - d.seg_row[seg]).tolist()  # noqa: E731
    # Striker: windows starting at steps 26..36 (the last one ends at the collision); the earlier ones are clean log.
    assert rows(0, ADVERSARIAL) == list(range(26, 37)) and rows(0, BENIGN) == list(range(26))
    # The victim's windows are all benign (it did not cause the collision).
    assert rows(1, ADVERSARIAL) == [] and rows(1, BENIGN) == list(range(37))
    # Heuristic source: only the struck near miss's windows (steps 10..29 = rows 5..24), nothing benign.
    assert rows(2, ADVERSARIAL) == list(range(5, 25)) and rows(2, BENIGN) == []
    assert not (w.segment == 3).any()
    assert w.n_unused == (51 - 20) + 51
    no_near = d.windows(WindowSpec(horizon=10, near_misses=False))
    assert not ((no_near.segment == 2) & (no_near.label == ADVERSARIAL)).any()
    both = d.windows(WindowSpec(horizon=10, benign_sources=("log", "heuristic")))
    assert ((both.segment == 3) & (both.label == BENIGN)).sum() == 51



def test_avoided_only_keeps_the_near_misses_broken_off_and_drops_what_led_to_contact() -> None:
    # Segment 0 (log): struck near miss at 30, then touched at 38 (within 2H): left out, and its lead-up is not benign.
    # Segment 1 (log): struck near miss at 30 and no contact: adversarial. Segment 2 (heuristic): struck collision at
    # 40: left out. Segment 3 (log): struck near miss at 20, a collision only at 55 (more than 2H later): avoided.
    d = _demos([60, 60, 60, 60], [LOG, LOG, HEURISTIC, LOG],
               [(0, 30, NEAR_MISS_EVENT, 1), (0, 38, COLLISION_EVENT, 1), (1, 30, NEAR_MISS_EVENT, 1),
                (2, 40, COLLISION_EVENT, 1), (3, 20, NEAR_MISS_EVENT, 1), (3, 55, COLLISION_EVENT, 1)])
    spec = WindowSpec(horizon=10, avoided_only=True)
    w = d.windows(spec)
    rows = lambda seg, label: (w.row[(w.segment == seg) & (w.label == label)] - d.seg_row[seg]).tolist()  # noqa: E731
    assert rows(0, ADVERSARIAL) == [] and rows(0, BENIGN) == list(range(10)) + list(range(38, 51))
    assert rows(1, ADVERSARIAL) == list(range(10, 30)) and rows(1, BENIGN) == list(range(10)) + list(range(30, 51))
    assert not (w.segment == 2).any()
    assert rows(3, ADVERSARIAL) == list(range(0, 20)) and rows(3, BENIGN) == list(range(20, 35))
    # The default rule counts every struck event.
    every = d.windows(WindowSpec(horizon=10))
    assert ((every.segment == 2) & (every.label == ADVERSARIAL)).sum() == 20
    with pytest.raises(ValueError, match="avoided_only needs near_misses"):
        WindowSpec(avoided_only=True, near_misses=False)

def test_log_demonstrations_reproduce_the_log_and_label_its_rear_end() -> None:
    road = sf.straight_road(2)
    scenario = sf.make_scenario(road, [_constant(0.0, 20.0).astype(np.float32),
                                       _constant(50.5, 10.0).astype(np.float32),
                                       _constant(0.0, 15.0, y=4.0).astype(np.float32)], "log_rear_end")
    d = roll_out_log_demonstrations(scenario, DemoConfig(source="log"))
    d.validate()
    assert (d.seg_source == LOG).all() and not d.seg_impaired.any()
    # The recovered actions of constant-speed logs: no steering, no acceleration.
    assert np.abs(d.actions).max() < 1e-3
    by_agent = {int(a): k for k, a in enumerate(d.seg_agent)}
    assert d.seg_end_reason[by_agent[0]] == COLLISION and d.seg_len[by_agent[0]] == 46
    struck = {int(d.seg_agent[s]): bool(st) for s, st, kind in zip(d.ev_seg, d.ev_striker, d.ev_kind, strict=True)
              if kind == COLLISION_EVENT}
    assert struck == {0: True, 1: False}
    w = d.windows(WindowSpec())
    adv_agents = set(d.seg_agent[w.segment[w.label == ADVERSARIAL]].tolist())
    assert adv_agents == {0}
    # The third car (other lane) is clean driving to the end of the log: all of its windows are benign.
    assert d.seg_len[by_agent[2]] == N_STEPS - 1
    assert ((w.segment == by_agent[2]) & (w.label == BENIGN)).sum() == N_STEPS - 1 - 10 + 1


def test_log_demonstrations_follow_generated_traffic(highway) -> None:
    d = roll_out_demonstrations(highway[0], DemoConfig(source="log", end_step=40))
    assert (d.seg_source == LOG).all() and d.n_segments >= 8
    h = roll_out_demonstrations(highway[0], DemoConfig(end_step=40))
    assert (h.seg_source == HEURISTIC).all()
    # The log's drivers act smoothly: their per-step acceleration changes are far below the noisy heuristic's.
    jerk = lambda x: float(np.abs(np.diff(x.actions[:, 1])).mean())  # noqa: E731
    assert jerk(d) < 0.5 * jerk(h)
