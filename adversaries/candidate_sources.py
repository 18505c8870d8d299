"""Where candidate-based generators (`seal.adversaries.candidate_generator`: CAT, SEAL) get their candidate
adversary futures from.

A candidate source is any ``Callable[[Scenario], Candidates]`` returning the adversary's candidates. Built-ins:

* ``prior_source(path)``: the trained trajectory prior pi_gen (`seal.models.prior.TrajectoryPrior`, imported lazily).
* ``"lanes"``: map-based heuristic futures (`seal.adversaries.lane_candidates`), no learning.
* ``"constant_velocity"``: `seal.models.prior.constant_velocity_candidates`, a fan of 32 (imported lazily).
* ``steered_prior_source(path, steer, vector, alpha)``: the prior's candidates decoded with the adversary's latent
  steered along a fitted vector (``seal fit probes``; papers 000 / 002), e.g. toward risk.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from seal.core.scenario import Scenario
from seal.models.prior.candidates import Candidates

CandidateSource = Callable[[Scenario], Candidates]
NAMED_SOURCES = ("lanes", "constant_velocity")
N_CV_CANDIDATES = 32
"""Size of the constant-velocity fan (candidate 0 is plain constant velocity)."""


PRIOR_THREADS = 1
"""Torch intra-op threads for batch-of-one prior inference, set by the entry points (CLI handlers, worker entries)
of processes that build a prior-based generator. One is fastest: on the shared 2-core machine the 1-epoch prior took
22 ms mean / 27 ms p95 per scenario with 1 thread and 195 ms / 732 ms with 2 (the transformer layers are too small
to split, and a second thread competes with every other process)."""


def prior_source(path: str | Path, project_road: bool = False) -> CandidateSource:
    """The trained trajectory prior at ``path`` as a candidate source for the adversary (batch of one). Torch's
    thread count is the process's (entry points set `PRIOR_THREADS`).

    Args:
        path: a file written by `seal.models.prior.TrajectoryPrior.save`.
        project_road: project the candidates on the road (`seal.models.prior.road_projection`). Off by default,
            so CAT and SEAL keep the candidates of the papers' prior unless asked.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"trajectory prior file {path} does not exist (fit one with the prior commands)")
    try:
        from seal.models.prior import TrajectoryPrior
    except ImportError as exc:
        raise ValueError(f"seal.models.prior.TrajectoryPrior is not available ({exc}); cannot load prior "
            f"{path}") from exc
    prior = TrajectoryPrior.load(path)
    if project_road:
        prior.road_projection = prior.default_road_projection()

    def predict(scenario: Scenario) -> Candidates:
        return prior.predict([scenario], agent_indices=[scenario.adv_index])[0]

    return predict


DEFAULT_STEER_VECTOR = "lane_change@output,acceleration@output"
"""Default steering: the lateral (lane change) and longitudinal (acceleration) control vectors at the prior's output
latent, as a grid (`DEFAULT_STEER_ALPHA`). On the 2,500-scenario pool this grid raised CAT's collision rate against
the Replay ego from 71 % to 81 % with better realism (83 % with the road projection, the steered default), where
the risk vectors (``risk_proximity``,
``risk_activity``: a bare feature name means its vector at the best probe site) changed nothing (issue 20 note)."""
DEFAULT_STEER_ALPHA = "-1,0,1"
"""Steering strengths of the default grid: each vector at -1, 0, +1 class gaps (0, 0 = the prior's own decode)."""


