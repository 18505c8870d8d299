"""Behaviour embedding data: encoder inputs in the target frame, SafeShift labels (eq. 7.1) with an even delta, the
crash set's cause / reaction labels, the Table 7.5 metrics on hand-built clusters, and the model file."""

from __future__ import annotations

import numpy as np
import pytest

import tests.scenario_factory as sf
from seal.core.scenario import CURRENT_STEP, HEADING, N_STEPS, VALID, X, Y
from seal.models.behavior.analysis import cluster_quality, davies_bouldin, kmeans, linear_probe, silhouette
from seal.models.behavior.crash_set import CrashSetConfig, closest_approach, crash_samples
from seal.models.behavior.features import BehaviorFeatureConfig, scene_inputs, scene_targets, target_inputs
from seal.models.behavior.labels import NEUTRAL, SAFE, UNSAFE, class_shares, even_delta, safety_labels

CFG = BehaviorFeatureConfig(n_agents=3, stride_steps=10)


# ------------------------------------------------------------------------------------------------------- inputs
def test_inputs_are_in_the_target_frame_with_the_closest_agents_first() -> None:
    s = sf.lane_change_scenario()  # ego 0, adversary 1 ahead in lane 1, two cars in lane 2
    inputs = scene_inputs(s.tracks, np.array([1]), CFG)
    rows = CFG.rows
    assert rows.tolist() == list(range(0, N_STEPS, 10)) and CFG.n_rows == 10
    # The target sits at the origin heading +x at the current step (row 1 of the sub-sampled rows is step 10).
    np.testing.assert_allclose(inputs.target_xy[0, 1], [0.0, 0.0], atol=1e-5)
    adv = s.tracks[1].astype(np.float64)
    expected = (adv[rows][:, [X, Y]] - adv[CURRENT_STEP, [X, Y]]) @ np.array(
        [[np.cos(adv[CURRENT_STEP, HEADING]), -np.sin(adv[CURRENT_STEP, HEADING])],
         [np.sin(adv[CURRENT_STEP, HEADING]), np.cos(adv[CURRENT_STEP, HEADING])]])
    np.testing.assert_allclose(inputs.target_xy[0], expected, atol=1e-4)
    tok = inputs.agents[0].reshape(3, -1)
    assert inputs.mask.tolist() == [[True, True, True]]
    np.testing.assert_allclose(tok[0, :2], inputs.target_xy[0, 0] / CFG.pos_scale_m, atol=1e-6)
    assert tok[0, -1] == 1.0 and tok[1, -1] == 0.0  # is-target flag
    # Second token: the agent that comes closest to the adversary over the rows where both exist.
    gaps = []
    for a in (0, 2, 3):
        both = (s.tracks[a, rows, VALID] > 0.5) & (s.tracks[1, rows, VALID] > 0.5)
        gaps.append(np.linalg.norm(s.tracks[a, rows][both][:, [X, Y]] - s.tracks[1, rows][both][:, [X, Y]],
                                   axis=1).min())
    closest = (0, 2, 3)[int(np.argmin(gaps))]
    other_x = (s.tracks[closest, 0, X] - adv[CURRENT_STEP, X]) / CFG.pos_scale_m  # straight road: frame = world
    assert tok[1, 0] == pytest.approx(other_x, abs=1e-3)


def test_missing_agents_are_masked_and_invalid_rows_zeroed() -> None:
    s = sf.curve_scenario()  # two agents only
    inputs = scene_inputs(s.tracks, np.array([0, 1]), CFG)
    assert inputs.mask.tolist() == [[True, True, False], [True, True, False]]
    assert not inputs.agents[:, 2].any()
    tracks = s.tracks.copy()
    tracks[1, 40:, VALID] = 0.0
    inp = target_inputs(tracks[None], np.array([0]), CFG)
    per_row = inp.agents[0, 1, :-3].reshape(CFG.n_rows, 7)
    assert not per_row[4:].any() and per_row[:4, 6].all()
    with pytest.raises(ValueError, match="current step"):
        bad = tracks.copy()
        bad[0, CURRENT_STEP, VALID] = 0.0
        target_inputs(bad[None], np.array([0]), CFG)
    assert scene_targets(tracks, min_valid_rows=5, cfg=CFG).tolist() == [0]  # agent 1 is valid on 4 rows


