"""TrajectoryPrior: shapes, latents, world frame, determinism, overfitting, fallback, files."""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf
import torch

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import CURRENT_STEP, DT_S, Scenario
from seal.models.prior import FeatureConfig, PriorConfig, PriorTrainConfig, TrajectoryPrior, fit_prior
from seal.models.prior.prior import PriorFileError
from seal.models.prior.samples import TargetFilter

TINY = PriorConfig(
    features=FeatureConfig(n_agents=8, n_chunks=8), d_model=32, n_heads=2, n_layers=1, n_knots=8, n_modes=32
)


def tiny_train(epochs: int, seed: int = 0, val_fraction: float = 0.2, road_weight: float = 1.0) -> PriorTrainConfig:
    return PriorTrainConfig(
        epochs=epochs, batch_size=256, lr=3e-3, warmup_steps=5, val_fraction=val_fraction, patience=10_000,
        max_minutes=None, seed=seed, road_weight=road_weight, road_chunks=24,
    )


def transformed(s: Scenario, angle: float, shift: tuple[float, float], sid: str) -> Scenario:
    """``s`` rotated by ``angle`` about the origin, then shifted: positions, headings, velocities and lanes."""
    c, si = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -si], [si, c]])
    tr = s.tracks.astype(np.float64).copy()
    valid = tr[:, :, 7:8]
    tr[:, :, 0:2] = (tr[:, :, 0:2] @ rot.T + np.array(shift)) * valid
    tr[:, :, 3:5] = tr[:, :, 3:5] @ rot.T
    tr[:, :, 2] = (tr[:, :, 2] + angle) * valid[..., 0]
    lanes = tuple(
        LaneSpec(lane.lane_id, lane.centerline @ rot.T + np.array(shift), lane.width_m, lane.line_types,
                 lane.speed_limit_mps, lane.successors)
        for lane in s.road.lanes
    )
    road = RoadDescription(s.road.layout, lanes, s.road.params)
    return Scenario(sid, tr, s.agent_ids, s.agent_types, s.ego_id, s.adv_id, road, s.source, s.metadata)


@pytest.fixture(scope="module")
def untrained() -> TrajectoryPrior:
    return TrajectoryPrior.untrained(seed=0)


@pytest.fixture(scope="module")
def handful() -> list[Scenario]:
    return [sf.highway_scenario(i) for i in range(4)] + [sf.lane_change_scenario(), sf.curve_scenario()]


@pytest.fixture(scope="module")
def overfit(handful: list[Scenario], tmp_path_factory: pytest.TempPathFactory) -> TrajectoryPrior:
    out = tmp_path_factory.mktemp("prior") / "overfit.pt"
    # No on-road loss here: the point is the capacity to fit the logged futures.
    cfg = tiny_train(epochs=150, val_fraction=0.1, road_weight=0.0)
    return fit_prior(handful, out, TINY, cfg, progress=False)


def test_predict_shapes_order_and_default_adversary(untrained: TrajectoryPrior, all_scenarios: list[Scenario]
                                                    ) -> None:
    cands = untrained.predict(all_scenarios)
    assert len(cands) == len(all_scenarios)
    for s, c in zip(all_scenarios, cands, strict=True):
        assert c.agent_index == s.adv_index and c.fallback is None
        assert c.xy.shape == (32, 80, 2) and c.heading.shape == (32, 80) and c.speed.shape == (32, 80)
        assert np.all(np.diff(c.probs) <= 0) and c.probs.sum() == pytest.approx(1.0)
        # Speed follows from the positions (the step before step 0 is the current position).
        start = s.tracks[s.adv_index, CURRENT_STEP, :2].astype(np.float64)
        assert np.allclose(np.linalg.norm(c.xy[:, 0] - start, axis=-1) / DT_S, c.speed[:, 0])
    ego = untrained.predict(all_scenarios[:2], [s.ego_index for s in all_scenarios[:2]])
    assert [c.agent_index for c in ego] == [s.ego_index for s in all_scenarios[:2]]


