"""``seal eval steering``: what steering the prior's latents does to its predictions (papers 000 and 002).

On the targets of a split (`seal.experiments.steering.collect.find_targets`):

1. risk against alpha for each risk vector (``risk_*`` in the bundle, every site or the chosen ones) and for a
   random direction of the same norm; the structured-minus-random margin at ``alpha_report`` with a paired
   bootstrap CI; the share of drivable candidates against alpha (the prior's drivability check);
2. speed control linearity: the relative change of the predicted mean speed against tau for each speed control
   vector (plain PCA and SAE), Pearson / R^2 / straightness within +-50 % (`seal.experiments.steering.metrics`);
3. zero-shot domain shift: the same targets with futures slowed to ``shift_factor`` of their speed (paper 002's
   construct), and optionally a second dataset (e.g. NGSIM imports): minADE@6 / minFDE@6 / miss rate without
   and with each speed vector at the tau its calibration curve gives for the shift and at fixed taus.

Output folder: ``report.json``, ``config.yaml`` and the plots of `seal.experiments.steering.plots`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from tqdm import tqdm

from seal.core.atomic import atomic_write_bytes, atomic_write_json
from seal.core.scenario import Scenario
from seal.experiments.steering.collect import Target, find_targets, logged_future, target_state
from seal.experiments.steering.metrics import calibrated_tau, linearity, paired_bootstrap
from seal.experiments.steering.sweeps import Decoder, displacement, risk_sweep, slowed_future, speed_sweep
from seal.models.prior.prior import TrajectoryPrior
from seal.models.steering.bundle import SteeringBundle, SteeringVector
from seal.models.steering.labels import RiskConfig
from seal.models.steering.latents import OUTPUT

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SteeringEvalConfig:
    """Settings of ``seal eval steering`` (``--config`` YAML keys; ``--set key=value``)."""

    split: str = "eval"
    """Dataset split of the targets."""
    limit: int | None = None
    """Use the first N scenarios of the split."""
    max_targets: int | None = 300
    """At most this many targets (seeded draw; paper 000 uses 300)."""
    alphas: tuple[float, ...] = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0)
    """Risk steering strengths (standard deviations of the latents at the site)."""
    alpha_report: float = 1.5
    """Alpha of the structured-vs-random margin and the plausibility share in the summary."""
    sites: tuple[str, ...] = ()
    """Latent sites whose vectors are swept by default (empty: ``output`` and the bundle's best probe sites)."""
    risk_vectors: tuple[str, ...] = ()
    """Risk vectors to sweep (empty: every ``risk_*`` vector at ``sites``)."""
    taus_pct: tuple[float, ...] = tuple(float(t) for t in range(-600, 601, 50))
    """Control strengths tau (%, 100 = one class gap) of the speed sweep. Wide: on the default pool one class gap
    moves the predicted speed by only ~12 %, and the linearity is measured where the change is within +-50 %."""
    speed_vectors: tuple[str, ...] = ()
    """Control vectors of the speed sweep (empty: every ``speed*`` and ``acceleration*`` vector of the bundle at
    ``sites``)."""
    shift_factor: float = 0.5
    """Domain shift: futures replayed at this share of their speed."""
    shift_taus_pct: tuple[float, ...] = (-30.0, -50.0, -70.0)
    """Fixed taus of the domain-shift table (besides 0 and the calibrated one)."""
    shift_dataset: str | None = None
    """A second dataset with its own (e.g. slower, real) futures for the domain-shift table."""
    shift_split: str | None = None
    """Split of ``shift_dataset`` (None: every scenario)."""
    shift_max_targets: int | None = 300
    """At most this many targets of ``shift_dataset``."""
    miss_threshold_m: float = 2.0
    """Miss: minFDE@6 above this (m)."""
    check_road: bool = True
    """Measure drivability (on-road check included); off: risk only, faster."""
    project_road: bool = True
    """Measure the candidates as the ``steered`` generator uses them: projected on the road
    (`seal.models.prior.road_projection`); the decoder's own candidates' drivable share is reported beside them
    (``plausible_raw``). Off: the decoder's candidates everywhere."""
    n_boot: int = 2000
    """Bootstrap resamples of the margin's CI."""
    seed: int = 0
    """Seed of the target draw, the random directions and the bootstrap."""
    risk: dict[str, float] = field(default_factory=dict)
    """`seal.models.steering.labels.RiskConfig` overrides."""

    def __post_init__(self) -> None:
        if not self.alphas or not self.taus_pct:
            raise ValueError("steering eval config: alphas and taus_pct need at least one value each")
        if not 0.0 < self.shift_factor < 1.0:
            raise ValueError(f"steering eval config: shift_factor must be in (0, 1), got {self.shift_factor}")
        if self.max_targets is not None and self.max_targets < 1:
            raise ValueError(f"steering eval config: max_targets must be positive, got {self.max_targets}")
        if self.n_boot < 100:
            raise ValueError(f"steering eval config: n_boot must be >= 100, got {self.n_boot}")


def _mean(a: np.ndarray) -> list[float]:
    return [float(v) for v in np.nanmean(a, axis=1)]


def _risk_section(prior: TrajectoryPrior, scenarios: Sequence[Scenario], targets: Sequence[Target],
                  vectors: Sequence[SteeringVector], cfg: SteeringEvalConfig, progress: bool) -> dict[str, Any]:
    risk = RiskConfig(**cfg.risk)
    out: dict[str, Any] = {}
    alphas = list(cfg.alphas)
    at = alphas.index(cfg.alpha_report) if cfg.alpha_report in alphas else len(alphas) - 1
    bar = tqdm(total=2 * len(alphas) * len(vectors), desc="risk sweeps", unit="decode", disable=not progress)
    decoders: dict[str, Decoder] = {}
    for v in vectors:
        dec = decoders.setdefault(v.site, Decoder(prior, scenarios, targets, v.site, cfg.project_road))
        s = risk_sweep(dec, v, alphas, risk, None, cfg.check_road, bar.update)
        r = risk_sweep(dec, v, alphas, risk, cfg.seed, cfg.check_road, bar.update)
        feature = "activity" if "activity" in v.name else "proximity"
        own_s, own_r = getattr(s, feature), getattr(r, feature)
        out[v.name] = {
            "site": v.site, "feature": feature, "alphas": alphas,
            "structured": {"activity": _mean(s.activity), "proximity": _mean(s.proximity),
                           "plausible": _mean(s.plausible), "plausible_raw": _mean(s.plausible_raw)},
            "random": {"activity": _mean(r.activity), "proximity": _mean(r.proximity),
                       "plausible": _mean(r.plausible), "plausible_raw": _mean(r.plausible_raw)},
            "alpha_report": alphas[at],
            "margin": paired_bootstrap(own_s[at], own_r[at], cfg.n_boot, cfg.seed),
            "plausible_structured": float(np.nanmean(s.plausible[at])),
            "plausible_random": float(np.nanmean(r.plausible[at])),
            "plausible_unsteered": float(np.nanmean(s.plausible[alphas.index(0.0)])) if 0.0 in alphas else None,
            "plausible_raw_structured": float(np.nanmean(s.plausible_raw[at])),
            "plausible_raw_random": float(np.nanmean(r.plausible_raw[at])),
            "project_road": cfg.project_road,
        }
    bar.close()
    return out


def _speed_section(prior: TrajectoryPrior, scenarios: Sequence[Scenario], targets: Sequence[Target],
                   vectors: Sequence[SteeringVector], cfg: SteeringEvalConfig) -> dict[str, Any]:
    out: dict[str, Any] = {}
    taus = np.asarray(cfg.taus_pct, np.float64)
    if 0.0 not in taus:
        taus = np.sort(np.append(taus, 0.0))
    decoders: dict[str, Decoder] = {}
    for v in vectors:
        dec = decoders.setdefault(v.site, Decoder(prior, scenarios, targets, v.site, cfg.project_road))
        speeds = speed_sweep(dec, v, taus.tolist())  # [taus, N]
        base = speeds[int(np.flatnonzero(taus == 0)[0])]
        moving = base > 0.5  # relative change of a near-still prediction is noise
        change = (speeds[:, moving] / base[moving] - 1.0).mean(1)
        out[v.name] = {"site": v.site, "taus_pct": taus.tolist(), "change": change.tolist(),
                       "targets": int(moving.sum()), "linearity": linearity(taus, change)}
    return out


def _shift_rows(prior: TrajectoryPrior, scenarios: Sequence[Scenario], targets: Sequence[Target],
                future: np.ndarray, vectors: Sequence[SteeringVector], calibrated: dict[str, float],
                cfg: SteeringEvalConfig) -> list[dict[str, Any]]:
    site = vectors[0].site if vectors else OUTPUT
    decoders = {site: Decoder(prior, scenarios, targets, site, cfg.project_road)}
    xy, pr = decoders[site].decode(None)
    rows = [{"vector": None, "tau_pct": 0.0, "tau_from": "unsteered",
             **displacement(xy, pr, future, miss_m=cfg.miss_threshold_m)}]
    for v in vectors:
        dec = decoders.setdefault(v.site, Decoder(prior, scenarios, targets, v.site, cfg.project_road))
        taus = [("calibrated", calibrated[v.name])] if v.name in calibrated else []
        taus += [("fixed", t) for t in cfg.shift_taus_pct]
        for how, tau in taus:
            xy, pr = dec.decode(np.broadcast_to(v.offset(tau / 100.0), (len(targets), v.direction.size)))
            rows.append({"vector": v.name, "tau_pct": float(tau), "tau_from": how,
                         **displacement(xy, pr, future, miss_m=cfg.miss_threshold_m)})
    return rows


def _futures(scenarios: Sequence[Scenario], targets: Sequence[Target]) -> tuple[np.ndarray, np.ndarray]:
    fut = np.stack([logged_future(scenarios[t.scene], t.agent) for t in targets])
    start = np.stack([target_state(scenarios[t.scene], t.agent).start_xy for t in targets])
    return fut, start


def _select(bundle: SteeringBundle, names: Sequence[str], prefixes: tuple[str, ...], sites: Sequence[str]
            ) -> list[SteeringVector]:
    if names:
        return [bundle.get(n) for n in names]
    if not sites:
        best = bundle.info.get("best_site", {})
        sites = [OUTPUT, *(s for s in best.values() if s != OUTPUT)] if isinstance(best, dict) else [OUTPUT]
    return [v for n, v in sorted(bundle.vectors.items()) if n.startswith(prefixes) and v.site in sites]


def evaluate_steering(prior: TrajectoryPrior, bundle: SteeringBundle, scenarios: Sequence[Scenario],
                      cfg: SteeringEvalConfig, shift_scenarios: Sequence[Scenario] | None = None,
                      progress: bool = False) -> dict[str, Any]:
    """The report of the module docstring (JSON-serialisable)."""
    targets = find_targets(scenarios, cfg.max_targets, cfg.seed)
    if not targets:
        raise ValueError("no targets with 2 history steps and a full 8 s future in the chosen scenarios")
    risk_vectors = _select(bundle, cfg.risk_vectors, ("risk_",), cfg.sites)
    speed_vectors = _select(bundle, cfg.speed_vectors, ("speed", "acceleration"), cfg.sites)
    log.info("steering evaluation: %d targets, %d risk vectors, %d speed vectors", len(targets), len(risk_vectors),
             len(speed_vectors))
    report: dict[str, Any] = {"targets": len(targets), "scenes": len({t.scene for t in targets}),
                              "config": _plain(asdict(cfg))}
    report["risk"] = _risk_section(prior, scenarios, targets, risk_vectors, cfg, progress)
    report["speed"] = _speed_section(prior, scenarios, targets, speed_vectors, cfg)
    calibrated, reached = {}, {}
    for name, sec in report["speed"].items():
        calibrated[name], reached[name] = calibrated_tau(np.array(sec["taus_pct"]), np.array(sec["change"]),
                                                         cfg.shift_factor - 1.0)
    fut, start = _futures(scenarios, targets)
    report["domain_shift"] = {
        "calibrated_tau_pct": calibrated, "calibration_reached": reached,
        "unshifted": _shift_rows(prior, scenarios, targets, fut, [], {}, cfg),
        "synthetic": {"factor": cfg.shift_factor, "rows": _shift_rows(
            prior, scenarios, targets, slowed_future(fut, start, cfg.shift_factor), speed_vectors, calibrated, cfg)},
    }
    if shift_scenarios is not None:
        st = find_targets(shift_scenarios, cfg.shift_max_targets, cfg.seed)
        if st:
            sfut, _ = _futures(shift_scenarios, st)
            report["domain_shift"]["dataset"] = {"dataset": cfg.shift_dataset, "targets": len(st), "rows": _shift_rows(
                prior, shift_scenarios, st, sfut, speed_vectors, calibrated, cfg)}
    return report


def write_report(report: dict[str, Any], out: str | Path) -> None:
    """``report.json``, ``config.yaml`` and the plots into ``out``."""
    from seal.experiments.steering.plots import write_plots

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "report.json", report)
    atomic_write_bytes(out / "config.yaml", yaml.safe_dump(report["config"], sort_keys=False).encode())
    write_plots(report, out)


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value
