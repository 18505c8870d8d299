"""Hidden states at each encoder site of the prior, steered decoding, the steering file and `SteeredPrior`.

The "known direction" of the real decoder: the finite-difference gradient of the predicted mean speed with
respect to the target's output latent. Steering along it moves the predicted speed monotonically; a random
direction of the same norm moves it far less."""

from __future__ import annotations

import numpy as np
import pytest
import scenario_factory as sf
import torch

from seal.experiments.steering.collect import find_targets, target_state
from seal.experiments.steering.sweeps import Decoder, risk_sweep, speed_sweep
from seal.models.prior.prior import TrajectoryPrior
from seal.models.steering.bundle import SteeringBundle, SteeringFileError, SteeringVector
from seal.models.steering.labels import RiskConfig, mean_speed
from seal.models.steering.latents import OUTPUT, SteeringSession, hidden_states, prepare, site_names
from seal.models.steering.linear import random_direction
from seal.models.steering.steer import SteeredPrior, resolve_vector


@pytest.fixture(scope="module")
def prior() -> TrajectoryPrior:
    torch.set_num_threads(1)
    return TrajectoryPrior.untrained(seed=0)


@pytest.fixture(scope="module")
def scenes() -> list:
    return [sf.highway_scenario(i) for i in range(3)]


def test_unsteered_decoding_from_every_site_is_the_prior(prior: TrajectoryPrior, scenes: list) -> None:
    agents = [s.adv_index for s in scenes]
    xy0, p0 = prior.decode(prior.encode(scenes, agents))
    batch = prepare(prior, scenes, agents)
    assert site_names(prior) == ("input", "layer1", "layer2", "output")
    for site in site_names(prior):
        xy, p = SteeringSession(prior, batch, site).decode()
        np.testing.assert_allclose(xy, xy0, atol=1e-6)
        np.testing.assert_allclose(p, p0, atol=1e-9)
    states = hidden_states(prior, batch)
    np.testing.assert_allclose(states[OUTPUT], prior.encode(scenes, agents).target_latent.double().numpy(), atol=1e-6)
    assert {k: v.shape for k, v in states.items()} == {s: (3, 64) for s in site_names(prior)}


def test_offset_at_the_output_site_is_encodings_target_offset(prior: TrajectoryPrior, scenes: list) -> None:
    offset = np.linspace(-1.0, 1.0, 64)
    enc = prior.encode(scenes)
    xy0, _ = prior.decode(enc.with_target_offset(torch.as_tensor(offset, dtype=torch.float32)))
    xy, _ = SteeringSession(prior, prepare(prior, scenes, [s.adv_index for s in scenes]), OUTPUT).decode(offset)
    np.testing.assert_allclose(xy, xy0, atol=1e-5)
    early, _ = SteeringSession(prior, prepare(prior, scenes, [s.adv_index for s in scenes]), "layer1").decode(offset)
    assert np.abs(early - xy0).max() > 1e-3  # another site, another effect


def test_steering_along_the_speed_gradient_moves_speed_and_random_does_not(prior: TrajectoryPrior,
                                                                            scenes: list) -> None:
    targets = find_targets(scenes)
    dec = Decoder(prior, scenes, targets, OUTPUT)
    starts = np.stack([target_state(scenes[t.scene], t.agent).start_xy for t in targets])

    def speed(offset: np.ndarray) -> float:
        xy, probs = dec.decode(offset)
        return float((probs * mean_speed(xy, starts[:, None])).sum(1).mean())

    eye = np.eye(64)
    grad = np.array([speed(0.5 * eye[i]) - speed(-0.5 * eye[i]) for i in range(64)])
    known = SteeringVector("known@output", OUTPUT, grad / np.linalg.norm(grad), 4.0, "control")
    rand = SteeringVector("rand@output", OUTPUT, random_direction(64, np.random.default_rng(0)), 4.0, "control")
    taus = [-100.0, -50.0, 0.0, 50.0, 100.0]
    change = {v.name: (lambda s: (s / s[2] - 1).mean(1))(speed_sweep(dec, v, taus)) for v in (known, rand)}
    assert np.all(np.diff(change["known@output"]) > 0)
    assert change["known@output"][-1] - change["known@output"][0] > 0.05
    assert np.abs(change["rand@output"]).max() < 0.5 * (change["known@output"][-1] - change["known@output"][0])


def test_risk_sweep_measures_projected_candidates_and_keeps_the_decoders_share(prior: TrajectoryPrior) -> None:
    scenes = [sf.curve_scenario(), sf.highway_scenario(0)]
    targets = find_targets(scenes)
    vec = SteeringVector("risk_activity@output", OUTPUT, random_direction(64, np.random.default_rng(1)), 1.0, "risk")
    risk = RiskConfig()
    plain = risk_sweep(Decoder(prior, scenes, targets, OUTPUT), vec, [0.0, 2.0], risk)
    projected = risk_sweep(Decoder(prior, scenes, targets, OUTPUT, project_road=True), vec, [0.0, 2.0], risk)
    # The decoder's own share is the unprojected sweep's; the projected candidates are more often on the road.
    np.testing.assert_array_equal(projected.plausible_raw, plain.plausible)
    np.testing.assert_array_equal(plain.plausible_raw, plain.plausible)
    assert projected.plausible.mean() > plain.plausible.mean() + 0.05


def _bundle(d: int = 64) -> SteeringBundle:
    v = np.zeros(d)
    v[0] = 1.0
    return SteeringBundle({"risk_proximity@layer1": SteeringVector("risk_proximity@layer1", "layer1", v, 2.0, "risk"),
                           "speed@output": SteeringVector("speed@output", OUTPUT, v, 3.0, "control")},
                          {"best_site": {"proximity": "layer1", "activity": "output"}})


def test_bundle_round_trip_and_errors(tmp_path) -> None:
    _bundle().save(tmp_path / "steering.pt")
    back = SteeringBundle.load(tmp_path)  # the folder finds steering.pt
    assert set(back.vectors) == {"risk_proximity@layer1", "speed@output"}
    v = back.get("speed@output")
    np.testing.assert_allclose(v.offset(0.5), 1.5 * np.eye(64)[0])
    assert resolve_vector(back, "risk_proximity").name == "risk_proximity@layer1"
    with pytest.raises(SteeringFileError, match="no steering vector 'nope'"):
        back.get("nope")
    torch.save({"format": "other"}, tmp_path / "bad.pt")
    with pytest.raises(SteeringFileError, match="not written by seal fit probes"):
        SteeringBundle.load(tmp_path / "bad.pt")
    with pytest.raises(FileNotFoundError, match="seal fit probes"):
        SteeringBundle.load(tmp_path / "missing.pt")


def test_steered_prior_at_zero_is_the_prior_and_checks_dimensions(prior: TrajectoryPrior, scenes: list) -> None:
    s = scenes[0]
    plain = prior.predict([s])[0]
    same = SteeredPrior(prior, _bundle(), "risk_proximity", 0.0, project_road=False).predict(s, s.adv_index)
    np.testing.assert_allclose(same.xy, plain.xy, atol=1e-6)
    moved = SteeredPrior(prior, _bundle(), "risk_proximity", 3.0, project_road=False).predict(s, s.adv_index)
    assert moved.fallback is None and np.abs(moved.xy - plain.xy).max() > 1e-3
    with pytest.raises(SteeringFileError, match="another prior"):
        SteeredPrior(prior, _bundle(d=8), "speed@output", 1.0)
