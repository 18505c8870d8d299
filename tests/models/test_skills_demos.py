"""Skill demonstrations: the multi-agent simulation, window labelling, the demonstrations file and its build."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scenario_factory as sf

import seal.models.skills.demonstrations as demo_mod
from seal.core.geometry import overlaps_one, pairwise_overlaps
from seal.core.scenario import DT_S, N_STEPS
from seal.envs.heuristic import HeuristicDriver
from seal.envs.kinematics import AgentState
from seal.envs.multi_agent import COLLISION, FINISHED, HORIZON, OUT_OF_ROAD, MultiAgentSim, SimConfig
from seal.envs.observation import ObservationBuilder
from seal.envs.road_geometry import get_road_geometry
from seal.envs.route import Route
from seal.models.skills.demonstrations import DemoConfig, build_demonstrations, parts_dir, roll_out_demonstrations
from seal.models.skills.demos import (
    ADVERSARIAL,
    BENIGN,
    LOG,
    DemoFileError,
    Demonstrations,
    WindowSpec,
    split_by_scenario,
)


def _constant_track(x0: float, y: float, speed: float) -> np.ndarray:
    """A straight log along +x at constant speed (5 m x 2 m box)."""
    t = np.arange(N_STEPS) * DT_S
    track = np.zeros((N_STEPS, 8), dtype=np.float32)
    track[:, 0] = x0 + speed * t
    track[:, 1] = y
    track[:, 3] = speed
    track[:, 5], track[:, 6], track[:, 7] = 5.0, 2.0, 1.0
    return track


def _rear_end_scenario(gap_m: float = 45.5):
    """Follower at 20 m/s behind a leader at 10 m/s in lane 0; ``gap_m`` between the boxes at step 0."""
    road = sf.straight_road(2)
    follower = _constant_track(0.0, 0.0, 20.0)
    leader = _constant_track(5.0 + gap_m, 0.0, 10.0)
    return sf.make_scenario(road, [follower, leader], "rear_end")


def _segments(seg_len: list[int], reasons: list[int], source: int = LOG) -> Demonstrations:
    """Event-free demonstrations with segments of ``seg_len`` rows ending for ``reasons``."""
    n = len(seg_len)
    e = np.zeros(0, dtype=np.int64)
    return Demonstrations(
        obs=np.zeros((sum(seg_len), 100), np.float16), actions=np.zeros((sum(seg_len), 2), np.float32),
        seg_row=np.concatenate([[0], np.cumsum(seg_len)[:-1]]).astype(np.int64), seg_len=np.array(seg_len, np.int32),
        seg_scenario=np.zeros(n, np.int32), seg_agent=np.arange(n, dtype=np.int64),
        seg_start_step=np.zeros(n, np.int32), seg_end_reason=np.array(reasons, np.int8),
        seg_impaired=np.zeros(n, bool), seg_source=np.full(n, source, np.int8),
        ev_seg=e, ev_step=e.astype(np.int32), ev_kind=e.astype(np.int8), ev_striker=e.astype(bool),
        scenario_ids=np.array(["s"]), params={})


def test_windows_drop_near_out_of_road_ends_and_stride() -> None:
    d = _segments([50, 50, 7], [OUT_OF_ROAD, HORIZON, HORIZON])
    w = d.windows(WindowSpec(horizon=10, drop_steps=20))
    # Segment 0 (out of road): starts 21..40 end within 20 steps of it and are dropped, the rest benign.
    assert w.row[w.segment == 0].tolist() == list(range(21))
    assert (w.label == BENIGN).all() and w.n_dropped == 20
    assert (w.segment == 1).sum() == 41 and not (w.segment == 2).any()  # segment 2 is shorter than a window
    strided = d.windows(WindowSpec(stride=5))
    assert strided.row[strided.segment == 1].tolist() == [50 + s for s in range(0, 41, 5)]


def test_box_overlaps_matches_the_env_test() -> None:
    rng = np.random.default_rng(0)
    boxes = np.zeros((40, 8))
    boxes[:, :2] = rng.uniform(0, 15, (40, 2))
    boxes[:, 2] = rng.uniform(-np.pi, np.pi, 40)
    boxes[:, 5] = rng.uniform(3, 8, 40)
    boxes[:, 6] = rng.uniform(1.5, 2.5, 40)
    hit = pairwise_overlaps(boxes)
    assert hit.any() and not hit.all() and np.array_equal(hit, hit.T) and not hit.diagonal().any()
    for i in range(40):
        expected = overlaps_one(boxes[i, 0], boxes[i, 1], boxes[i, 2], boxes[i, 5], boxes[i, 6], boxes)
        expected[i] = False
        assert np.array_equal(hit[i], expected)


def test_rear_end_collision_at_the_predicted_step_labels_the_last_20_steps() -> None:
    gap, closing = 45.5, 10.0
    collide = math.floor(gap / (closing * DT_S)) + 1  # first step with the boxes overlapping: 46
    sim = MultiAgentSim(_rear_end_scenario(gap), SimConfig(start_step=0))
    steps = 0
    while not sim.done:
        idx, obs = sim.observe()
        assert obs.shape == (idx.size, 100)
        ended = sim.step(idx, np.zeros((idx.size, 2)))  # nobody brakes or steers
        steps += 1
        if ended:
            break
    assert steps == collide
    assert sorted((e.index, e.start_step, e.end_step, e.end_reason) for e in sim.ends) == [
        (0, 0, collide, COLLISION), (1, 0, collide, COLLISION)]
    # The same roll-out as heuristic demonstrations: the follower struck at step 46, so its windows starting at
    # steps 26..36 (2H before, inside its 46 rows) are adversarial; the leader was struck: none of its windows.
    d = roll_out_demonstrations(_rear_end_scenario(gap), DemoConfig(start_step=0, steer_noise=0.0, accel_noise=0.0,
                                                                  impaired_share=1.0, distraction_rate_hz=100.0,
                                                                  distraction_s=(9.0, 9.0)))
    w = d.windows(WindowSpec())
    follower = int(np.flatnonzero(d.seg_agent == 0)[0])
    assert d.seg_len[follower] == collide and d.seg_end_reason[follower] == COLLISION
    assert (w.row[w.label == ADVERSARIAL] - d.seg_row[follower]).tolist() == list(range(collide - 20, collide - 9))
    assert (w.segment[w.label == ADVERSARIAL] == follower).all() and not (w.label == BENIGN).any()


def test_out_of_road_finish_and_horizon_ends() -> None:
    road = sf.straight_road(2, length_m=400.0)
    # Agent 0 steers off the road; agent 1 reaches the end of its short logged route; agent 2 keeps going.
    short = _constant_track(0.0, 4.0, 10.0)
    short[40:, 7] = 0.0
    scenario = sf.make_scenario(road, [_constant_track(0.0, 0.0, 10.0), short, _constant_track(100.0, 4.0, 10.0)],
                                "ends", ego=0, adv=2)
    sim = MultiAgentSim(scenario, SimConfig(start_step=0, end_step=60))
    while not sim.done:
        idx, _ = sim.observe()
        actions = np.zeros((idx.size, 2))
        actions[idx == 0, 0] = -0.3  # steer right, over the solid road edge
        sim.step(idx, actions)
    ends = {e.index: e for e in sim.ends}
    assert ends[0].end_reason == OUT_OF_ROAD and ends[0].end_step < 20
    assert ends[1].end_reason == FINISHED and 36 <= ends[1].end_step <= 39  # 39 * 1 m logged, 1 m margin
    assert ends[2].end_reason == HORIZON and ends[2].end_step == 60


def test_agents_entering_late_are_driven_from_their_first_logged_step() -> None:
    road = sf.straight_road(2)
    late = _constant_track(60.0, 4.0, 10.0)
    late[:25, 7] = 0.0
    scenario = sf.make_scenario(
        road, [_constant_track(0.0, 0.0, 10.0), _constant_track(150.0, 0.0, 10.0), late], "late", ego=0, adv=1)
    sim = MultiAgentSim(scenario, SimConfig(start_step=0, end_step=40))
    seen = []
    while not sim.done:
        idx, _ = sim.observe()
        seen.append(idx.tolist())
        sim.step(idx, np.zeros((idx.size, 2)))
    assert seen[24] == [0, 1] and seen[25] == [0, 1, 2]
    assert {e.index: e.start_step for e in sim.ends} == {0: 0, 1: 0, 2: 25}


def test_demonstrations_record_own_viewpoint_and_are_deterministic(highway) -> None:
    scenario = highway[0]
    quiet = DemoConfig(steer_noise=0.0, accel_noise=0.0, impaired_share=0.0, start_step=0, end_step=30,
                       headway_range_s=(1.0, 1.0), min_gap_range_m=(2.5, 2.5))
    demos = roll_out_demonstrations(scenario, quiet)
    demos.validate()
    driven = scenario.n_agents
    assert demos.n_segments == driven
    # Each agent's first row is the observation from its own logged state at the first step (when everybody is
    # at their logged state), on its own route.
    geom = get_road_geometry(scenario.road)
    builder = ObservationBuilder(geom)
    at_start = np.flatnonzero(demos.seg_start_step == 0)
    assert at_start.size >= 8
    for k in at_start:
        i = scenario.index_of(int(demos.seg_agent[k]))
        t = 0
        others = np.delete(scenario.tracks[:, t].astype(np.float64), i, axis=0)
        others = others[others[:, 7] > 0.5][:, :7]
        route = Route.from_track(scenario.tracks[i].astype(np.float64), start_step=t)
        state = AgentState.from_track_row(scenario.tracks[i, t].astype(np.float64))
        expected = builder.build(state, route, others, route.project(state.x, state.y, route.start_segment))
        assert np.allclose(demos.obs[demos.seg_row[k]].astype(np.float32), expected, atol=2e-3)  # float16 storage
    # Without noise the recorded action is the heuristic's action for the recorded observation.
    driver = HeuristicDriver()
    acts = np.stack([driver.act(o.astype(np.float64)) for o in demos.obs])
    assert np.allclose(acts, demos.actions, atol=0.02)  # the observation went through float16
    noisy = DemoConfig(start_step=0, end_step=30, seed=3)
    a, b = roll_out_demonstrations(scenario, noisy), roll_out_demonstrations(scenario, noisy)
    assert np.array_equal(a.obs, b.obs) and np.array_equal(a.actions, b.actions)
    assert not np.allclose(a.actions[: demos.n_rows], demos.actions[: a.n_rows], atol=1e-3)
    c = roll_out_demonstrations(scenario, DemoConfig(start_step=0, end_step=30, seed=4))
    assert not np.array_equal(a.actions, c.actions)


def _braking_track(x0: float, speed: float, brake_s: float, decel: float) -> np.ndarray:
    """Along lane 0 at ``speed``, braking at ``decel`` (m/s^2) from ``brake_s`` to a stop."""
    t = np.arange(N_STEPS) * DT_S
    v = np.where(t < brake_s, speed, np.maximum(0.0, speed - decel * (t - brake_s)))
    track = _constant_track(x0, 0.0, speed)
    track[:, 0] = x0 + np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * DT_S)])
    track[:, 3] = v
    return track


def test_impaired_drivers_rear_end_a_braking_leader_attentive_ones_do_not() -> None:
    # The leader brakes to a stop at 3 m/s^2 (its log; the heuristic follows its logged speed). The follower's
    # route keeps 20 m/s: only its IDM reaction to the leader can stop it.
    road = sf.straight_road(2)
    scenario = sf.make_scenario(road, [_constant_track(0.0, 0.0, 20.0), _braking_track(35.0, 20.0, 1.5, 3.0)],
                                "brake")
    calm = DemoConfig(steer_noise=0.0, accel_noise=0.0, impaired_share=0.0)
    impaired = DemoConfig(impaired_share=1.0, reaction_delay_steps=(15, 15), distraction_rate_hz=2.0,
                          distraction_s=(3.0, 3.0))
    a = roll_out_demonstrations(scenario, calm)
    assert a.seg_end_reason.tolist() == [HORIZON, HORIZON] and not a.seg_impaired.any()
    b = roll_out_demonstrations(scenario, impaired)
    assert b.seg_end_reason.tolist() == [COLLISION, COLLISION] and b.seg_impaired.all()
    assert b.seg_len[0] < 80


def test_demonstrations_file_round_trip_and_errors(tmp_path, highway) -> None:
    demos = roll_out_demonstrations(highway[1], DemoConfig(end_step=25))
    path = tmp_path / "d.npz"
    demos.save(path)
    back = Demonstrations.load(path)
    for name in ("obs", "actions", "seg_row", "seg_len", "seg_end_reason", "seg_agent", "scenario_ids", "seg_source",
                 "ev_seg", "ev_step", "ev_kind", "ev_striker"):
        assert np.array_equal(getattr(back, name), getattr(demos, name)), name
    assert back.params == demos.params
    broken = Demonstrations.load(path)
    broken.seg_len[0] = 10_000
    broken.save(tmp_path / "bad.npz")
    with pytest.raises(DemoFileError, match=r"bad\.npz.*'seg_row'/'seg_len'"):
        Demonstrations.load(tmp_path / "bad.npz")
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(DemoFileError, match="junk.npz"):
        Demonstrations.load(tmp_path / "junk.npz")


def test_split_by_scenario_holds_out_whole_scenarios() -> None:
    w = _segments([60] * 10, [HORIZON] * 10).windows(WindowSpec())
    seg_scenario = np.repeat(np.arange(5), 2)
    train, val = split_by_scenario(w, seg_scenario, 5, 0.2, seed=0)
    assert len(train) + len(val) == len(w)
    val_scen = set(seg_scenario[val.segment].tolist())
    assert len(val_scen) == 1 and not val_scen & set(seg_scenario[train.segment].tolist())


def test_build_resumes_from_finished_chunks(tmp_path, highway, monkeypatch) -> None:
    cfg = DemoConfig(end_step=20)
    out = tmp_path / "demos.npz"
    real = demo_mod._run_chunk
    calls: list[int] = []

    def failing(job):
        if calls:
            raise KeyboardInterrupt
        calls.append(job[0])
        return real(job)

    monkeypatch.setattr(demo_mod, "_run_chunk", failing)
    with pytest.raises(KeyboardInterrupt):
        build_demonstrations(highway, out, cfg, workers=1, chunk_size=1, progress=False)
    assert not out.exists() and len(list(parts_dir(out).glob("part_*.npz"))) == 1
    done: list[int] = []
    monkeypatch.setattr(demo_mod, "_run_chunk", lambda job: (done.append(job[0]), real(job))[1])
    merged = build_demonstrations(highway, out, cfg, workers=1, chunk_size=1, progress=False)
    assert done == [1, 2]  # chunk 0 was reused
    assert not parts_dir(out).exists()
    fresh = Demonstrations.concat([roll_out_demonstrations(s, cfg) for s in highway])
    assert np.array_equal(merged.obs, fresh.obs) and np.array_equal(merged.seg_scenario, fresh.seg_scenario)
    assert Demonstrations.load(out).scenario_ids.tolist() == [s.scenario_id for s in highway]


def test_expert_source_records_clean_actions_while_applying_noisy_ones(highway) -> None:
    """DART: the applied action is noisy, so the track leaves the quiet expert's; the recorded action is the clean
    heuristic's action for the recorded observation. Only the ego and the expert share of others are recorded."""
    scenario = highway[0]
    noisy = DemoConfig(source="expert", start_step=0, end_step=40, expert_share=0.0, expert_steer_noise=0.1,
                       expert_accel_noise=0.4, seed=1)
    demos = roll_out_demonstrations(scenario, noisy)
    demos.validate()
    assert demos.n_segments == 1 and int(demos.seg_agent[0]) == scenario.ego_id
    assert set(demos.seg_source.tolist()) == {demo_mod.EXPERT}
    driver = HeuristicDriver()
    clean = np.stack([driver.act(o.astype(np.float64)) for o in demos.obs])
    assert np.allclose(clean, demos.actions, atol=0.02)  # the observation went through float16
    quiet = roll_out_demonstrations(scenario, DemoConfig(source="expert", start_step=0, end_step=40,
                                                         expert_share=0.0, expert_steer_noise=0.0,
                                                         expert_accel_noise=0.0, seed=1))
    # The noise moved the expert off the quiet expert's path: its observations differ.
    assert np.abs(quiet.obs.astype(np.float32) - demos.obs.astype(np.float32)).max() > 0.05
    again = roll_out_demonstrations(scenario, noisy)
    assert np.array_equal(again.obs, demos.obs) and np.array_equal(again.actions, demos.actions)
    everyone = roll_out_demonstrations(scenario, DemoConfig(source="expert", start_step=0, end_step=40,
                                                            expert_share=1.0))
    assert everyone.n_segments == scenario.n_agents


def test_a_source_identity_holds_only_the_settings_it_uses() -> None:
    """A fit that changes the noisy drivers' settings reuses the log's and the expert's files (and the ``expert_*``
    settings are not part of the other sources' parameters)."""
    log = DemoConfig(source="log", expert_share=0.9, distraction_rate_hz=0.0, noise_tau_s=2.0).to_dict()
    assert not any(k.startswith("expert_") for k in log)
    assert log == DemoConfig(source="log").to_dict() and "distraction_rate_hz" not in log
    assert DemoConfig.from_dict(log) == DemoConfig(source="log")
    assert DemoConfig(source="expert", expert_share=0.9).to_dict()["expert_share"] == 0.9
    expert = DemoConfig(source="expert", impaired_share=0.0, noise_tau_s=2.0).to_dict()
    assert "impaired_share" not in expert and expert["noise_tau_s"] == 2.0
    heuristic = DemoConfig(source="heuristic", distraction_rate_hz=0.0, expert_share=0.9).to_dict()
    assert heuristic["distraction_rate_hz"] == 0.0 and "expert_share" not in heuristic
    with pytest.raises(ValueError, match="expert_share"):
        DemoConfig(source="expert", expert_share=1.5)
