"""Embedding-space analysis of Table 7.5 (thesis 7.6.2), in numpy / torch (no scikit-learn in this stack).

* Per-class sub-clustering: k-means (k-means++ seeding, Lloyd iterations) with ``k`` clusters inside each safety
  class; every sample gets the label (class, sub-cluster), ``3 k`` clusters in all.
* Silhouette (mean over samples of ``(b - a) / max(a, b)``, ``a`` the mean distance to the own cluster's other
  members, ``b`` the smallest mean distance to another cluster; 0 for singletons) and Davies-Bouldin (mean over
  clusters of ``max_j (s_i + s_j) / d(c_i, c_j)``, ``s`` the mean distance of a cluster's members to its centroid)
  of that labelling, Euclidean, averaged over ``k = 3..6``. High silhouette / low Davies-Bouldin = coherent
  sub-clusters that stay apart from each other and from the other classes.
* Linear probe: multinomial logistic regression (full-batch L-BFGS, small L2) fitted on training embeddings,
  accuracy on held-out ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

KM_RANGE = (3, 4, 5, 6)
"""N_km of Table 7.5."""


def kmeans(x: np.ndarray, k: int, seed: int = 0, iters: int = 50) -> np.ndarray:
    """``[N]`` cluster index of each row of ``x [N, D]`` (k-means++ seeding, Lloyd); ``k`` is capped at ``N``."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0]
    k = max(1, min(k, n))
    rng = np.random.default_rng(seed)
    centres = [x[rng.integers(n)]]
    for _ in range(1, k):
        d2 = np.min(((x[:, None] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
        total = d2.sum()
        centres.append(x[rng.choice(n, p=d2 / total)] if total > 0 else x[rng.integers(n)])
    c = np.array(centres)
    assign = np.zeros(n, dtype=np.int64)
    for it in range(iters):
        new = ((x[:, None] - c[None]) ** 2).sum(-1).argmin(axis=1)
        if it > 0 and np.array_equal(new, assign):
            break
        assign = new
        for j in range(k):
            if (assign == j).any():
                c[j] = x[assign == j].mean(axis=0)
    return assign


def _pairwise(x: np.ndarray) -> np.ndarray:
    sq = (x * x).sum(1)
    return np.sqrt(np.maximum(sq[:, None] + sq[None] - 2.0 * x @ x.T, 0.0))


def silhouette(x: np.ndarray, labels: np.ndarray) -> float:
    """Mean silhouette of the clustering ``labels [N]`` of ``x [N, D]`` (needs at least two clusters)."""
    x = np.asarray(x, dtype=np.float64)
    ids, labels = np.unique(labels, return_inverse=True)
    if ids.size < 2:
        raise ValueError("silhouette needs at least two clusters")
    dist = _pairwise(x)
    onehot = np.eye(ids.size)[labels]  # [N, C]
    sums = dist @ onehot  # [N, C] summed distance to each cluster
    sizes = onehot.sum(0)
    own = sizes[labels]
    a = np.where(own > 1, sums[np.arange(x.shape[0]), labels] / np.maximum(own - 1, 1), 0.0)
    mean_other = sums / sizes[None]
    mean_other[np.arange(x.shape[0]), labels] = np.inf
    b = mean_other.min(axis=1)
    s = np.where(own > 1, (b - a) / np.maximum(np.maximum(a, b), 1e-12), 0.0)
    return float(s.mean())


def davies_bouldin(x: np.ndarray, labels: np.ndarray) -> float:
    """Davies-Bouldin index of the clustering ``labels [N]`` of ``x [N, D]`` (needs at least two clusters)."""
    x = np.asarray(x, dtype=np.float64)
    ids, labels = np.unique(labels, return_inverse=True)
    if ids.size < 2:
        raise ValueError("davies_bouldin needs at least two clusters")
    c = np.stack([x[labels == j].mean(0) for j in range(ids.size)])
    s = np.array([np.linalg.norm(x[labels == j] - c[j], axis=1).mean() for j in range(ids.size)])
    dc = _pairwise(c)
    np.fill_diagonal(dc, np.inf)
    ratio = (s[:, None] + s[None]) / np.maximum(dc, 1e-12)
    return float(ratio.max(axis=1).mean())


def subcluster_labels(v: np.ndarray, classes: np.ndarray, k: int, seed: int = 0) -> np.ndarray:
    """``[N]`` label ``class * k + sub-cluster`` from k-means with ``k`` clusters inside each class."""
    out = np.zeros(len(classes), dtype=np.int64)
    for cls in np.unique(classes):
        rows = np.flatnonzero(classes == cls)
        out[rows] = int(cls) * k + kmeans(v[rows], k, seed=seed + int(cls))
    return out


def cluster_quality(v: np.ndarray, classes: np.ndarray, ks: Sequence[int] = KM_RANGE, seed: int = 0
                    ) -> dict[str, float]:
    """Silhouette and Davies-Bouldin of the per-class sub-clustering, averaged over ``ks``."""
    sil, db = [], []
    for k in ks:
        lab = subcluster_labels(v, classes, k, seed)
        sil.append(silhouette(v, lab))
        db.append(davies_bouldin(v, lab))
    return {"silhouette": float(np.mean(sil)), "davies_bouldin": float(np.mean(db))}


def linear_probe(train_v: np.ndarray, train_y: np.ndarray, test_v: np.ndarray, test_y: np.ndarray,
                 n_classes: int = 3, l2: float = 1e-3, seed: int = 0) -> float:
    """Held-out accuracy of a multinomial logistic regression fitted on ``train_v [N, D]``, ``train_y [N]``."""
    torch.manual_seed(seed)
    xt = torch.as_tensor(train_v, dtype=torch.float64)
    mean, std = xt.mean(0), xt.std(0).clamp(min=1e-6)  # standardised inputs: one L2 strength fits any scale
    xt = (xt - mean) / std
    yt = torch.as_tensor(train_y, dtype=torch.long)
    w = torch.zeros(xt.shape[1], n_classes, dtype=torch.float64, requires_grad=True)
    b = torch.zeros(n_classes, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([w, b], max_iter=200, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(xt @ w + b, yt) + l2 * (w * w).sum()
        loss.backward()
        return loss

    opt.step(closure)
    xs = (torch.as_tensor(test_v, dtype=torch.float64) - mean) / std
    with torch.no_grad():
        pred = (xs @ w + b).argmax(1).numpy()
    return float((pred == np.asarray(test_y)).mean())
