"""How an episode (or one agent's part of it) ends: the one set of outcome names every layer uses.

`Outcome` is a `StrEnum`, so its members compare equal to (and are stored as) the plain strings that results
stores, CSV files and ``info["outcome"]`` have always held: ``"success"``, ``"crash"``, ``"out_of_road"``,
``"timeout"``.
"""

from __future__ import annotations

from enum import StrEnum


class Outcome(StrEnum):
    """The end of an ego episode, in the order reports list them."""

    SUCCESS = "success"
    """Route completion reached the success threshold (0.95 of the logged route)."""
    CRASH = "crash"
    """The ego's box overlapped another agent's (ends the episode when ``terminate_on_crash``)."""
    OUT_OF_ROAD = "out_of_road"
    """The ego left the drivable area, crossed a solid edge / median, or strayed too far from its route."""
    TIMEOUT = "timeout"
    """The scenario's time ran out first."""


OUTCOMES: tuple[str, ...] = tuple(o.value for o in Outcome)
"""The outcome names as plain strings, in `Outcome` order."""
