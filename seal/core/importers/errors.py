"""Errors of the importers: every message names the file and the element that is wrong."""

from __future__ import annotations

import os


class ImportFormatError(ValueError):
    """A file cannot be imported.

    The message reads ``"FILE: ELEMENT: PROBLEM"`` (``ELEMENT`` may be empty for whole-file problems), e.g.
    ``"x.xml: dynamicObstacle 12: trajectory has a gap (time steps 31..33 missing)"``.

    Args:
        path: the file.
        element: the offending element (``"lanelet 5"``, ``"tracks['17'].state.valid"``), or ``""``.
        problem: what is wrong and, where it helps, what is expected instead.
    """

    def __init__(self, path: str | os.PathLike[str], element: str, problem: str) -> None:
        self.path = str(path)
        self.element = element
        self.problem = problem
        where = f"{self.path}: {element}" if element else self.path
        super().__init__(f"{where}: {problem}")
