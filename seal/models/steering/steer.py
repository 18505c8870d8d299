"""`SteeredPrior`: a trajectory prior whose target latent is steered along one fitted vector before decoding (the
candidate source of the ``steered`` generator and of CAT / SEAL's ``steer`` option)."""

from __future__ import annotations

import os

from seal.core.scenario import Scenario
from seal.models.prior.baseline import constant_velocity_candidates
from seal.models.prior.candidates import Candidates
from seal.models.prior.prior import TrajectoryPrior
from seal.models.steering.bundle import SteeringBundle, SteeringFileError, SteeringVector
from seal.models.steering.latents import SteeringSession, prepare, site_names


def resolve_vector(bundle: SteeringBundle, name: str) -> SteeringVector:
    """``FEATURE@SITE``, or a bare ``FEATURE`` (e.g. ``risk_proximity``) at the bundle's best probe site for it
    (``output`` when the bundle names none)."""
    if "@" in name:
        return bundle.get(name)
    best = bundle.info.get("best_site", {})
    feature = name.removeprefix("risk_")
    site = best.get(feature, "output") if isinstance(best, dict) else "output"
    return bundle.get(f"{name}@{site}")


class SteeredPrior:
    """Candidates of ``prior`` with each target's latent moved by ``alpha`` along ``vector`` of ``steer``.

    Args:
        prior: the trajectory prior.
        steer: a steering file or folder (``seal fit probes``), or a loaded `SteeringBundle`.
        vector: vector name (`resolve_vector`).
        alpha: steering strength in the vector's unit (alpha for risk vectors, tau / 100 for control vectors).
    """

    def __init__(self, prior: TrajectoryPrior, steer: str | os.PathLike[str] | SteeringBundle, vector: str,
                 alpha: float) -> None:
        bundle = steer if isinstance(steer, SteeringBundle) else SteeringBundle.load(steer)
        self.prior = prior
        self.vector = resolve_vector(bundle, vector)
        if self.vector.site not in site_names(prior):
            raise SteeringFileError(f"steering vector {self.vector.name!r} is at site {self.vector.site!r}, which this "
                                    f"prior does not have ({', '.join(site_names(prior))})")
        if self.vector.direction.shape != (prior.config.d_model,):
            raise SteeringFileError(f"steering vector {self.vector.name!r} has {self.vector.direction.size} "
                                    f"dimensions; the prior's latents have {prior.config.d_model} (fitted for "
                                    "another prior?)")
        self.alpha = float(alpha)
        self.offset = self.vector.offset(self.alpha)

    def predict(self, scenario: Scenario, agent: int) -> Candidates:
        """Steered candidates of ``agent`` (constant-velocity fallback for a too-short history, as the prior)."""
        self.prior._check_present(scenario, agent)
        try:
            batch = prepare(self.prior, [scenario], [agent])
        except ValueError as exc:
            return constant_velocity_candidates(scenario, agent, self.prior.n_candidates, fallback=str(exc))
        xy, probs = SteeringSession(self.prior, batch, self.vector.site).decode(self.offset)
        return Candidates.from_positions(xy[0], probs[0], batch.pose[0, :2], float(batch.pose[0, 2]), agent)