def steered_prior_source(path: str | Path, steer: str | Path, vector: str = DEFAULT_STEER_VECTOR,
                         alpha: float | Sequence[float] | str = DEFAULT_STEER_ALPHA,
                         random_seed: int | None = None, project_road: bool = True) -> CandidateSource:
    """The trajectory prior at ``path`` with the adversary's latent steered by ``alpha`` along ``vector`` of the
    steering file / folder ``steer`` (`seal.models.steering.bundle.SteeringBundle`; several comma-separated vectors
    and / or alphas: a grid, `seal.models.steering.steer.SteeredPrior`; ``random_seed``: random directions of the
    same norms, the baseline; ``project_road``: candidates projected on the road, the default, see `SteeredPrior`).
    An adversary with too short a history gets the prior's constant-velocity fallback, as `prior_source`."""
    if not Path(path).is_file():
        raise FileNotFoundError(f"trajectory prior file {path} does not exist (fit one with the prior commands)")
    from seal.models.prior import TrajectoryPrior
    from seal.models.steering.steer import SteeredPrior

    steered = SteeredPrior(TrajectoryPrior.load(path), steer, vector, alpha, random_seed, project_road)

    def predict(scenario: Scenario) -> Candidates:
        return steered.predict(scenario, scenario.adv_index)

    return predict


def named_source(name: str) -> CandidateSource:
    """A built-in candidate source by name (one of `NAMED_SOURCES`)."""
    if name == "lanes":
        from seal.adversaries.lane_candidates import lane_candidates

        return lane_candidates
    if name == "constant_velocity":
        try:
            from seal.models.prior import constant_velocity_candidates
        except ImportError as exc:
            raise ValueError(f"seal.models.prior.constant_velocity_candidates is not available ({exc})") from exc

        def predict(scenario: Scenario) -> Candidates:
            return constant_velocity_candidates(scenario, scenario.adv_index, n_candidates=N_CV_CANDIDATES)

        return predict
    raise ValueError(f"unknown candidate source {name!r}; choose from {', '.join(NAMED_SOURCES)} or give a prior file")


def make_candidate_source(
    candidate_source: CandidateSource | None = None, prior: str | Path | None = None, candidates: str | None = None,
    steer: str | Path | None = None, steer_vector: str = DEFAULT_STEER_VECTOR,
    steer_alpha: float | Sequence[float] | str = DEFAULT_STEER_ALPHA, project_road: bool | None = None,
) -> CandidateSource:
    """Exactly one of: a callable, a prior file (`prior_source`; `steered_prior_source` when ``steer`` names a
    steering file or folder), or a built-in name. ``project_road`` (prior files only): project the prior's
    candidates on the road; None: the source's default (off for the plain prior, on when steered)."""
    given = [x is not None for x in (candidate_source, prior, candidates)]
    if sum(given) != 1:
        raise ValueError(
            "a candidate-based generator needs exactly one candidate source: a trajectory prior file (--prior FILE, "
            f"'prior:' in configs) or a built-in source ({', '.join(NAMED_SOURCES)}: --candidates NAME); "
            f"got {sum(given)}"
        )
    if steer is not None and prior is None:
        raise ValueError(f"option 'steer' ({steer}) steers the trajectory prior's latents: give a prior file too "
                         "(--prior FILE, 'prior:' in configs)")
    if project_road is not None and prior is None:
        raise ValueError(f"option 'project_road' ({project_road}) projects the trajectory prior's candidates on the "
                         "road: give a prior file (--prior FILE, 'prior:' in configs)")
    if candidate_source is not None:
        return candidate_source
    if prior is not None:
        if steer is None:
            return prior_source(prior, bool(project_road))
        return steered_prior_source(prior, steer, steer_vector, steer_alpha,
                                    project_road=True if project_road is None else bool(project_road))
    return named_source(str(candidates))


def adversary_candidates(source: CandidateSource, scenario: Scenario, generator: str) -> Candidates:
    """``source(scenario)``, checked to be the candidates of the scenario's adversary (the error names
    ``generator``)."""
    cands = source(scenario)
    if cands.agent_index != scenario.adv_index:
        raise ValueError(
            f"{generator}: candidates are for agent index {cands.agent_index}, the adversary of scenario "
            f"{scenario.scenario_id!r} is index {scenario.adv_index}"
        )
    return cands
