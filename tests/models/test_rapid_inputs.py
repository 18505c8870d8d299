"""The compiled RAPID input building (`seal.models.rapid.input_kernels.own_inputs`, issue 22: per-agent cost)
against the numpy code it replaced (`kernel_reference.rapid_agent_inputs`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scenario_factory as sf
from kernel_reference import rapid_agent_inputs, rapid_neighbor_features

from seal.core import scenario as scn
from seal.models.rapid import features as F
from seal.models.rapid import input_kernels as IK
from seal.models.rapid.features import (
    OWN_DIM,
    Segments,
    agent_input_tables,
    agent_inputs,
    build_map_geometry,
    scan_pairs,
)


def test_constants_of_the_kernel_file_are_the_data_models() -> None:
    assert (IK._X, IK._Y, IK._H, IK._VX, IK._VY) == (scn.X, scn.Y, scn.HEADING, scn.VX, scn.VY)
    assert (IK._DT_S, IK._ACC_SCALE_MPS2) == (scn.DT_S, F.ACC_SCALE_MPS2)


def scene_on(road_xy: np.ndarray, seed: int, n: int = 30) -> np.ndarray:
    """``[n, 8]`` boxes scattered around the road points ``road_xy``, random headings / speeds, a few absent."""
    rng = np.random.default_rng(seed)
    cur = np.zeros((n, 8))
    cur[:, :2] = road_xy[rng.integers(len(road_xy), size=n)] + rng.normal(0, 4, (n, 2))
    cur[:, 2] = rng.uniform(-np.pi, np.pi, n)
    v = rng.uniform(0, 20, n)
    cur[:, 3], cur[:, 4] = v * np.cos(cur[:, 2]), v * np.sin(cur[:, 2])
    cur[:, 5], cur[:, 6] = rng.uniform(3.5, 6, n), rng.uniform(1.6, 2.2, n)
    cur[:, 7] = (rng.random(n) > 0.1).astype(float)
    return cur


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("edges", [True, False])
def test_compiled_inputs_equal_the_numpy_ones(seed: int, edges: bool) -> None:
    geo = build_map_geometry(sf.straight_road(3))
    if not edges:  # a road without edges: the stand-in edge point 50 m off
        geo = dataclasses.replace(geo, edges=Segments.of([]))
    cur = scene_on(np.concatenate([np.asarray(lane.centerline) for lane in sf.straight_road(3).lanes]), seed)
    rows = np.flatnonzero(cur[:, scn.VALID] > 0.5)
    rng = np.random.default_rng(seed + 7)
    n = rows.size
    prev_vel = cur[rows][:, [scn.VX, scn.VY]] + rng.normal(0, 0.3, (n, 2))
    prev_ok = rng.random(n) > 0.3
    desired = np.where(rng.random(n) > 0.4, rng.uniform(0, 25, n), np.nan)
    dest = np.where((rng.random(n) > 0.4)[:, None], cur[rows][:, :2] + rng.normal(0, 50, (n, 2)), np.nan)
    scan = scan_pairs(cur, rows)
    assert np.isfinite(scan.leader_gap).any() and not np.isfinite(scan.leader_gap).all()
    ref = rapid_agent_inputs(geo, cur, rows, prev_vel, prev_ok, desired, dest, scan.leader_gap, scan.leader_v)
    inp = agent_inputs(geo, cur, rows, prev_vel, prev_ok, desired, dest, scan)
    assert inp.own.shape == (n, OWN_DIM)
    for name, want in ref.items():
        got = getattr(inp, name)
        assert got.dtype == np.float32 and got.shape == want.shape, name
        # float64 in both, rounded to float32 once; libm and numpy's sin / cos may differ in the last bit
        np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-6, err_msg=name)
    ref_nb, ref_mask = rapid_neighbor_features(cur, rows, scan.neighbor_rows)
    np.testing.assert_allclose(inp.neighbors, ref_nb, rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(inp.neighbor_mask, ref_mask)
    tables = agent_input_tables(geo, cur, rows, prev_vel, prev_ok, desired, dest, scan)
    want_edge = geo.edges.nearest(cur[rows][:, :2])[0] if edges else cur[rows][:, :2] + 50.0
    np.testing.assert_array_equal(tables.edge_xy, want_edge)
