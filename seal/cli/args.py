"""Argument types shared by the ``seal`` subcommands: each names the option in its error."""

from __future__ import annotations

import argparse
from collections.abc import Callable

LAYOUTS = ("highway", "merge", "intersection", "roundabout")


class CliError(Exception):
    """A user error: printed without a traceback, exit status 2."""


def positive_int(name: str) -> Callable[[str], int]:
    """Parser for a strictly positive integer option called ``name``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer, got {text!r}") from None
        if value <= 0:
            raise argparse.ArgumentTypeError(f"{name} must be positive, got {value}")
        return value

    return parse


def positive_float(name: str) -> Callable[[str], float]:
    """Parser for a strictly positive float option called ``name``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if not value > 0.0:
            raise argparse.ArgumentTypeError(f"{name} must be positive, got {value}")
        return value

    return parse


def share(name: str) -> Callable[[str], float]:
    """Parser for a share in [0, 1] called ``name``."""

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number, got {text!r}") from None
        if not 0.0 <= value <= 1.0:
            raise argparse.ArgumentTypeError(f"{name} must be in [0, 1], got {value}")
        return value

    return parse


def layouts(text: str) -> list[str]:
    """Parser for ``--layouts``: names separated by spaces or commas."""
    names = [t.strip() for t in text.replace(",", " ").split() if t.strip()]
    unknown = [n for n in names if n not in LAYOUTS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown layout(s) {unknown}; choose from {', '.join(LAYOUTS)}")
    return names


def print_result(result: dict, as_json: bool, width: int = 32) -> None:
    """Print a flat result dict as JSON or as aligned ``key: value`` lines."""
    import json

    if as_json:
        print(json.dumps(result, indent=2, default=str))
    else:
        for key, value in result.items():
            print(f"{key:>{width}}: {value}")
