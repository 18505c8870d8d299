"""seal core: scenario data model, dataset store, learned models, CLI."""

from seal.core.road import LaneSpec, RoadDescription
from seal.core.scenario import CURRENT_STEP, DT_S, N_FUTURE, N_HISTORY, N_STEPS, TRACK_FIELDS, Scenario, ScenarioError

__version__ = "0.1.0"

__all__ = [
    "CURRENT_STEP",
    "DT_S",
    "LaneSpec",
    "N_FUTURE",
    "N_HISTORY",
    "N_STEPS",
    "RoadDescription",
    "Scenario",
    "ScenarioError",
    "TRACK_FIELDS",
    "__version__",
]