def test_encode_exposes_per_agent_latents_and_decode_matches_predict(
    untrained: TrajectoryPrior, all_scenarios: list[Scenario]
) -> None:
    enc = untrained.encode(all_scenarios)
    cfg = untrained.config
    assert enc.agent_latents.shape == (len(all_scenarios), cfg.features.n_agents, cfg.d_model)
    assert enc.target_latent.shape == (len(all_scenarios), cfg.d_model)
    assert enc.agent_index[:, 0].tolist() == [s.adv_index for s in all_scenarios]
    for s, row, m in zip(all_scenarios, enc.agent_index, enc.mask[:, : cfg.features.n_agents], strict=True):
        present = row[row >= 0]
        assert len(set(present.tolist())) == len(present) and present.max() < s.n_agents
        assert m.sum().item() == len(present)
    xy, probs = untrained.decode(enc)
    cands = untrained.predict(all_scenarios)
    for j, c in enumerate(cands):
        order = np.argsort(-probs[j], kind="stable")
        assert np.allclose(xy[j][order], c.xy) and np.allclose(probs[j][order], c.probs)
    # Steering hook: an offset on the target latent changes the candidates, a zero offset does not.
    same, _ = untrained.decode(enc.with_target_offset(torch.zeros(cfg.d_model)))
    moved, _ = untrained.decode(enc.with_target_offset(3.0 * torch.ones(cfg.d_model)))
    assert np.allclose(same, xy) and not np.allclose(moved, xy, atol=0.1)


def test_candidates_follow_rigid_motions_of_the_scenario(untrained: TrajectoryPrior, all_scenarios: list[Scenario]
                                                         ) -> None:
    angle, shift = 2.1, (350.0, -120.0)
    moved = [transformed(s, angle, shift, s.scenario_id + "-moved") for s in all_scenarios]
    c, si = math.cos(angle), math.sin(angle)
    rot = np.array([[c, -si], [si, c]])
    for a, b in zip(untrained.predict(all_scenarios), untrained.predict(moved), strict=True):
        assert np.allclose(a.xy @ rot.T + np.array(shift), b.xy, atol=2e-2)
        assert np.allclose(a.probs, b.probs, atol=1e-4)


def test_untrained_predictions_are_deterministic_for_a_seed(all_scenarios: list[Scenario]) -> None:
    a = TrajectoryPrior.untrained(TINY, seed=3).predict(all_scenarios)
    b = TrajectoryPrior.untrained(TINY, seed=3).predict(all_scenarios)
    c = TrajectoryPrior.untrained(TINY, seed=4).predict(all_scenarios)
    assert all(np.array_equal(x.xy, y.xy) and np.array_equal(x.probs, y.probs) for x, y in zip(a, b, strict=True))
    assert not np.allclose(a[0].probs, c[0].probs)


def test_training_is_deterministic_for_a_seed(handful: list[Scenario], tmp_path: Path) -> None:
    runs = [
        fit_prior(handful, tmp_path / f"m{i}.pt", TINY, tiny_train(epochs=3, seed=seed), progress=False)
        for i, seed in enumerate((7, 7, 8))
    ]
    sa, sb, sc = (r.net.state_dict() for r in runs)
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert not all(torch.equal(sa[k], sc[k]) for k in sa)
    def losses(run: TrajectoryPrior) -> list[dict]:
        return [{k: v for k, v in h.items() if k != "seconds"} for h in run.training["history"]]

    assert losses(runs[0]) == losses(runs[1])


def test_tiny_model_overfits_a_handful_of_scenarios(overfit: TrajectoryPrior) -> None:
    t = overfit.training
    assert t["n_train_targets"] >= 30
    first, last = t["initial_train_loss"], t["history"][-1]["train_loss"]
    assert last <= first / 10.0, (first, last)


