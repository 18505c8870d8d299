"""``seal fit probes``: probes, risk vectors, control vectors and SAEs on a prior's latents, written to a folder.

For every latent site (`seal.models.steering.latents.site_names`):

* ridge probes of the activity risk and of the proximity risk (held-out R^2 on a share of the scenes);
* softmax probes of the motion classes (held-out accuracy, with the majority-class accuracy beside it);
* risk vectors ``risk_activity@SITE`` / ``risk_proximity@SITE`` (paper 000's PCA-whitened mean difference);
* control vectors ``speed@SITE`` (low vs high speed), ``acceleration@SITE`` (decelerating vs accelerating),
  ``direction@SITE`` (right vs left turn), ``lane_change@SITE`` (right vs left), by paired-difference PCA, and
  ``speed_sae{W}@SITE`` / ``acceleration_sae{W}@SITE`` refined by a sparse autoencoder of each width ``W``.

Output folder: ``steering.pt`` (`seal.models.steering.bundle.SteeringBundle`), ``report.json`` (every probe,
SAE and vector; the resolved config) and ``config.yaml``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.scenario import Scenario
from seal.experiments.steering.collect import Samples, collect, find_targets
from seal.models.prior.prior import TrajectoryPrior
from seal.models.steering.bundle import FILE_NAME, SteeringBundle, SteeringVector
from seal.models.steering.labels import CLASS_NAMES, RiskConfig
from seal.models.steering.linear import (
    pca_control_vector,
    ridge_probe,
    scene_split,
    softmax_probe,
    whitened_mean_difference,
)
from seal.models.steering.sae import SAEConfig, fit_sae, sae_control_vector

log = logging.getLogger(__name__)

CONTROL_PAIRS: dict[str, tuple[str, tuple[int, ...], tuple[int, ...]]] = {
    # name: (class set, positive classes, negative classes); see seal.models.steering.labels.CLASS_NAMES.
    "speed": ("speed", (2,), (0,)),
    "acceleration": ("acceleration", (2,), (0,)),
    "direction": ("direction", (3,), (1,)),
    "lane_change": ("lane_change", (2,), (1,)),
}
RISKS = ("activity", "proximity")
SAE_FEATURES = ("speed", "acceleration")
"""Control vectors that also get SAE-refined versions (the speed-changing ones)."""


@dataclass(frozen=True)
class ProbeFitConfig:
    """Settings of ``seal fit probes`` (``--config`` YAML keys; ``--set key=value``)."""

    split: str = "train"
    """Dataset split the latents come from (the prior's training split: probing reads, it does not fit the prior)."""
    limit: int | None = None
    """Use the first N scenarios of the split."""
    max_targets: int | None = 6000
    """Draw at most this many targets (seeded)."""
    held_out: float = 0.25
    """Share of the scenes held out for probe R^2 / accuracy."""
    risk_quantile: float = 0.25
    """Risk vectors: top vs bottom quantile of the score."""
    sae_widths: tuple[int, ...] = (32, 128, 256)
    """Sparse intermediate dimensions of the SAEs (one per width and site)."""
    sae_sites: tuple[str, ...] = ()
    """Sites that get SAEs (empty: every site)."""
    sae: dict[str, Any] = field(default_factory=lambda: {"l1": 3e-2, "epochs": 150, "batch_size": 512, "lr": 1e-3})
    """`seal.models.steering.sae.SAEConfig` fields besides width and seed."""
    risk: dict[str, float] = field(default_factory=dict)
    """`seal.models.steering.labels.RiskConfig` overrides."""
    seed: int = 0
    """Seed of the target draw, the held-out scenes, the pairing and the SAEs."""

    def __post_init__(self) -> None:
        if not 0.0 < self.held_out < 1.0:
            raise ValueError(f"probes config: held_out must be in (0, 1), got {self.held_out}")
        if not 0.0 < self.risk_quantile <= 0.5:
            raise ValueError(f"probes config: risk_quantile must be in (0, 0.5], got {self.risk_quantile}")
        if any(w <= 0 for w in self.sae_widths):
            raise ValueError(f"probes config: sae_widths must be positive, got {list(self.sae_widths)}")
        if self.max_targets is not None and self.max_targets < 10:
            raise ValueError(f"probes config: max_targets must be >= 10 (or null), got {self.max_targets}")


def _rows(labels: dict[str, np.ndarray], cls_set: str, classes: tuple[int, ...]) -> np.ndarray:
    return np.isin(labels[cls_set], classes)


def _probe_site(z: np.ndarray, s: Samples, train: np.ndarray, test: np.ndarray, seed: int) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for risk in RISKS:
        y = s.labels[risk]
        ok = np.isfinite(y)
        p = ridge_probe(z[ok], y[ok], train[ok], test[ok], groups=s.groups[ok], seed=seed)
        out[f"r2_{risk}"] = {"test": p.r2_test, "train": p.r2_train, "penalty": p.penalty, "n_train": p.n_train,
                             "n_test": p.n_test}
    for name, classes in CLASS_NAMES.items():
        lab = s.labels[name].astype(int)
        if np.unique(lab[train]).size < 2:
            out[f"acc_{name}"] = {"skipped": "one class only in the training rows"}
            continue
        sp = softmax_probe(z, lab, len(classes), train, test)
        out[f"acc_{name}"] = {"test": sp.accuracy_test, "train": sp.accuracy_train, "majority": sp.majority_test,
                              "class_counts": dict(zip(classes, sp.class_counts, strict=True))}
    return out


def _vectors_site(site: str, z: np.ndarray, s: Samples, cfg: ProbeFitConfig, sae_report: dict[str, Any]
                  ) -> dict[str, SteeringVector]:
    vectors: dict[str, SteeringVector] = {}
    rms = float(np.sqrt(z.var(0).mean()))
    for risk in RISKS:
        ok = np.isfinite(s.labels[risk])
        w = whitened_mean_difference(z[ok], s.labels[risk][ok], cfg.risk_quantile)
        vectors[f"risk_{risk}@{site}"] = SteeringVector(f"risk_{risk}@{site}", site, w, rms, "risk")
    for name, (cls_set, pos_c, neg_c) in CONTROL_PAIRS.items():
        pos, neg = z[_rows(s.labels, cls_set, pos_c)], z[_rows(s.labels, cls_set, neg_c)]
        if len(pos) < 5 or len(neg) < 5:
            log.info("control vector %s@%s skipped: %d positive, %d negative rows", name, site, len(pos), len(neg))
            continue
        v, gap = pca_control_vector(pos, neg, seed=cfg.seed)
        vectors[f"{name}@{site}"] = SteeringVector(f"{name}@{site}", site, v, gap, "control")
    if cfg.sae_sites and site not in cfg.sae_sites:
        return vectors
    pairs = {n: (z[_rows(s.labels, c, pc)], z[_rows(s.labels, c, nc)])
             for n, (c, pc, nc) in CONTROL_PAIRS.items() if n in SAE_FEATURES}
    for width in cfg.sae_widths:
        sae, stats = fit_sae(z, SAEConfig(width=width, seed=cfg.seed, **cfg.sae))
        sae_report[f"sae{width}@{site}"] = asdict(stats)
        for feature, (pos, neg) in pairs.items():
            if len(pos) >= 5 and len(neg) >= 5:
                v, gap = sae_control_vector(sae, pos, neg, seed=cfg.seed)
                name = f"{feature}_sae{width}@{site}"
                vectors[name] = SteeringVector(name, site, v, gap, "control")
    return vectors


def _best_site(probes: dict[str, Any], key: str) -> str:
    """The site whose probe ``key`` has the highest held-out value."""
    return max(probes, key=lambda site: float(probes[site][key]["test"]))


def fit_probes(prior: TrajectoryPrior, scenarios: Sequence[Scenario], out: str | Path, cfg: ProbeFitConfig,
               info: dict[str, Any] | None = None, progress: bool = False) -> dict[str, Any]:
    """Fit everything of the module docstring on ``scenarios`` and write ``out``; returns the report."""
    risk = RiskConfig(**cfg.risk)
    targets = find_targets(scenarios, cfg.max_targets, cfg.seed)
    samples = collect(prior, scenarios, targets, risk, progress=progress)
    train, test = scene_split(samples.groups, cfg.held_out, cfg.seed)
    probes: dict[str, Any] = {}
    vectors: dict[str, SteeringVector] = {}
    sae_report: dict[str, Any] = {}
    for site, z in samples.latents.items():
        log.info("probes and vectors at site %s (%d targets)", site, len(z))
        probes[site] = _probe_site(z, samples, train, test, cfg.seed)
        vectors.update(_vectors_site(site, z, samples, cfg, sae_report))
    best = {r: _best_site(probes, f"r2_{r}") for r in RISKS}
    cosines = {n: float(v.direction @ vectors[n.split("_sae")[0] + "@" + v.site].direction)
               for n, v in vectors.items() if "_sae" in n and n.split("_sae")[0] + "@" + v.site in vectors}
    report: dict[str, Any] = {
        "data": {**(info or {}), "targets": len(targets), "scenes": int(np.unique(samples.groups).size),
                 "held_out_targets": int(test.sum())},
        "config": _jsonable(asdict(cfg)), "risk_config": asdict(risk),
        "label_shares": {name: np.bincount(samples.labels[name].astype(int), minlength=len(c)).tolist()
                         for name, c in CLASS_NAMES.items()},
        "probes": probes, "best_site": best, "sae": sae_report, "sae_pca_cosine": cosines,
        "vectors": {n: {"site": v.site, "unit": v.unit, "kind": v.kind} for n, v in vectors.items()},
    }
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    SteeringBundle(vectors, {"prior": (info or {}).get("prior"), "best_site": best}).save(out / FILE_NAME)
    atomic_write_json(out / "report.json", report)
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(_jsonable(asdict(cfg)), sort_keys=False).encode())
    return report


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value