# ------------------------------------------------------------------------------------------------------- labels
def test_safety_labels_follow_eq_7_1() -> None:
    diff = np.array([-2.0, -0.5, 0.0, 0.5, 0.51, 3.0])
    assert safety_labels(diff, 0.5).tolist() == [SAFE, NEUTRAL, NEUTRAL, NEUTRAL, UNSAFE, UNSAFE]
    with pytest.raises(ValueError, match="delta"):
        safety_labels(diff, -1.0)


def test_even_delta_balances_the_classes() -> None:
    diff = np.array([-3.0, -2.0, -0.1, 0.05, 0.2, 2.5])  # two clearly negative, two small, two clearly positive
    delta = even_delta(diff)
    assert delta == pytest.approx(0.1)  # smallest delta with |diff| <= delta holding exactly two values
    np.testing.assert_allclose(class_shares(safety_labels(diff, delta)), [1 / 3, 1 / 3, 1 / 3])
    rng = np.random.default_rng(0)
    skewed = rng.normal(0.5, 1.0, 3000)
    best = np.abs(class_shares(safety_labels(skewed, even_delta(skewed))) - 1 / 3).max()
    # One symmetric threshold cannot even out a skewed distribution; no other threshold does better, though.
    grid = [np.abs(class_shares(safety_labels(skewed, d)) - 1 / 3).max() for d in np.linspace(0.0, 3.0, 601)]
    assert best <= min(grid) + 1e-12 and best < 0.2


# ---------------------------------------------------------------------------------------------------- crash set
def _pair(ego_track: np.ndarray, adv_track: np.ndarray, **meta: str):
    road = sf.straight_road(3)
    return sf.make_scenario(road, [ego_track, adv_track], "pair", metadata=meta)


def test_crash_set_blames_the_follower_closing_from_behind() -> None:
    road = sf.straight_road(3)
    lane = road.lanes[1].centerline
    lead = sf.simulate_track(lane, 60.0, 10.0, substeps=2)
    follow = sf.simulate_track(lane, 30.0, 20.0, substeps=2)  # 20 m/s into a 10 m/s car 30 m ahead: meets ~3 s
    s = _pair(follow, lead)
    step, gap = closest_approach(s)
    assert gap == 0.0 and CURRENT_STEP < step < 50
    samples = crash_samples([s], CrashSetConfig())
    assert [(x.agent, x.label, x.role) for x in samples] == [(0, UNSAFE, "aggressor"), (1, NEUTRAL, "recipient")]
    assert samples[0].reason == "closed the gap from behind"


def test_crash_set_blames_the_cut_in_and_credits_a_braking_recipient() -> None:
    road = sf.straight_road(3)
    # The ego (25 m/s) closes on a 20 m/s car in the next lane that cuts in ahead of it; the ego brakes at 5 m/s^2
    # from 2 s: relative speed 0 at 3 s with about 2.5 m between the boxes.
    ego = sf.simulate_track(road.lanes[1].centerline, 30.0, 25.0, accel_fn=lambda t: -5.0 if t > 2.0 else 0.0,
                            substeps=2)
    cutter = sf.simulate_track(road.lanes[0].centerline, 50.0, 20.0, substeps=2,
                               offset_fn=lambda t: min(1.0, max(0.0, (t - 0.5) / 1.5)) * sf.LANE_WIDTH_M)
    samples = crash_samples([_pair(ego, cutter)], CrashSetConfig(near_miss_m=3.0))
    roles = {x.agent: (x.label, x.role) for x in samples}
    assert roles == {1: (UNSAFE, "aggressor"), 0: (SAFE, "recipient")}
    # A driver model in the log overrides the geometry.
    samples = crash_samples([_pair(ego, cutter, ego_driver="aggressive", adv_driver="normal")],
                            CrashSetConfig(near_miss_m=3.0))
    assert {x.agent: x.label for x in samples}[0] == UNSAFE
    # Pairs that stay apart are not in the crash set.
    far = sf.simulate_track(road.lanes[2].centerline, 200.0, 20.0, substeps=2)
    assert crash_samples([_pair(ego, far)], CrashSetConfig()) == []


