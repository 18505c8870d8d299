"""The measurements of ``seal eval steering``, each over a list of targets decoded in batches.

* `risk_sweep`: per target and alpha, the prior-weighted risk of the candidates (activity and proximity,
  `seal.experiments.steering.collect.future_labels`) and the share of drivable candidates
  (`seal.models.prior.metrics.drivability`: |acc| <= 8 m/s^2, |yaw rate| <= 1 rad/s, on or near the road), for a
  steering vector and for a random direction of the same norm (a fresh direction per target, seeded). With the
  decoder's ``project_road`` (the steered generator's default) the candidates are measured as the generator uses
  them, projected on the road (`seal.models.prior.road_projection`), and the drivable share of the decoder's own
  candidates is kept beside it (``plausible_raw``).
* `speed_sweep`: per target and tau, the prior-weighted mean speed of the candidates.
* `displacement`: minADE@6, minFDE@6 and misses of candidates against futures.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from seal.core.scenario import Scenario
from seal.experiments.steering.collect import BATCH, Target, future_labels, target_state
from seal.models.prior.metrics import drivability
from seal.models.prior.prior import TrajectoryPrior
from seal.models.steering.bundle import SteeringVector
from seal.models.steering.labels import RiskConfig, mean_speed
from seal.models.steering.latents import SteeringSession, prepare
from seal.models.steering.linear import random_direction


@dataclass
class Decoder:
    """Decodes the targets batch by batch with a per-target offset at one site; ``project_road``: candidates
    projected on the road as the steered generator projects them (`TrajectoryPrior.project`)."""

    prior: TrajectoryPrior
    scenarios: Sequence[Scenario]
    targets: Sequence[Target]
    site: str
    project_road: bool = False

    def __post_init__(self) -> None:
        self.sessions: list[tuple[int, SteeringSession]] = []
        for lo in range(0, len(self.targets), BATCH):
            chunk = self.targets[lo : lo + BATCH]
            batch = prepare(self.prior, [self.scenarios[t.scene] for t in chunk], [t.agent for t in chunk])
            self.sessions.append((lo, SteeringSession(self.prior, batch, self.site)))

    def decode(self, offsets: np.ndarray | None, raw: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Candidates ``[N, K, 80, 2]`` and probabilities ``[N, K]`` with ``offsets`` ``[N, d]`` or ``[d]`` (the
        same for every target; None: unsteered); projected on the road when ``project_road`` unless ``raw``."""
        if offsets is not None and np.ndim(offsets) == 1:
            offsets = np.broadcast_to(offsets, (len(self.targets), np.size(offsets)))
        xy, pr = [], []
        for lo, session in self.sessions:
            off = None if offsets is None else offsets[lo : lo + session.batch.size]
            a, b = session.decode(off)
            xy.append(a)
            pr.append(b)
        out = np.concatenate(xy)
        return (out if raw or not self.project_road else self.projected(out)), np.concatenate(pr)

    def projected(self, xy: np.ndarray) -> np.ndarray:
        """Candidates ``[N, K, 80, 2]`` of the targets (as `decode` with ``raw``) projected on the road."""
        out = []
        for lo, session in self.sessions:
            b = session.batch
            scenes = [self.scenarios[t.scene] for t in self.targets[lo : lo + b.size]]
            out.append(self.prior.project(xy[lo : lo + b.size], b.pose, b.feats["start"].numpy(), scenes))
        return np.concatenate(out)


@dataclass(frozen=True)
class RiskCurves:
    """``[A, N]`` per alpha and target: prior-weighted activity and proximity risk, share of drivable candidates
    (as measured: projected when the decoder projects) and share of the decoder's own candidates that are drivable
    (``plausible_raw``; equal to ``plausible`` without projection)."""

    activity: np.ndarray
    proximity: np.ndarray
    plausible: np.ndarray
    plausible_raw: np.ndarray


