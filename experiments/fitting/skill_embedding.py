"""The skill-space picture of thesis Fig. 6.2: samples of the benign and the adversarial prior over a set of states,
projected to 2-D, coloured by prior.

The thesis uses t-SNE; here the projection is PCA (numpy SVD, no extra dependency, and deterministic): axes are
the two directions of largest variance of all samples together, so overlap and separation of the priors show
as they are in the latent space, not as t-SNE's neighbourhood-preserving distortion.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from seal.core.atomic import atomic_write_bytes
from seal.models.skills.realnvp import ConditionalRealNVP


@torch.no_grad()
def prior_samples(prior: ConditionalRealNVP, states: np.ndarray, per_state: int, seed: int = 0) -> np.ndarray:
    """Latents ``[S * per_state, L]``: ``per_state`` draws from ``prior`` for each state ``states [S, D]``."""
    gen = torch.Generator().manual_seed(seed)
    cond = torch.as_tensor(states, dtype=torch.float32).repeat_interleave(per_state, dim=0)
    noise = torch.randn(cond.shape[0], prior.config.latent_dim, generator=gen)
    return prior.sample(noise, cond).numpy()


def pca_2d(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """2-D PCA projection ``[N, 2]`` of ``points [N, L]`` and the explained variance share of both axes ``[2]``."""
    centred = points - points.mean(0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    var = s**2
    return centred @ vt[:2].T, var[:2] / max(var.sum(), 1e-12)


def embedding_summary(samples: dict[str, np.ndarray]) -> dict[str, Any]:
    """Per prior: mean latent norm and per-dimension std; between the two: distance of the sample means in units
    of the pooled std (a scalar view of the separation the plot shows)."""
    out: dict[str, Any] = {}
    for name, z in samples.items():
        out[name] = {"samples": int(z.shape[0]), "mean_norm": round(float(np.linalg.norm(z.mean(0))), 4),
                     "mean_std": round(float(z.std(0).mean()), 4)}
    names = list(samples)
    if len(names) == 2:
        a, b = samples[names[0]], samples[names[1]]
        pooled = np.sqrt(0.5 * (a.var(0) + b.var(0))).mean()
        out["mean_distance_pooled_std"] = round(float(np.linalg.norm(a.mean(0) - b.mean(0)) / max(pooled, 1e-9)), 4)
    return out


def plot_embedding(samples: dict[str, np.ndarray], path: str | Path, title: str = "") -> dict[str, Any]:
    """Scatter of the PCA projection of all samples coloured by prior; written atomically as PNG. Returns the
    explained-variance shares and `embedding_summary`."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(samples)
    xy, explained = pca_2d(np.concatenate([samples[n] for n in names]))
    colours = {"benign": "tab:blue", "adversarial": "tab:red"}
    fig, ax = plt.subplots(figsize=(6.5, 5.5), dpi=120)
    start = 0
    for name in names:
        n = samples[name].shape[0]
        ax.scatter(xy[start : start + n, 0], xy[start : start + n, 1], s=4, alpha=0.35,
                   color=colours.get(name), label=f"{name} prior ({n} samples)", edgecolors="none")
        start += n
    ax.set_xlabel(f"PC 1 ({100 * explained[0]:.0f} % of variance)")
    ax.set_ylabel(f"PC 2 ({100 * explained[1]:.0f} % of variance)")
    ax.set_title(title or "skill latents sampled from the priors over held-out states")
    ax.legend(loc="best", markerscale=4)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())
    return {"explained_variance": [round(float(e), 4) for e in explained], **embedding_summary(samples)}
