"""Importers of recorded driving data into seal datasets: CommonRoad XML and ScenarioNet pickles.

Core code: numpy, shapely and the seal data model only (no simulator). Entry point: `import_files`
(``seal data import commonroad|scenarionet``).
"""

from seal.core.importers.driver import FORMATS, ImportFailed, ImportOptions, collect_files, import_files
from seal.core.importers.errors import ImportFormatError
from seal.core.importers.safe_pickle import UnsafePickleError, safe_load

__all__ = [
    "FORMATS",
    "ImportFailed",
    "ImportFormatError",
    "ImportOptions",
    "UnsafePickleError",
    "collect_files",
    "import_files",
    "safe_load",
]
