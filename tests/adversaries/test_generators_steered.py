"""The ``steered`` generator (CAT over candidates decoded from a steered latent) and the ``steer`` option of CAT /
SEAL's candidate source."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scenario_factory as sf

from seal.adversaries.base import make_generator
from seal.adversaries.history import RolloutHistory
from seal.core.scenario import CURRENT_STEP, N_FUTURE
from seal.models.prior import TrajectoryPrior
from seal.models.steering.bundle import SteeringBundle, SteeringFileError, SteeringVector


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("steered")
    TrajectoryPrior.untrained(seed=0).save(root / "prior.pt")
    v = np.random.default_rng(0).standard_normal(64)
    vec = SteeringVector("risk_proximity@layer1", "layer1", v / np.linalg.norm(v), 2.0, "risk")
    SteeringBundle({vec.name: vec}, {"best_site": {"proximity": "layer1"}}).save(root / "steering.pt")
    return root / "prior.pt", root


def _generate(gen, scenario):
    return gen.generate(scenario, RolloutHistory().queue(scenario), np.random.default_rng(0))


def test_steered_at_alpha_zero_is_cat_and_steering_changes_the_candidates(files: tuple[Path, Path]) -> None:
    prior, steer = files
    scenario = sf.highway_scenario(1)
    # The steered generator projects its candidates on the road by default: CAT with the same projection.
    cat = _generate(make_generator("cat", prior=str(prior), project_road=True), scenario)
    same = _generate(make_generator("steered", prior=str(prior), steer=str(steer), steer_alpha=0.0,
                                    steer_vector="risk_proximity"), scenario)
    assert same.chosen_candidate == cat.chosen_candidate and same.extra["score"] == pytest.approx(cat.extra["score"])
    gen = make_generator("steered", prior=str(prior), steer=str(steer), steer_alpha=4.0, steer_vector="risk_proximity")
    out = _generate(gen, scenario)
    assert out.extra["n_candidates"] == 32 and out.extra["candidate_fallback"] == ""
    assert CURRENT_STEP < out.predicted_step <= CURRENT_STEP + N_FUTURE
    steered = gen.candidate_source(scenario)
    plain = make_generator("cat", prior=str(prior)).candidate_source(scenario)
    assert np.abs(steered.xy - plain.xy).max() > 0.01
    # CAT with the same steer option reads the same steered candidates.
    cat_steered = make_generator("cat", prior=str(prior), steer=str(steer), steer_alpha=4.0,
                                 steer_vector="risk_proximity")
    np.testing.assert_allclose(cat_steered.candidate_source(scenario).xy, steered.xy)


def test_steer_needs_a_prior_and_steered_needs_steer(files: tuple[Path, Path]) -> None:
    prior, steer = files
    with pytest.raises(ValueError, match="option 'steer' is required"):
        make_generator("steered", prior=str(prior))
    with pytest.raises(ValueError, match="give a prior file too"):
        make_generator("cat", candidates="lanes", steer=str(steer))
    with pytest.raises(FileNotFoundError, match="steering file"):
        make_generator("steered", prior=str(prior), steer=str(steer / "nope.pt"))
    with pytest.raises(SteeringFileError, match="no steering vector 'speed@output'"):
        make_generator("steered", prior=str(prior), steer=str(steer), steer_vector="speed")
    with pytest.raises(SteeringFileError, match="no steering vector 'lane_change@output'"):
        make_generator("steered", prior=str(prior), steer=str(steer))  # the default grid's vectors are missing


def test_seal_accepts_the_steer_option(files: tuple[Path, Path]) -> None:
    prior, steer = files
    gen = make_generator("seal", prior=str(prior), objective="cat", switch="none", steer=str(steer), steer_alpha=4.0,
                         steer_vector="risk_proximity")
    out = _generate(gen, sf.highway_scenario(2))
    assert out.extra["n_candidates"] == 32 and out.extra["objective"] == "cat"


def test_a_grid_of_vectors_and_alphas_keeps_every_decode(files: tuple[Path, Path], tmp_path: Path) -> None:
    prior, _ = files
    rng = np.random.default_rng(1)
    vecs = {}
    for name in ("lane_change@output", "acceleration@output"):
        d = rng.standard_normal(64)
        vecs[name] = SteeringVector(name, "output", d / np.linalg.norm(d), 2.0, "control")
    SteeringBundle(vecs).save(tmp_path / "steering.pt")
    scenario = sf.highway_scenario(1)
    grid = make_generator("steered", prior=str(prior), steer=str(tmp_path))  # the default: this grid
    cands = grid.candidate_source(scenario)
    assert cands.n_candidates == 9 * 32 and cands.probs.sum() == pytest.approx(1.0)
    plain = make_generator("cat", prior=str(prior), project_road=True).candidate_source(scenario)
    # The (0, 0) decode is the prior's own: each of its candidates is in the grid with a ninth of its probability.
    for k in range(32):
        d = np.abs(cands.xy - plain.xy[k]).max(axis=(1, 2))
        j = int(np.argmin(d))
        assert d[j] < 1e-4 and cands.probs[j] == pytest.approx(plain.probs[k] / 9, rel=1e-4)  # float32, batched
    assert _generate(grid, scenario).extra["n_candidates"] == 288
    # The baseline: random directions of the same norms; (0, 0) is still the prior's decode, the rest differ.
    rand = make_generator("steered", prior=str(prior), steer=str(tmp_path), steer_random_seed=3).candidate_source(
        scenario)
    assert rand.n_candidates == 288 and np.abs(np.sort(rand.xy, axis=0) - np.sort(cands.xy, axis=0)).max() > 0.01
    assert min(np.abs(rand.xy - plain.xy[0]).max(axis=(1, 2))) < 1e-4
    with pytest.raises(ValueError, match="steer_alpha"):
        make_generator("steered", prior=str(prior), steer=str(tmp_path), steer_vector="lane_change@output",
                       steer_alpha="fast")


def test_project_road_option(files: tuple[Path, Path]) -> None:
    prior, steer = files
    scenario = sf.curve_scenario()  # the untrained prior's candidates leave this curved road
    raw = make_generator("cat", prior=str(prior)).candidate_source(scenario)  # CAT's default: the decoder's own
    projected = make_generator("cat", prior=str(prior), project_road=True).candidate_source(scenario)
    unprojected = make_generator("steered", prior=str(prior), steer=str(steer), steer_alpha=0.0,
                                 steer_vector="risk_proximity", project_road=False).candidate_source(scenario)
    steered = make_generator("steered", prior=str(prior), steer=str(steer), steer_alpha=0.0,
                             steer_vector="risk_proximity").candidate_source(scenario)
    np.testing.assert_allclose(unprojected.xy, raw.xy, atol=1e-6)
    np.testing.assert_allclose(steered.xy, projected.xy, atol=1e-6)
    changed = np.abs(projected.xy - raw.xy).max(axis=(1, 2)) > 1e-6
    assert 0 < changed.sum() < 32  # some candidates re-driven, the ones on the road kept
    np.testing.assert_allclose(projected.speed, raw.speed, atol=1e-6)  # re-driven with their own speeds
    with pytest.raises(ValueError, match="option 'project_road'.*give a prior file"):
        make_generator("cat", candidates="lanes", project_road=True)
