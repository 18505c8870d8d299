"""A skill space's reach (`seal.models.skills.reach`) on a hand-built skill model whose numbers are known."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from seal.models.skills.reach import box_candidates, first_accelerations, format_reach, skill_reach


class _IdentityPrior:
    """A prior whose flow is the identity (the skill is the noise) and whose state embedding is the state."""

    config = SimpleNamespace(latent_dim=2)

    def eval(self) -> None:
        pass

    def embed_state(self, cond: torch.Tensor) -> torch.Tensor:
        return cond

    def sample(self, noise: torch.Tensor, cond: torch.Tensor | None = None,
               embedded: torch.Tensor | None = None) -> torch.Tensor:
        assert embedded is not None and embedded.shape[0] == noise.shape[0]
        return noise


class _AccelDecoder:
    """Acceleration ``tanh(z_0 + state_0)``, steering 0."""

    def eval(self) -> None:
        pass

    def decode(self, obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return torch.stack([torch.zeros(len(z)), torch.tanh(z[:, 0] + obs[:, 0])], dim=-1)


def test_box_candidates_are_the_corners_the_centre_and_draws() -> None:
    c = box_candidates(2, 3, np.random.default_rng(0))
    assert c.dtype == np.float32 and c.shape == (4 + 1 + 3, 2)
    assert {tuple(x) for x in c[:4]} == {(-1, -1), (-1, 1), (1, -1), (1, 1)} and not c[4].any()
    assert np.abs(c[5:]).max() < 1
    assert box_candidates(7, 2, np.random.default_rng(0)).shape == (32 + 1 + 2, 7)  # corners drawn above dim 5


def test_reach_is_the_hardest_braking_and_throttle_per_state() -> None:
    states = np.array([[0.0, 5.0], [0.5, 5.0], [-0.5, 5.0]], dtype=np.float32)
    candidates = np.array([[1.0, 0.0], [-1.0, 1.0], [0.2, -1.0]], dtype=np.float32)
    accel = first_accelerations(_AccelDecoder(), _IdentityPrior(), states, candidates, 2.0)  # type: ignore[arg-type]
    expected = np.tanh(2.0 * candidates[:, 0][None, :] + states[:, :1])
    assert np.allclose(accel, expected, atol=1e-6)

    reach = skill_reach(_AccelDecoder(), _IdentityPrior(), states, np.linspace(-1, 1, 3),  # type: ignore[arg-type]
                        noise_bounds=(0.5, 2.0), n_random=4)
    # the corners u_0 = -1 / +1 are the extremes: tanh(-b + s), tanh(b + s) for the states' s in (-0.5, 0, 0.5)
    for b in (0.5, 2.0):
        cell = reach[f"noise_bound_{b:g}"]
        assert cell["hardest_braking"]["p50"] == pytest.approx(np.tanh(-b), abs=1e-4)
        assert cell["strongest_throttle"]["p50"] == pytest.approx(np.tanh(b), abs=1e-4)
        lo = np.percentile(np.tanh(-b + np.array([-0.5, 0.0, 0.5])), 10)
        assert cell["hardest_braking"]["p10"] == pytest.approx(lo, abs=1e-4)
    assert reach["states"] == 3 and reach["candidates"] == 4 + 1 + 4
    assert reach["logged_accel"] == {"p5": -0.9, "p50": 0.0, "p95": 0.9}
    line = format_reach("benign", reach)
    assert "noise bound 0.5: [-0.46, +0.46]; noise bound 2: [-0.96, +0.96]" in line and "[-0.90, +0.90]" in line