def _risk_of(xy: np.ndarray, probs: np.ndarray, scenarios: Sequence[Scenario], targets: Sequence[Target],
             risk: RiskConfig, check_road: bool, xy_raw: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    act, prox, ok, ok_raw = (np.full(len(targets), np.nan) for _ in range(4))
    for i, t in enumerate(targets):
        s = scenarios[t.scene]
        st = target_state(s, t.agent)
        lab = future_labels(xy[i], st, risk)
        act[i] = float(probs[i] @ lab["activity"])
        prox[i] = float(probs[i] @ lab["proximity"]) if not st.is_ego else np.nan
        if check_road:
            ok[i] = float(drivability(xy[i], st.start_xy, st.start_heading, s.road).drivable.mean())
            ok_raw[i] = ok[i] if xy_raw is None else float(
                drivability(xy_raw[i], st.start_xy, st.start_heading, s.road).drivable.mean())
    return act, prox, ok, ok_raw


def risk_sweep(decoder: Decoder, vector: SteeringVector, alphas: Sequence[float], risk: RiskConfig,
               random_seed: int | None = None, check_road: bool = True,
               tick: Callable[[], None] | None = None) -> RiskCurves:
    """`RiskCurves` of steering every target by ``vector`` at each alpha, or, with ``random_seed``, each target
    along its own random unit direction scaled like ``vector`` (the same offset norm at every alpha)."""
    n, d = len(decoder.targets), decoder.prior.config.d_model
    directions = np.broadcast_to(vector.direction, (n, d))
    if random_seed is not None:
        rng = np.random.default_rng(random_seed)
        directions = np.stack([random_direction(d, rng) for _ in range(n)])
    curves = []
    for a in alphas:
        xy_raw, probs = decoder.decode(a * vector.unit * directions if a != 0 else None, raw=True)
        xy = decoder.projected(xy_raw) if decoder.project_road else xy_raw
        curves.append(_risk_of(xy, probs, decoder.scenarios, decoder.targets, risk, check_road,
                               xy_raw if decoder.project_road else None))
        if tick is not None:
            tick()
    return RiskCurves(*(np.stack([c[k] for c in curves]) for k in range(4)))


def speed_sweep(decoder: Decoder, vector: SteeringVector, taus_pct: Sequence[float]) -> np.ndarray:
    """``[len(taus), N]`` prior-weighted mean candidate speed (m/s) of each target at each tau (%)."""
    out = []
    for tau in taus_pct:
        xy, probs = decoder.decode(None if tau == 0 else np.broadcast_to(vector.offset(tau / 100.0),
                                                                         (len(decoder.targets), vector.direction.size)))
        starts = np.stack([target_state(decoder.scenarios[t.scene], t.agent).start_xy for t in decoder.targets])
        v = mean_speed(xy, starts[:, None, :])  # [N, K]
        out.append((probs * v).sum(1))
    return np.stack(out)


def displacement(xy: np.ndarray, probs: np.ndarray, future: np.ndarray, k: int = 6, miss_m: float = 2.0
                 ) -> dict[str, float]:
    """minADE@k, minFDE@k (m) and the miss rate (minFDE@k > ``miss_m``) of candidates ``[N, K, T, 2]`` with
    probabilities ``[N, K]`` against futures ``[N, T, 2]``."""
    top = np.argsort(-probs, axis=1, kind="stable")[:, :k]
    cand = np.take_along_axis(xy, top[:, :, None, None], axis=1)
    d = np.linalg.norm(cand - future[:, None], axis=-1)  # [N, k, T]
    ade, fde = d.mean(-1).min(1), d[..., -1].min(1)
    return {"min_ade": float(ade.mean()), "min_fde": float(fde.mean()), "miss_rate": float((fde > miss_m).mean()),
            "targets": int(len(future))}


def slowed_future(future: np.ndarray, start: np.ndarray, factor: float = 0.5) -> np.ndarray:
    """Paper 002's domain shift: futures ``[N, T, 2]`` replayed at ``factor`` of their speed (the first
    ``factor`` of the waypoints stretched over the horizon by linear interpolation from ``start [N, 2]``)."""
    n, t, _ = future.shape
    pts = np.concatenate([start[:, None], future], axis=1)  # index j = time j * dt
    src = factor * np.arange(1, t + 1)
    lo = np.floor(src).astype(int)
    frac = (src - lo)[None, :, None]
    hi = np.minimum(lo + 1, t)
    return pts[:, lo] * (1 - frac) + pts[:, hi] * frac
