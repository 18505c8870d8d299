"""The command tree: top-level commands and the groups (``data``, ``bench``, ``fit``, ``eval``) that each
command module adds its subcommands to."""

from __future__ import annotations

import argparse

GROUPS = {
    "data": ("build, import, score, split and inspect scenario datasets", "Scenario datasets."),
    "fit": ("train models (trajectory prior, objective network, adversary agents)", "Model training."),
    "eval": ("evaluate models, generators and egos", "Evaluation."),
    "bench": ("benchmarks (ratios against a reference measured in the same run)", "Benchmarks."),
}


class CommandTree:
    """Hands out the top-level subparsers and, on first use, each group's subparsers."""

    def __init__(self, top: argparse._SubParsersAction) -> None:
        self.top = top
        self._groups: dict[str, argparse._SubParsersAction] = {}

    def group(self, name: str) -> argparse._SubParsersAction:
        """Subparsers of group ``name`` (one of :data:`GROUPS`), created the first time it is asked for."""
        if name not in self._groups:
            help_text, description = GROUPS[name]
            parser = self.top.add_parser(name, help=help_text, description=description)
            self._groups[name] = parser.add_subparsers(dest=f"{name}_command", metavar="SUBCOMMAND", required=True)
        return self._groups[name]
