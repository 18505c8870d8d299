"""Skill VAE, conditional RealNVP prior, numpy fast paths, skill policy and model files."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from seal.models.skills.fast import FastDecoder, FastPriorSampler
from seal.models.skills.io import SkillModelError, load_model, load_skill_models, prior_file, save_model
from seal.models.skills.policy import SkillPolicy
from seal.models.skills.realnvp import ConditionalRealNVP, RealNVPConfig
from seal.models.skills.train import SkillTrainConfig, train_prior
from seal.models.skills.vae import SkillVAE, VAEConfig

TINY_VAE = VAEConfig(obs_dim=6, horizon=5, latent_dim=4, encoder_hidden=32, decoder_hidden=(32, 32),
                     decoder_ignore=(), beta=1e-3)
TINY_PRIOR = RealNVPConfig(latent_dim=4, cond_dim=6, hidden=32, cond_embed=16)


@pytest.fixture(autouse=True, scope="module")
def _one_thread():
    """Tiny tensors: extra threads only add synchronisation cost (a lot of it on a busy shared machine)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _randomise(model: torch.nn.Module, seed: int, std: float = 0.3) -> None:
    """Non-trivial weights everywhere (the couplings start as the identity)."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.copy_(torch.randn(p.shape, generator=gen) * std)


def test_vae_shapes_and_action_range() -> None:
    torch.manual_seed(0)
    vae = SkillVAE(VAEConfig())
    obs, act = torch.randn(7, 10, 100), torch.rand(7, 10, 2) * 2 - 1
    mu, logvar = vae.encode(obs, act)
    assert mu.shape == logvar.shape == (7, 8)
    recon, mu2, _ = vae(obs, act, sample=False)
    assert recon.shape == (7, 10, 2) and torch.equal(mu, mu2)
    assert recon.abs().max() <= 1.0
    # One latent per window, broadcast over the steps: same as decoding step by step.
    step = torch.stack([vae.decode(obs[:, t], mu) for t in range(10)], dim=1)
    assert torch.allclose(step, recon, atol=1e-6)
    assert vae.kl(torch.zeros(3, 8), torch.zeros(3, 8)).abs().max() == 0.0


def test_decoder_sees_the_previous_action_unless_told_to_ignore_it() -> None:
    torch.manual_seed(0)
    obs, z = torch.randn(4, 100), torch.randn(4, 8)
    changed = obs.clone()
    changed[:, 32:35] += 5.0  # steering and last action
    sees = SkillVAE(VAEConfig())
    assert not torch.allclose(sees.decode(obs, z), sees.decode(changed, z))
    vae = SkillVAE(VAEConfig(decoder_ignore=(32, 33, 34)))
    assert torch.equal(vae.decode(obs, z), vae.decode(changed, z))
    changed[:, 31] += 1.0  # speed is seen
    assert not torch.allclose(vae.decode(obs, z), vae.decode(changed, z))


def test_closed_loop_training_feeds_the_decoder_its_own_previous_action() -> None:
    torch.manual_seed(0)
    vae = SkillVAE(VAEConfig(closed_loop_training=True))
    _randomise(vae, 3, std=0.1)
    obs, act = torch.randn(3, 10, 100), torch.rand(3, 10, 2) * 2 - 1
    mu, _ = vae.encode(obs, act)
    recon = vae.decode_closed_loop(obs, mu)
    assert torch.equal(recon[:, 0], vae.decode(obs[:, 0], mu))  # the first step sees the logged previous action
    for t in (1, 5, 9):
        own = obs[:, t].clone()
        own[:, 32], own[:, 33], own[:, 34] = recon[:, t - 1, 0], recon[:, t - 1, 0], recon[:, t - 1, 1]
        assert torch.allclose(recon[:, t], vae.decode(own, mu), atol=1e-6)
    assert not torch.allclose(recon, vae.decode(obs, mu))  # teacher forcing differs
    out, mu2, _ = vae(obs, act, sample=False)  # forward (the training loss) decodes closed-loop
    assert torch.equal(out, recon) and torch.equal(mu2, mu)
    loss, _ = vae.loss(obs, act)
    loss.backward()  # through the fed-back actions as well
    assert all(p.grad is not None for p in vae.decoder.parameters())
    assert VAEConfig.from_dict({"closed_loop_training": True}).closed_loop_training


def test_tiny_vae_reconstructs_a_handful_of_windows() -> None:
    # 12 windows: the action is a per-window constant the observation does not reveal, so only the latent can
    # carry it; a working VAE must bring the error far below predicting the mean.
    rng = np.random.default_rng(0)
    torch.manual_seed(0)
    obs = torch.as_tensor(rng.normal(size=(12, 5, 6)), dtype=torch.float32)
    levels = torch.as_tensor(rng.uniform(-0.8, 0.8, size=(12, 1, 2)), dtype=torch.float32)
    act = levels.expand(12, 5, 2).contiguous()
    vae = SkillVAE(TINY_VAE)
    vae.fit_norm(obs.reshape(-1, 6).numpy(), act.reshape(-1, 2).numpy())
    opt = torch.optim.Adam(vae.parameters(), lr=3e-3)
    losses = []
    for _ in range(400):
        loss, _ = vae.loss(obs, act)
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    with torch.no_grad():
        recon, _, _ = vae(obs, act, sample=False)
        err = vae.recon_error(recon, act).mean().item()
    assert np.mean(losses[:10]) > 1.5  # ~2 = predicting the mean in std units
    assert err < 0.1 * np.mean(losses[:10])
    assert losses[-1] < 0.2 * losses[0]


def test_realnvp_inverse_is_exact() -> None:
    prior = ConditionalRealNVP(TINY_PRIOR)
    _randomise(prior, 1, std=0.15)
    prior.fit_norm(np.random.default_rng(0).normal(2.0, 3.0, (50, 4)), np.random.default_rng(1).normal(size=(50, 6)))
    gen = torch.Generator().manual_seed(0)  # seeded inputs: the test does not depend on the run order
    z, cond = torch.randn(20, 4, generator=gen) * 2, torch.randn(20, 6, generator=gen)
    with torch.no_grad():
        u, _ = prior.to_noise(z, cond)
        assert u.abs().max() > 3.0  # a non-trivial map
        assert torch.allclose(prior.sample(u, cond), z, atol=1e-4)
        noise = torch.randn(20, 4, generator=gen)
        z2 = prior.sample(noise, cond)
        assert torch.allclose(prior.to_noise(z2, cond)[0], noise, atol=1e-4)


def test_realnvp_log_det_matches_autograd_jacobian() -> None:
    prior = ConditionalRealNVP(TINY_PRIOR).double()
    _randomise(prior, 2)
    with torch.no_grad():
        prior.z_std.copy_(torch.tensor([0.5, 2.0, 1.5, 0.8], dtype=torch.float64))
    cond = torch.randn(1, 6, dtype=torch.float64)
    for seed in range(3):
        z = torch.randn(1, 4, dtype=torch.float64, generator=torch.Generator().manual_seed(seed))
        jac = torch.autograd.functional.jacobian(lambda x: prior.to_noise(x, cond)[0][0], z)[:, 0, :]
        _, logdet = prior.to_noise(z, cond)
        sign, expected = torch.linalg.slogdet(jac)
        assert sign > 0
        assert math.isclose(logdet[0].item(), expected.item(), abs_tol=1e-9)


def test_identity_prior_log_prob_is_the_fitted_gaussian() -> None:
    # Couplings start as the identity: log p(z) is the diagonal Gaussian of the fitted standardisation.
    prior = ConditionalRealNVP(TINY_PRIOR)
    mean, std = np.array([1.0, -2.0, 0.0, 3.0]), np.array([0.5, 2.0, 1.0, 4.0])
    with torch.no_grad():
        prior.z_mean.copy_(torch.as_tensor(mean, dtype=torch.float32))
        prior.z_std.copy_(torch.as_tensor(std, dtype=torch.float32))
        z = np.array([[1.5, 0.0, -1.0, 3.0]])
        got = float(prior.log_prob(torch.as_tensor(z, dtype=torch.float32), torch.zeros(1, 6))[0])
    expected = float(np.sum(-0.5 * ((z - mean) / std) ** 2 - np.log(std) - 0.5 * math.log(2 * math.pi)))
    assert math.isclose(got, expected, rel_tol=1e-5)


def test_prior_sampling_depends_on_the_state() -> None:
    prior = ConditionalRealNVP(TINY_PRIOR)
    _randomise(prior, 3, std=0.5)
    noise = torch.randn(2000, 4, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        a = prior.sample(noise, torch.full((2000, 6), -1.0))
        b = prior.sample(noise, torch.full((2000, 6), 1.0))
    # Same noise, different states: different latents, and different distributions (means far apart in
    # units of the standard error).
    assert (a - b).abs().mean() > 0.05
    se = torch.sqrt((a.var(0) + b.var(0)) / 2000)
    assert ((a.mean(0) - b.mean(0)).abs() / se).max() > 10


def test_trained_prior_recovers_a_state_dependence() -> None:
    # z = W s + 0.1 eps: the conditional NLL is 4 * (log 0.1 + log(2 pi) / 2 + 1/2) = -4.37 nats; an
    # unconditional model cannot get below ~ the NLL of the marginal (a few nats higher).
    rng = np.random.default_rng(0)
    w = np.array([[2.0, 0, 0, 0, 0, 0], [0, -1.5, 0, 0, 0, 0], [1.0, 1.0, 0, 0, 0, 0], [0, 0, 0.5, 0, 0, 0]])
    s = rng.normal(size=(3000, 6))
    z = s @ w.T + 0.1 * rng.normal(size=(3000, 4))
    prior = ConditionalRealNVP(TINY_PRIOR)
    torch.manual_seed(0)
    fit = train_prior(prior, z[:2500], s[:2500], z[2500:], s[2500:],
                      SkillTrainConfig(batch_size=128, lr=3e-3, max_epochs=25, patience=25), progress=False)
    true_nll = 4 * (math.log(0.1) + 0.5 * math.log(2 * math.pi) + 0.5)
    marginal_nll = float(np.sum(0.5 * np.log(2 * math.pi * math.e * z.var(0))))
    assert fit.best_val < true_nll + 1.5
    assert fit.best_val < marginal_nll - 4.0
    # Conditional samples follow W s.
    states = np.array([[1.0, -1.0, 0.5, 0, 0, 0], [-1.0, 1.0, -0.5, 0, 0, 0]])
    with torch.no_grad():
        for st in states:
            samples = prior.sample(torch.randn(1000, 4), torch.as_tensor(np.tile(st, (1000, 1)), dtype=torch.float32))
            assert np.allclose(samples.mean(0).numpy(), w @ st, atol=0.15)
            assert np.all(samples.std(0).numpy() < 0.3)


def test_fast_paths_match_torch() -> None:
    vae = SkillVAE(VAEConfig())
    _randomise(vae, 4, std=0.1)
    vae.fit_norm(np.random.default_rng(0).normal(size=(100, 100)), np.random.default_rng(1).normal(size=(100, 2)))
    prior = ConditionalRealNVP(RealNVPConfig())
    _randomise(prior, 5, std=0.1)
    dec, sampler = FastDecoder(vae), FastPriorSampler(prior)
    rng = np.random.default_rng(0)
    for _ in range(5):
        obs, noise = rng.normal(size=100).astype(np.float32), rng.normal(size=8).astype(np.float32)
        z = sampler.sample(noise, obs)
        dec.set_skill(z)
        with torch.no_grad():
            z_ref = prior.sample(torch.as_tensor(noise)[None], torch.as_tensor(obs)[None])[0].numpy()
            a_ref = vae.decode(torch.as_tensor(obs)[None], torch.as_tensor(z)[None])[0].numpy()
        assert np.allclose(z, z_ref, atol=1e-4)
        assert np.allclose(dec.decode(obs), a_ref, atol=1e-5)


def _policy(seed: int = 0) -> SkillPolicy:
    torch.manual_seed(0)
    vae, prior = SkillVAE(VAEConfig()), ConditionalRealNVP(RealNVPConfig())
    _randomise(prior, 6, std=0.1)
    return SkillPolicy(vae, prior, seed=seed)


def test_skill_policy_resamples_every_horizon_and_is_seeded() -> None:
    policy = _policy(seed=7)
    rng = np.random.default_rng(0)
    observations = rng.uniform(-1, 1, size=(25, 100)).astype(np.float32)
    actions, latents = [], []
    for o in observations:
        actions.append(policy.act(o))
        latents.append(policy.z.copy())
    changes = [t for t in range(1, 25) if not np.array_equal(latents[t], latents[t - 1])]
    assert changes == [10, 20]
    assert all(np.abs(a).max() <= 1.0 and a.shape == (2,) and a.dtype == np.float32 for a in actions)
    # Closed loop: a new observation changes the action under the same skill.
    assert not np.allclose(actions[1], actions[2])
    again = _policy(seed=7)
    assert np.array_equal(np.stack([again.act(o) for o in observations]), np.stack(actions))
    other = _policy(seed=8)
    assert not np.allclose(np.stack([other.act(o) for o in observations]), np.stack(actions))
    # reset(seed) restarts the same stream; SB3-style episode_start restarts the schedule.
    policy.reset(7)
    assert np.array_equal(policy.act(observations[0]), actions[0])
    policy.predict(observations[1], episode_start=np.array([True]))
    assert policy.steps == 1
    # Any layout of the observation (float64, a strided or [1, D] view) acts like its contiguous float32 vector.
    wide = np.zeros((25, 200))
    wide[:, ::2] = observations
    for view in (observations.astype(np.float64), wide[:, ::2], observations[:, None, :]):
        policy.reset(7)
        assert np.array_equal(np.stack([policy.act(o) for o in view]), np.stack(actions))
    with pytest.raises(ValueError, match="100 entries"):
        policy.act(observations[0, :99])


def test_model_files_round_trip_and_errors(tmp_path) -> None:
    torch.manual_seed(0)
    vae, prior = SkillVAE(VAEConfig(latent_dim=8)), ConditionalRealNVP(RealNVPConfig())
    _randomise(prior, 7, std=0.1)
    save_model(vae, tmp_path / "vae.pt", {"note": "x"})
    for name in ("benign", "adversarial"):
        save_model(prior, tmp_path / prior_file(name))
    models = load_skill_models(tmp_path)
    obs, z = torch.randn(3, 100), torch.randn(3, 8)
    with torch.no_grad():
        assert torch.equal(models.vae.decode(obs, z), vae.decode(obs, z))
        noise = torch.randn(3, 8)
        assert torch.equal(models.priors["adversarial"].sample(noise, obs), prior.sample(noise, obs))
    assert models.info["vae"] == {"note": "x"}
    with pytest.raises(SkillModelError, match="field 'kind'"):
        load_model(tmp_path / "vae.pt", "prior")
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    with pytest.raises(SkillModelError, match="junk.pt"):
        load_model(tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_model(tmp_path / "missing.pt")
    # A prior that does not fit the VAE is refused with the file named.
    save_model(ConditionalRealNVP(RealNVPConfig(latent_dim=4)), tmp_path / prior_file("benign"))
    with pytest.raises(SkillModelError, match="prior_benign.pt"):
        load_skill_models(tmp_path)
