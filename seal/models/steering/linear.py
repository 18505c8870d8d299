"""Linear probes and steering directions on latents ``Z [N, d]``.

* `ridge_probe`: ridge regression of a score, the penalty picked on a validation part of the training rows, R^2
  on held-out rows (paper 000's latent probing).
* `softmax_probe`: a multinomial logistic classifier (L2, L-BFGS) with held-out accuracy and the majority-class
  accuracy for reference (paper 002's linear probes).
* `whitened_mean_difference`: paper 000's risk vector: the mean difference of high- and low-score latents in the
  PCA-whitened space, mapped back with the principal axes (``Sigma^{-1/2} (m_hi - m_lo)``), unit norm, sign such
  that it raises the score.
* `pca_control_vector`: paper 002's control vector: the first principal axis of differences between latents of
  opposing classes (randomly paired, each difference's sign flipped at random so the axis, not the mean, carries
  the direction), sign towards the positive class.
* `random_direction`: the baseline: a uniformly random unit direction.

Held-out rows are whole scenes (`scene_split`), because the agents of one scene share context.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

RIDGE_PENALTIES = (0.01, 0.1, 1.0, 10.0, 100.0, 1000.0)


def scene_split(groups: np.ndarray, held_out: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Boolean masks ``(train, test)`` over rows whose scene ids are ``groups [N]``: a share ``held_out`` of the
    scenes (at least one, when there are two or more) goes to test."""
    scenes = np.unique(groups)
    rng = np.random.default_rng(seed)
    n_test = min(max(int(round(held_out * scenes.size)), 1 if scenes.size > 1 else 0), scenes.size - 1)
    test_scenes = rng.choice(scenes, size=n_test, replace=False)
    test = np.isin(groups, test_scenes)
    return ~test, test


def r2_score(y: np.ndarray, pred: np.ndarray) -> float:
    """Coefficient of determination ``1 - SS_res / SS_tot`` (nan when ``y`` is constant)."""
    ss_tot = float(((y - y.mean()) ** 2).sum())
    return float("nan") if ss_tot == 0 else 1.0 - float(((y - pred) ** 2).sum()) / ss_tot


@dataclass(frozen=True)
class Standardizer:
    """Per-dimension standardisation fitted on training rows."""

    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def fit(cls, z: np.ndarray) -> Standardizer:
        return cls(z.mean(0), np.maximum(z.std(0), 1e-8))

    def __call__(self, z: np.ndarray) -> np.ndarray:
        return (z - self.mean) / self.std


@dataclass(frozen=True)
class RidgeProbe:
    """A fitted ridge probe: ``score ~ standardized(z) @ coef + intercept``.

    Attributes:
        coef: ``[d]`` weights on standardised latents.
        intercept: offset.
        penalty: the chosen ridge penalty.
        scaler: the standardisation.
        r2_train: R^2 on the training rows.
        r2_test: R^2 on the held-out rows.
        n_train, n_test: rows.
    """

    coef: np.ndarray
    intercept: float
    penalty: float
    scaler: Standardizer
    r2_train: float
    r2_test: float
    n_train: int
    n_test: int

    def predict(self, z: np.ndarray) -> np.ndarray:
        return self.scaler(z) @ self.coef + self.intercept

    @property
    def direction(self) -> np.ndarray:
        """``[d]`` unit direction in latent space along which the predicted score rises fastest."""
        w = self.coef / self.scaler.std
        return w / max(float(np.linalg.norm(w)), 1e-12)


def _ridge(x: np.ndarray, y: np.ndarray, penalty: float) -> tuple[np.ndarray, float]:
    mu = y.mean()
    coef = np.linalg.solve(x.T @ x + penalty * np.eye(x.shape[1]), x.T @ (y - mu))
    return coef, float(mu - x.mean(0) @ coef)


def ridge_probe(z: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray,
                groups: np.ndarray | None = None, seed: int = 0) -> RidgeProbe:
    """Ridge regression of ``y [N]`` on ``z [N, d]``: penalty from `RIDGE_PENALTIES` by R^2 on a fifth of the
    training scenes (``groups``), refit on all training rows, R^2 on ``test`` rows."""
    z, y = np.asarray(z, np.float64), np.asarray(y, np.float64)
    scaler = Standardizer.fit(z[train])
    x = scaler(z)
    rows = np.flatnonzero(train)
    g = groups[rows] if groups is not None else rows
    fit_part, val_part = scene_split(g, 0.2, seed)
    best, best_r2 = RIDGE_PENALTIES[0], -np.inf
    for pen in RIDGE_PENALTIES:
        coef, b = _ridge(x[rows[fit_part]], y[rows[fit_part]], pen)
        r2 = r2_score(y[rows[val_part]], x[rows[val_part]] @ coef + b)
        if r2 > best_r2:
            best, best_r2 = pen, r2
    coef, b = _ridge(x[train], y[train], best)
    return RidgeProbe(coef, b, best, scaler, r2_score(y[train], x[train] @ coef + b),
                      r2_score(y[test], x[test] @ coef + b), int(train.sum()), int(test.sum()))


