"""RAPID background model (issue 22, paper 004): guidance (eq. 7), the per-scenario map cache, training and the
model file, the social-force targets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf
import torch

from seal.core.scenario import CURRENT_STEP, VALID, X
from seal.envs.background import roll_background
from seal.envs.scenario_env import ScenarioEnv
from seal.models.rapid import Guidance, RapidBackground, load_rapid
from seal.models.rapid.data import build_samples
from seal.models.rapid.network import RapidNet
from seal.models.rapid.sampler import ddim_sample, guide, map_force, schedule, social_force
from seal.models.rapid.train import RapidFileError, RapidTrainConfig, save_rapid, train_rapid

UNGUIDED = Guidance(w_destination=0.0, w_social=0.0, w_map=0.0, w_safety=0.0)


@pytest.fixture(scope="module")
def net() -> RapidNet:
    torch.manual_seed(0)
    return RapidNet(16).eval()


def test_guide_moves_x0_toward_the_target_and_is_identity_at_zero_weights() -> None:
    x0 = torch.tensor([[1.0, -1.0], [0.0, 2.0]])
    target = torch.tensor([[-1.0, 0.5], [0.5, 0.0]])
    g = Guidance(w_destination=0.2, w_social=0.0, w_map=0.0)
    moved = guide(x0, {"destination": target}, g)
    assert torch.all((moved - target).norm(dim=1) < (x0 - target).norm(dim=1))
    torch.testing.assert_close(moved, x0 - 0.4 * (x0 - target))  # eq. 7: x0 - w * grad ||x0 - a||^2
    assert torch.equal(guide(x0, {"destination": target, "social": target, "map": target}, UNGUIDED), x0)


def test_sampler_with_guidance_lands_closer_to_the_target(net: RapidNet) -> None:
    ctx = torch.randn(64, 16, generator=torch.Generator().manual_seed(1))
    target = torch.full((64, 2), 1.5)
    ab = schedule()
    plain = ddim_sample(net.denoiser, ctx, ab, 5, torch.Generator().manual_seed(2), {}, UNGUIDED)
    zero = ddim_sample(net.denoiser, ctx, ab, 5, torch.Generator().manual_seed(2), {"destination": target}, UNGUIDED)
    guided = ddim_sample(net.denoiser, ctx, ab, 5, torch.Generator().manual_seed(2), {"destination": target},
                         Guidance(w_destination=0.25, w_social=0.0, w_map=0.0))
    assert torch.equal(zero, plain)
    assert float((guided - target).norm(dim=1).mean()) < 0.6 * float((plain - target).norm(dim=1).mean())


def test_zero_weights_leave_the_controller_unchanged(net: RapidNet) -> None:
    sc = sf.highway_scenario(0)
    a = roll_background(sc, RapidBackground(net, UNGUIDED), np.random.default_rng(3), CURRENT_STEP + 15)
    b = roll_background(sc, RapidBackground(net, UNGUIDED), np.random.default_rng(3), CURRENT_STEP + 15)
    c = roll_background(sc, RapidBackground(net, Guidance()), np.random.default_rng(3), CURRENT_STEP + 15)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_map_context_is_built_once_per_scenario(net: RapidNet) -> None:
    rapid = RapidBackground(net)
    first, second = sf.highway_scenario(0), sf.curve_scenario()
    env = ScenarioEnv([first, second], config={"background": "rapid"}, background_model=rapid)
    for _ in range(3):
        env.reset(seed=0, options={"scenario_id": first.scenario_id})
        for _ in range(3):
            env.step(np.zeros(2))
    assert rapid.map_builds == 1
    env.reset(seed=0, options={"scenario_id": second.scenario_id})
    env.reset(seed=0, options={"scenario_id": first.scenario_id})
    assert rapid.map_builds == 2


def test_social_force_pushes_back_from_the_car_ahead_and_map_force_away_from_the_edge() -> None:
    cur = np.zeros((3, 8))
    cur[:, 5], cur[:, 6], cur[:, VALID] = 5.0, 2.0, 1.0
    cur[1, X] = 7.0  # 2 m bumper gap ahead
    cur[2, X] = 60.0
    f = social_force(cur, np.array([0, 2]), Guidance())
    assert f[0, 0] < -1.0 and abs(f[0, 1]) < 1e-9
    assert np.abs(f[1]).max() < 1e-3
    road_sc = sf.highway_scenario(0)
    from seal.models.rapid.features import build_map_geometry

    geo = build_map_geometry(road_sc.road)
    k = int(np.argmax(geo.edges.len2))
    edge_pt = geo.edges.a[k] + 0.5 * geo.edges.e[k]  # the middle of the longest edge segment
    row = np.zeros((1, 8))
    q, _ = geo.centres.nearest(edge_pt[None])
    row[0, :2] = edge_pt + 0.3 * (q[0] - edge_pt) / np.linalg.norm(q[0] - edge_pt)
    row[0, 5], row[0, 6], row[0, VALID] = 5.0, 2.0, 1.0
    m = map_force(geo, row, np.array([0]), Guidance())
    assert float(m[0] @ (q[0] - edge_pt)) > 0  # toward the lane centre, away from the edge


def test_training_reduces_the_loss_and_the_model_file_round_trips(tmp_path: Path) -> None:
    scenarios = [sf.highway_scenario(i) for i in range(2)]
    samples = build_samples(scenarios, seed=0, stride=3)
    assert len(samples) > 500 and np.abs(samples.target).max() <= 3.0
    net, history = train_rapid(samples, samples, RapidTrainConfig(dim=16, epochs=3, batch_size=256, lr=3e-3))
    assert history["train_loss"][-1] < history["train_loss"][0]
    path = tmp_path / "model.pt"
    save_rapid(path, net, RapidTrainConfig(dim=16), {"note": "test"})
    loaded = load_rapid(path, {"w_social": 0.5}, ddim_steps=3)
    assert loaded.guidance.w_social == 0.5 and loaded.ddim_steps == 3
    for p, q in zip(net.parameters(), loaded.net.parameters(), strict=True):
        assert torch.equal(p, q)
    with pytest.raises(Exception, match="unknown option"):
        load_rapid(path, {"w_magic": 1.0})
    (tmp_path / "bad.pt").write_bytes(b"not a model")
    with pytest.raises(RapidFileError, match="bad.pt"):
        load_rapid(tmp_path / "bad.pt")


def test_closest_points_kernel_matches_the_numpy_projection() -> None:
    from seal.models.rapid.features import Segments

    rng = np.random.default_rng(4)
    lines = [np.cumsum(rng.normal(0, 5, (6, 2)), axis=0) for _ in range(4)]
    seg = Segments.of(lines)
    pts = rng.uniform(-20, 20, (50, 2))
    q, direction = seg.nearest(pts)
    d = pts[:, None, :] - seg.a[None]
    t = np.clip((d * seg.e[None]).sum(-1) / seg.len2[None], 0.0, 1.0)
    cand = seg.a[None] + t[..., None] * seg.e[None]
    k = np.argmin(((pts[:, None, :] - cand) ** 2).sum(-1), axis=1)
    np.testing.assert_allclose(q, cand[np.arange(50), k], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0)


def test_guidance_options_are_checked() -> None:
    from seal.core.errors import SealError

    with pytest.raises(SealError, match="w_social must be >= 0"):
        Guidance(w_social=-0.1)
    with pytest.raises(SealError, match="tau_s must be > 0"):
        Guidance(tau_s=0.0)


def test_headway_makes_the_social_force_see_a_fast_approach() -> None:
    cur = np.zeros((2, 8))
    cur[:, 5], cur[:, 6], cur[:, VALID] = 5.0, 2.0, 1.0
    cur[1, X] = 25.0  # 20 m gap ahead, stopped; agent 0 closes at 20 m/s
    cur[0, 3] = 20.0
    static = social_force(cur, np.array([0]), Guidance())
    headway = social_force(cur, np.array([0]), Guidance(t_headway_s=1.0))
    assert abs(static[0, 0]) < 1e-3 and headway[0, 0] == pytest.approx(-6.0)


def test_leader_term_moves_only_the_longitudinal_part_of_agents_with_a_leader() -> None:
    x0 = torch.tensor([[1.0, 0.5], [1.0, 0.5]])
    lead = torch.tensor([[-2.0, 1.0], [-2.0, 0.0]])  # agent 0 has a box ahead, agent 1 none
    out = guide(x0, {"leader": lead}, Guidance(w_destination=0.0, w_social=0.0, w_map=0.0, w_leader=0.25))
    torch.testing.assert_close(out, torch.tensor([[1.0 - 0.5 * 3.0, 0.5], [1.0, 0.5]]))