def test_straight_driver_gets_candidates_ahead_in_the_world_frame(overfit: TrajectoryPrior) -> None:
    road = sf.straight_road(3, length_m=1200.0)
    lead = sf.simulate_track(road.lanes[1].centerline, 200.0, 22.0, substeps=2)
    other = sf.simulate_track(road.lanes[0].centerline, 150.0, 20.0, substeps=2)
    s = sf.make_scenario(road, [other, lead], "straight", ego=0, adv=1)
    for angle, shift in ((0.0, (0.0, 0.0)), (math.pi / 2, (40.0, -300.0))):
        moved = transformed(s, angle, shift, f"straight-{angle}")
        cand = overfit.predict([moved])[0]
        x0 = moved.tracks[1, CURRENT_STEP, :2].astype(np.float64)
        direction = np.array([math.cos(angle), math.sin(angle)])
        ahead = (cand.xy - x0) @ direction  # [K, T] along the driving direction, m
        side = (cand.xy - x0) @ np.array([-direction[1], direction[0]])
        # The most likely candidate drives on ahead (lane keeping or a lane change), not sideways or back.
        assert np.all(np.diff(ahead[0]) > 0) and ahead[0, -1] > 50.0, ahead[0, -1]
        assert np.max(np.abs(side[0])) < 1.5 * 4.0
        # And almost all candidates end well ahead.
        assert np.mean(ahead[:, -1] > 50.0) >= 0.9


def test_short_history_falls_back_to_constant_velocity(untrained: TrajectoryPrior) -> None:
    road = sf.straight_road(2)
    ego = sf.simulate_track(road.lanes[0].centerline, 50.0, 20.0)
    adv = sf.simulate_track(road.lanes[1].centerline, 80.0, 18.0, valid_from=CURRENT_STEP)  # 1 history step
    s = sf.make_scenario(road, [ego, adv], "newcomer")
    cand = untrained.predict([s])[0]
    assert cand.fallback is not None and "history" in cand.fallback
    assert cand.xy.shape == (32, 80, 2)
    row = s.tracks[1, CURRENT_STEP].astype(np.float64)
    t = np.arange(1, 81) * DT_S
    assert np.allclose(cand.xy[0], row[:2] + np.stack([row[3] * t, row[4] * t], axis=-1))
    with pytest.raises(ValueError, match="history"):
        untrained.predict([s], fallback=False)
    with pytest.raises(ValueError, match="history"):
        untrained.encode([s])
    # Mixed batch: the fallback does not disturb the network's answer for the others.
    normal = sf.curve_scenario()
    mixed = untrained.predict([normal, s])
    assert mixed[0].fallback is None and np.allclose(mixed[0].xy, untrained.predict([normal])[0].xy)


def test_absent_or_unknown_agents_raise(untrained: TrajectoryPrior) -> None:
    s = sf.lane_change_scenario()  # agent 2 appears at step 20
    with pytest.raises(ValueError, match="not valid at the current step"):
        untrained.predict([s], [2])
    with pytest.raises(ValueError, match="out of range"):
        untrained.predict([s], [17])
    with pytest.raises(ValueError, match="agent indices"):
        untrained.predict([s], [0, 1])