@dataclass(frozen=True)
class SoftmaxProbe:
    """Held-out result of a linear classifier (`softmax_probe`)."""

    accuracy_train: float
    accuracy_test: float
    majority_test: float
    """Accuracy of always answering the most frequent training class, on the held-out rows."""
    class_counts: list[int]
    n_train: int
    n_test: int


def softmax_probe(z: np.ndarray, labels: np.ndarray, n_classes: int, train: np.ndarray, test: np.ndarray,
                  l2: float = 1e-3, max_iter: int = 200) -> SoftmaxProbe:
    """Multinomial logistic regression of ``labels [N]`` (0..n_classes-1) on standardised ``z [N, d]``."""
    scaler = Standardizer.fit(np.asarray(z, np.float64)[train])
    x = torch.as_tensor(scaler(np.asarray(z, np.float64)), dtype=torch.float64)
    y = torch.as_tensor(np.asarray(labels), dtype=torch.long)
    tr = torch.as_tensor(train)
    w = torch.zeros(x.shape[1], n_classes, dtype=torch.float64, requires_grad=True)
    b = torch.zeros(n_classes, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([w, b], max_iter=max_iter, line_search_fn="strong_wolfe")

    def closure() -> torch.Tensor:
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(x[tr] @ w + b, y[tr]) + l2 * (w**2).sum()
        loss.backward()
        return loss

    opt.step(closure)
    with torch.no_grad():
        pred = (x @ w + b).argmax(1).numpy()
    lab = np.asarray(labels)
    counts = np.bincount(lab[train], minlength=n_classes)
    return SoftmaxProbe(
        accuracy_train=float((pred[train] == lab[train]).mean()),
        accuracy_test=float((pred[test] == lab[test]).mean()) if test.any() else float("nan"),
        majority_test=float((lab[test] == int(np.argmax(counts))).mean()) if test.any() else float("nan"),
        class_counts=[int(c) for c in np.bincount(lab, minlength=n_classes)], n_train=int(train.sum()),
        n_test=int(test.sum()),
    )


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        raise ValueError("steering direction has zero norm (the two groups have the same mean)")
    return v / n


def whitened_mean_difference(z: np.ndarray, score: np.ndarray, quantile: float = 0.25,
                             eps: float = 1e-3) -> np.ndarray:
    """Paper 000's risk vector ``[d]`` (module docstring): high = top ``quantile`` of ``score``, low = bottom."""
    z, score = np.asarray(z, np.float64), np.asarray(score, np.float64)
    lo_t, hi_t = np.quantile(score, [quantile, 1.0 - quantile])
    hi, lo = z[score >= hi_t], z[score <= lo_t]
    if len(hi) == 0 or len(lo) == 0:
        raise ValueError("whitened_mean_difference: empty high or low group")
    cov = np.cov(z - z.mean(0), rowvar=False)
    evals, evecs = np.linalg.eigh(cov)
    inv_sqrt = evecs @ np.diag(1.0 / np.sqrt(np.maximum(evals, 0.0) + eps * evals.max())) @ evecs.T
    w = _unit(inv_sqrt @ (hi.mean(0) - lo.mean(0)))
    # Sign: +alpha raises the score (the projection correlates positively with it).
    return w if np.corrcoef(z @ w, score)[0, 1] >= 0 else -w


def paired_differences(pos: np.ndarray, neg: np.ndarray, rng: np.random.Generator,
                       max_pairs: int = 4096) -> np.ndarray:
    """``[P, d]`` differences ``pos_i - neg_j`` of random pairs (each row of the smaller group used about once)."""
    n = min(max(len(pos), len(neg)), max_pairs)
    return pos[rng.integers(len(pos), size=n)] - neg[rng.integers(len(neg), size=n)]


def first_axis(diffs: np.ndarray, rng: np.random.Generator, towards: np.ndarray) -> np.ndarray:
    """The first principal axis ``[d]`` of ``diffs`` with random signs, pointing along ``towards``."""
    signs = rng.choice([-1.0, 1.0], size=(len(diffs), 1))
    _, _, vt = np.linalg.svd(signs * diffs, full_matrices=False)
    axis = _unit(vt[0])
    return axis if axis @ towards >= 0 else -axis


def pca_control_vector(pos: np.ndarray, neg: np.ndarray, seed: int = 0) -> tuple[np.ndarray, float]:
    """Paper 002's control vector: unit direction ``[d]`` and the class gap along it (m: the mean projection of
    the pair differences, so ``tau = 100 %`` moves a latent from the negative to the positive class mean)."""
    if len(pos) == 0 or len(neg) == 0:
        raise ValueError(f"control vector needs both classes, got {len(pos)} positive and {len(neg)} negative rows")
    rng = np.random.default_rng(seed)
    diffs = paired_differences(np.asarray(pos, np.float64), np.asarray(neg, np.float64), rng)
    axis = first_axis(diffs, rng, diffs.mean(0))
    return axis, float(diffs.mean(0) @ axis)


def random_direction(d: int, rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit direction ``[d]``."""
    return _unit(rng.standard_normal(d))
