"""The RAPID step's compiled parts and fast paths against their references (issue 22: per-agent cost), and the
safety guidance term."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf
import torch
from kernel_reference import rapid_neighbor_features, rapid_neighbors, rapid_social_force

from seal.core import scenario as scn
from seal.core.geometry import pairwise_overlaps
from seal.core.scenario import CURRENT_STEP, VALID
from seal.envs.background import roll_background
from seal.envs.car_following import (
    leader_gaps,
    obstacle_gaps,
    route_distances,
    safe_acceleration,
    safety_obstacles,
)
from seal.models.rapid import Guidance, RapidBackground
from seal.models.rapid import input_kernels as IK
from seal.models.rapid import kernels as K
from seal.models.rapid.fast import FastAgentEncoder, FastDenoiser
from seal.models.rapid.features import N_NEIGHBORS, NEIGHBOR_DIM, NEIGHBOR_RANGE_M, OWN_DIM, scan_pairs
from seal.models.rapid.network import RapidNet
from seal.models.rapid.sampler import NO_BOUND, guide, safety_bound

UNGUIDED = Guidance(w_destination=0.0, w_social=0.0, w_map=0.0, w_safety=0.0)


def random_scene(seed: int, n: int = 40) -> np.ndarray:
    """``[n, 8]`` boxes in a 120 m square, random headings and speeds, a few absent."""
    rng = np.random.default_rng(seed)
    cur = np.zeros((n, 8))
    cur[:, :2] = rng.uniform(-60, 60, (n, 2))
    cur[:, 2] = rng.uniform(-np.pi, np.pi, n)
    v = rng.uniform(0, 20, n)
    cur[:, 3], cur[:, 4] = v * np.cos(cur[:, 2]), v * np.sin(cur[:, 2])
    cur[:, 5], cur[:, 6] = rng.uniform(3.5, 6, n), rng.uniform(1.6, 2.2, n)
    cur[:, 7] = (rng.random(n) > 0.1).astype(float)
    return cur


def test_track_columns_of_the_kernel_file_are_the_data_models() -> None:
    assert (K._X, K._Y, K._H, K._VX, K._VY, K._L, K._W, K._VALID) == (
        scn.X, scn.Y, scn.HEADING, scn.VX, scn.VY, scn.LENGTH, scn.WIDTH, scn.VALID)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_pair_scan_matches_the_numpy_terms(seed: int) -> None:
    cur = random_scene(seed)
    logged = cur.copy()
    logged[:, :2] += np.random.default_rng(seed + 10).normal(0, 3, (len(cur), 2))
    rows = np.flatnonzero(cur[:, VALID] > 0.5)[::2]
    social = (6.0, 2.0, 0.5, 0.1)
    for log in (None, logged):
        scan = scan_pairs(cur, rows, log, social)
        gap, lv = leader_gaps(cur, rows)
        np.testing.assert_allclose(scan.leader_gap, gap, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(scan.leader_v, lv, rtol=1e-12, atol=1e-9)
        ogap, ov = obstacle_gaps(cur, rows, log)
        np.testing.assert_allclose(scan.obstacle_gap, ogap, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(scan.obstacle_v, ov, rtol=1e-12, atol=1e-9)
    assert np.isfinite(scan.obstacle_gap).sum() > 3  # the scene has obstacles to compare
    np.testing.assert_allclose(scan.social, rapid_social_force(cur, rows, *social), rtol=1e-9, atol=1e-12)
    idx, dist = rapid_neighbors(cur, rows, N_NEIGHBORS, NEIGHBOR_RANGE_M)
    np.testing.assert_array_equal(scan.neighbor_rows, idx)
    np.testing.assert_allclose(scan.neighbor_dist, dist, rtol=1e-12)
    nb_rows = scan.neighbor_rows.copy()
    nb_rows[::3, -3:] = -1  # some agents with fewer than N_NEIGHBORS neighbours
    feats, mask = K.neighbor_features(cur, rows.astype(np.int64), nb_rows)
    ref_feats, ref_mask = rapid_neighbor_features(cur, rows, nb_rows)
    assert 0 < mask.sum() < mask.size
    np.testing.assert_array_equal(mask, ref_mask)
    np.testing.assert_allclose(feats, ref_feats, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("seed", [0, 1])
def test_pair_scan_with_routes_matches_the_numpy_safety_obstacles(seed: int) -> None:
    rng = np.random.default_rng(seed)
    cur = random_scene(seed, 60)
    cur[:, :2] *= 0.5  # denser: more boxes in each other's paths
    t, n_steps = 5, 30
    route = np.zeros((len(cur), n_steps, 8))  # wandering logged tracks through each agent's position at t
    heading = np.stack([np.cos(cur[:, 2]), np.sin(cur[:, 2])], 1)
    steps = rng.normal(0, 1.5, (len(cur), n_steps, 2)) + 6.0 * heading[:, None]
    route[:, :, :2] = cur[:, None, :2] + np.cumsum(steps, axis=1) - steps[:, t:t + 1].cumsum(axis=1)
    route[:, :, 7] = (rng.random((len(cur), n_steps)) > 0.2).astype(float)
    logged = cur.copy()
    logged[:, :2] += rng.normal(0, 3, (len(cur), 2))
    rows = np.flatnonzero(cur[:, VALID] > 0.5)[1:]
    for log in (None, logged):
        scan = scan_pairs(cur, rows, log, route=route, t=t)
        gap, lv = safety_obstacles(cur, rows, log, route_distances(cur, rows, route, t))
        np.testing.assert_allclose(scan.obstacle_gap, gap, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(scan.obstacle_v, lv, rtol=1e-12, atol=1e-9)
        plain, _ = obstacle_gaps(cur, rows, log)
        assert (np.isfinite(plain) & ~np.isfinite(gap)).sum() > 0  # the route / priority rules drop some


def test_segment_grid_gives_the_brute_force_closest_points() -> None:
    rng = np.random.default_rng(5)
    pts_line = np.cumsum(rng.normal(0, 3, (300, 2)), axis=0)
    a, e = pts_line[:-1], np.diff(pts_line, axis=0)
    cols = np.ascontiguousarray(np.vstack([a.T, e.T]))
    len2 = np.ascontiguousarray((e**2).sum(axis=1))
    pts = np.ascontiguousarray(np.vstack([rng.uniform(-150, 150, (300, 2)), pts_line]))  # vertices: ties
    q1, k1 = K.closest_points(cols, len2, pts)
    for cell in (2.0, 10.0, 80.0):
        q2, k2 = IK.closest_points_grid(cols, len2, pts, *IK.segment_grid(cols, cell), cell)
        np.testing.assert_array_equal(k1, k2)
        np.testing.assert_array_equal(q1, q2)


def test_cached_read_out_and_the_denoisers_context_term_match_the_modules() -> None:
    torch.manual_seed(0)
    net = RapidNet(16).eval()
    z = torch.randn(1, 16, 16)
    h = torch.randn(7, 16)
    with torch.no_grad():
        ref, _ = net.agent.attn(h[:, None], z.expand(7, -1, -1), z.expand(7, -1, -1), need_weights=False)
        fast = net.agent._read(h, net.agent.latent_kv(z))
        torch.testing.assert_close(fast, ref[:, 0], rtol=1e-5, atol=1e-6)
        x, ctx = torch.randn(7, 2), torch.randn(7, 16)
        for k in (0, 12, 49):
            torch.testing.assert_close(net.denoiser.forward_from(x, k, net.denoiser.context_part(ctx)),
                                       net.denoiser(x, torch.full((7,), k), ctx), rtol=1e-5, atol=1e-6)


def test_fast_inference_path_matches_the_modules() -> None:
    torch.manual_seed(1)
    net = RapidNet(16).eval()
    with torch.no_grad():  # trained-looking weights: the missing embeddings are not zero
        for p in net.agent.missing.values():
            p.normal_()
    rng = np.random.default_rng(3)
    n = 9
    inp = {"own": rng.normal(size=(n, OWN_DIM)), "prev_acc": rng.normal(size=(n, 2)), "speed_cmd": rng.normal(
        size=(n, 1)), "dest": rng.normal(size=(n, 3)), "leader": rng.normal(size=(n, 2)),
        "neighbors": rng.normal(size=(n, N_NEIGHBORS, NEIGHBOR_DIM))}
    for name in ("prev", "speed", "dest", "leader"):
        inp[f"{name}_mask"] = (rng.random(n) > 0.4).astype(float)
    inp["neighbor_mask"] = (rng.random((n, N_NEIGHBORS)) > 0.5).astype(float)
    inp["neighbor_mask"][0] = 0.0  # an agent with no neighbour: the missing embedding
    for field, mask in (("prev_acc", "prev_mask"), ("speed_cmd", "speed_mask"), ("dest", "dest_mask"),
                        ("leader", "leader_mask")):
        inp[field] *= inp[mask][:, None]  # `agent_inputs` zeroes absent inputs
    t = {k: torch.from_numpy(v.astype(np.float32)) for k, v in inp.items()}
    z = torch.randn(1, 16, 16)
    kv = net.agent.latent_kv(z)
    with torch.no_grad():
        ref = net.agent(t, z.expand(n, -1, -1))
        torch.testing.assert_close(FastAgentEncoder(net.agent)(t, kv), ref, rtol=1e-5, atol=1e-5)
        fast = FastDenoiser(net.denoiser)
        x = torch.randn(n, 2)
        for k in (0, 12, 49, 12):  # 12 twice: the cached step term
            torch.testing.assert_close(fast.forward_from(x, k, fast.context_part(ref)),
                                       net.denoiser(x, torch.full((n,), k), ref), rtol=1e-5, atol=1e-5)


def test_safety_term_caps_the_longitudinal_acceleration_only_above_the_bound() -> None:
    x0 = torch.tensor([[1.0, 0.3], [-2.0, 0.1], [0.5, -0.2]])
    bound = torch.tensor([[0.0], [0.0], [NO_BOUND]])
    out = guide(x0, {"safety": bound}, Guidance(w_safety=0.5))
    torch.testing.assert_close(out, torch.tensor([[0.0, 0.3], [-2.0, 0.1], [0.5, -0.2]]))  # projection
    half = guide(x0, {"safety": bound}, Guidance(w_safety=0.25))
    assert float(half[0, 0]) == pytest.approx(0.5)  # x0 - 2 w (x0 - bound): half way
    assert torch.equal(guide(x0, {"safety": bound}, UNGUIDED), x0)


def test_safety_bound_is_the_gipps_acceleration_in_model_units() -> None:
    cur = np.zeros((2, 8))
    cur[:, 5], cur[:, 6], cur[:, VALID] = 5.0, 2.0, 1.0
    cur[0, 3] = 15.0
    cur[1, 0] = 45.0  # stopped 40 m ahead (bumper)
    gap, lv = obstacle_gaps(cur, np.array([0]))
    b = safety_bound(cur, np.array([0]), gap, lv)
    want = max(safe_acceleration(np.array([15.0]), np.array([40.0]), np.zeros(1))[0], -8.0) / 3.0
    assert b[0, 0] == pytest.approx(want)
    alone = cur[:1]
    g2, v2 = obstacle_gaps(alone, np.array([0]))
    assert safety_bound(alone, np.array([0]), g2, v2)[0, 0] == NO_BOUND


def follower_scenario() -> sf.Scenario:
    """Ego braking hard to a stop in lane 0 at 20 m/s, a background car 25 m behind it at 20 m/s."""
    road = sf.straight_road(2)
    lane0, lane1 = road.lanes[0].centerline, road.lanes[1].centerline
    ego = sf.simulate_track(lane0, 100.0, 20.0, accel_fn=lambda t: -5.0 if t > 1.5 else 0.0)
    adv = sf.simulate_track(lane1, 100.0, 20.0)
    follower = sf.simulate_track(lane0, 70.0, 20.0)
    return sf.make_scenario(road, [ego, adv, follower], "follower")


class KeepSpeed(torch.nn.Module):
    """A denoiser that predicts zero acceleration (a model that ignores the ego, deterministically)."""

    def forward(self, x: torch.Tensor, k: torch.Tensor, ctx: torch.Tensor) -> torch.Tensor:
        return torch.zeros_like(x)


def test_safety_guidance_keeps_a_rapid_follower_that_ignores_the_ego_off_it() -> None:
    torch.manual_seed(0)
    net = RapidNet(16).eval()
    net.denoiser = KeepSpeed()  # type: ignore[assignment]
    sc = follower_scenario()

    def hits(guidance: Guidance) -> bool:
        out = roll_background(sc, RapidBackground(net, guidance), np.random.default_rng(0))
        return any(pairwise_overlaps(out[[0, 2], t])[0, 1] for t in range(CURRENT_STEP, out.shape[1]))

    assert hits(UNGUIDED)
    assert not hits(Guidance(w_destination=0.0, w_social=0.0, w_map=0.0))  # safety term alone
