"""Held-out measures of the skill models: VAE reconstruction error and prior negative log-likelihoods."""

from __future__ import annotations

import math

import numpy as np
import torch

from seal.models.skills.demos import gather_windows
from seal.models.skills.realnvp import ConditionalRealNVP
from seal.models.skills.vae import SkillVAE

_LOG_2PI = math.log(2.0 * math.pi)


@torch.no_grad()
def vae_metrics(vae: SkillVAE, obs: np.ndarray, actions: np.ndarray, rows: np.ndarray, seed: int = 0,
                batch_size: int = 4096) -> dict[str, float]:
    """Reconstruction of the windows starting at ``rows`` (decoded closed-loop from the logged observations with
    the posterior mean):

    * ``recon_mse_std``: squared error in units of each action dimension's training std, summed over the two
      dimensions, mean over steps and windows (the training objective's reconstruction term);
    * ``rmse_steering`` / ``rmse_accel``: root mean squared error in normalised action units;
    * ``recon_mse_std_shuffled_z``: the same with every window decoded with another window's latent (how much
      the latent carries beyond the observation);
    * ``kl``: mean KL of the posterior from N(0, I) (nats).
    """
    vae.eval()
    perm = np.random.default_rng(seed).permutation(rows.size)
    sq = np.zeros(2)
    rec = rec_shuffled = kl = 0.0
    for s in range(0, rows.size, batch_size):
        o, a = (torch.from_numpy(x) for x in gather_windows(obs, actions, rows[s : s + batch_size], vae.config.horizon))
        mu, logvar = vae.encode(o, a)
        recon = vae.decode(o, mu)
        sq += ((recon - a) ** 2).mean(1).sum(0).numpy()
        rec += float(vae.recon_error(recon, a).sum())
        kl += float(vae.kl(mu, logvar).sum())
        # Another window's latent: the window at the permuted position (a whole-set permutation, batch by batch).
        other = rows[perm[s : s + batch_size]]
        o2, a2 = (torch.from_numpy(x) for x in gather_windows(obs, actions, other, vae.config.horizon))
        mu2, _ = vae.encode(o2, a2)
        rec_shuffled += float(vae.recon_error(vae.decode(o, mu2), a).sum())
    n = max(1, rows.size)
    return {
        "windows": int(rows.size),
        "recon_mse_std": rec / n,
        "recon_mse_std_shuffled_z": rec_shuffled / n,
        "rmse_steering": float(math.sqrt(sq[0] / n)),
        "rmse_accel": float(math.sqrt(sq[1] / n)),
        "kl": kl / n,
    }


@torch.no_grad()
def prior_nlls(prior: ConditionalRealNVP, z: np.ndarray, cond: np.ndarray, batch_size: int = 8192) -> np.ndarray:
    """Negative log-likelihood ``[N]`` (nats per window) of latents ``z [N, L]`` given states ``cond [N, D]``."""
    prior.eval()
    out = np.empty(z.shape[0], dtype=np.float64)
    for s in range(0, z.shape[0], batch_size):
        zb = torch.as_tensor(z[s : s + batch_size], dtype=torch.float32)
        cb = torch.as_tensor(cond[s : s + batch_size], dtype=torch.float32)
        out[s : s + batch_size] = (-prior.log_prob(zb, cb)).double().numpy()
    return out


def prior_nll(prior: ConditionalRealNVP, z: np.ndarray, cond: np.ndarray) -> dict[str, float]:
    """Mean and median NLL (nats per window): the mean is what training minimises; the median is robust to the
    few windows a flow puts far out in its tails (a prior evaluated on the other class has some)."""
    v = prior_nlls(prior, z, cond)
    return {"mean": float(v.mean()), "median": float(np.median(v))}


def gaussian_nll(z_fit: np.ndarray, z_eval: np.ndarray) -> float:
    """Mean NLL (nats) of ``z_eval`` under the diagonal Gaussian fitted to ``z_fit`` (an unconditional reference
    for the priors: the gap shows what conditioning on the state and the flow add)."""
    mean = z_fit.mean(0)
    var = np.maximum(z_fit.var(0), 1e-6)
    return float(0.5 * (((z_eval - mean) ** 2 / var) + np.log(var) + _LOG_2PI).sum(1).mean())