def test_save_load_round_trip_and_bad_files(untrained: TrajectoryPrior, all_scenarios: list[Scenario],
                                            tmp_path: Path) -> None:
    path = tmp_path / "prior.pt"
    untrained.save(path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["prior.pt"]  # no temp file left behind
    loaded = TrajectoryPrior.load(path)
    assert loaded.config == untrained.config
    for a, b in zip(untrained.predict(all_scenarios), loaded.predict(all_scenarios), strict=True):
        assert np.array_equal(a.xy, b.xy)
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a model")
    with pytest.raises(PriorFileError, match="garbage.pt"):
        TrajectoryPrior.load(garbage)
    foreign = tmp_path / "foreign.pt"
    torch.save({"format": "something-else"}, foreign)
    with pytest.raises(PriorFileError, match="format"):
        TrajectoryPrior.load(foreign)
    pickled = tmp_path / "pickled.pt"
    torch.save({"format": "seal-trajectory-prior", "payload": Path("x")}, pickled)  # arbitrary class: refused
    with pytest.raises(PriorFileError, match="pickled.pt"):
        TrajectoryPrior.load(pickled)
    state = untrained.state()
    state["config"] = replace(untrained.config, d_model=16).to_dict()
    with pytest.raises(PriorFileError, match="state_dict"):
        TrajectoryPrior.from_state(state)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        TrajectoryPrior.load(tmp_path / "missing.pt")


def test_targets_skip_parked_and_short_lived_agents() -> None:
    from seal.models.prior.samples import select_targets

    s = sf.lane_change_scenario()  # agent 2 appears at step 20: not valid now
    assert 2 not in select_targets(s, TargetFilter()).tolist()
    assert select_targets(s, TargetFilter(adversary_only=True)).tolist() == [s.adv_index]
    road = sf.straight_road(2)
    parked = sf.simulate_track(road.lanes[0].centerline, 30.0, 0.0)
    moving = sf.simulate_track(road.lanes[1].centerline, 30.0, 10.0)
    s2 = sf.make_scenario(road, [moving, parked], "parked", ego=0, adv=1)
    assert select_targets(s2, TargetFilter()).tolist() == [0]


def test_interrupted_training_resumes_to_the_same_model(handful: list[Scenario], tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch,
                                                        caplog: pytest.LogCaptureFixture) -> None:
    import seal.models.prior.train as train_mod

    monkeypatch.setattr(train_mod, "STATE_EVERY_S", 0.0)  # save the resumable state after every epoch
    cfg = tiny_train(epochs=3, seed=5)
    straight = fit_prior(handful, tmp_path / "straight.pt", TINY, cfg, progress=False)

    class InterruptInEpoch2(logging.Handler):
        """Stands for a Ctrl-C while epoch 2's line is logged (after its training, before its state is saved)."""

        def emit(self, record: logging.LogRecord) -> None:
            if record.getMessage().startswith("epoch 2:"):
                raise KeyboardInterrupt

    out = tmp_path / "resumed.pt"
    caplog.set_level(logging.INFO, logger=train_mod.__name__)
    interrupt = InterruptInEpoch2()
    train_mod.logger.addHandler(interrupt)
    try:
        with pytest.raises(KeyboardInterrupt):
            fit_prior(handful, out, TINY, cfg, progress=False)
    finally:
        train_mod.logger.removeHandler(interrupt)
    assert train_mod.state_path(out).exists()
    # what `seal run` goes on from without a resume option: a state of these very settings only
    assert train_mod.resumable_state(out, TINY, cfg)
    assert not train_mod.resumable_state(out, TINY, replace(cfg, epochs=4))
    assert not train_mod.resumable_state(tmp_path / "never.pt", TINY, cfg)
    caplog.clear()
    resumed = fit_prior(handful, out, TINY, cfg, resume=True, progress=False)
    assert any("resuming after epoch 1" in m for m in caplog.messages)
    assert resumed.training["epochs_run"] == 3 and not train_mod.state_path(out).exists()
    a, b = straight.net.state_dict(), resumed.net.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    # A state written with other settings is refused rather than mixed in.
    train_mod._save_state(train_mod.state_path(out), resumed.net, torch.optim.AdamW(resumed.net.parameters()),
                          None, {"epoch": 1}, [{"other": 1}, {}])
    with pytest.raises(ValueError, match="another model or training config"):
        fit_prior(handful, out, TINY, cfg, resume=True, progress=False)
    assert not train_mod.resumable_state(out, TINY, cfg)
    train_mod.state_path(out).write_bytes(b"cut short")
    assert not train_mod.resumable_state(out, TINY, cfg)


def test_a_budget_that_cuts_the_plan_is_named_as_the_stop_reason(handful: list[Scenario], tmp_path: Path) -> None:
    # A budget spent during the first epoch plans no more: the stop reason must say the budget decided (the model
    # then depends on the machine's speed), not that the planned epochs were completed.
    cut = fit_prior(handful, tmp_path / "cut.pt", TINY, replace(tiny_train(epochs=3), max_minutes=1e-6),
                    progress=False).training
    assert cut["epochs_run"] == 1 and cut["stop_reason"].startswith("time budget of 1e-06 min reached: 1 of 3")
    full = fit_prior(handful, tmp_path / "full.pt", TINY, tiny_train(epochs=2), progress=False).training
    assert full["epochs_run"] == 2 and full["stop_reason"] == "completed 2 planned epochs"