# ----------------------------------------------------------------------------------------------------- analysis
def test_silhouette_and_davies_bouldin_match_hand_values() -> None:
    x = np.array([[0.0, 0.0], [0.0, 1.0], [4.0, 0.0], [4.0, 1.0]])
    lab = np.array([0, 0, 1, 1])
    # a = 1; b = mean(4, sqrt(17)) for every point -> s = (b - a) / b
    b = (4.0 + np.sqrt(17.0)) / 2
    assert silhouette(x, lab) == pytest.approx((b - 1.0) / b)
    # s_i = 0.5, centroid distance 4 -> DB = (0.5 + 0.5) / 4
    assert davies_bouldin(x, lab) == pytest.approx(0.25)
    with pytest.raises(ValueError, match="two clusters"):
        silhouette(x, np.zeros(4))


def test_kmeans_probe_and_cluster_quality_see_structure() -> None:
    rng = np.random.default_rng(0)
    centres = np.array([[0, 0], [10, 0], [0, 10]], dtype=float)
    x = np.concatenate([c + rng.normal(0, 0.5, (30, 2)) for c in centres])
    truth = np.repeat(np.arange(3), 30)
    found = kmeans(x, 3, seed=1)
    assert len({tuple(np.unique(found[truth == k])) for k in range(3)}) == 3  # one cluster per blob
    assert all(np.unique(found[truth == k]).size == 1 for k in range(3))
    assert linear_probe(x[::2], truth[::2], x[1::2], truth[1::2]) == 1.0
    structured = cluster_quality(x, truth)
    shuffled = cluster_quality(x, rng.permutation(truth))
    assert structured["silhouette"] > shuffled["silhouette"]
    assert structured["davies_bouldin"] < shuffled["davies_bouldin"]


# --------------------------------------------------------------------------------------------------- model file
def test_model_file_round_trip_and_bad_files(tmp_path) -> None:
    import torch

    from seal.models.behavior.model import BehaviorFileError, BehaviorModel
    from seal.models.behavior.network import BehaviorConfig

    torch.manual_seed(0)
    model = BehaviorModel(BehaviorConfig(features=CFG, d_model=16, n_heads=2, n_layers=1, latent_dim=24,
                                         proj_dim=4, lora_rank=4, n_modes=2), info={"note": "x"})
    model.set_unsafe_cache(np.eye(4)[:3])
    s = sf.lane_change_scenario()
    v = model.embed_tracks(s.tracks[None].repeat(2, 0), np.array([0, 1]))
    assert v.shape == (2, 4)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, rtol=1e-5)
    path = model.save(tmp_path / "b.pt")
    back = BehaviorModel.load(path)
    np.testing.assert_array_equal(back.embed_tracks(s.tracks[None].repeat(2, 0), np.array([0, 1])), v)
    np.testing.assert_array_equal(back.unsafe_cache, np.eye(4, dtype=np.float32)[:3])
    assert back.info == {"note": "x"} and (tmp_path / "b.json").exists()
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    with pytest.raises(BehaviorFileError, match="junk.pt"):
        BehaviorModel.load(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError, match="seal fit behavior"):
        BehaviorModel.load(tmp_path / "missing.pt")
