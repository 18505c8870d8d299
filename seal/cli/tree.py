"""The command tree: top-level commands and the groups (``data``, ``bench``, ``fit``, ``eval``) that each
command module adds its subcommands to."""

from __future__ import annotations

import argparse

GROUPS = {
    "data": ("build, import, score, split and inspect scenario datasets", "Scenario datasets."),
    "fit": ("train models (trajectory prior, objective network, adversary agents)", "Model training."),
    "eval": ("evaluate models, generators and egos",
             "Evaluation. `seal eval RUN... [options]` (a first argument that is no subcommand) is short for "
             "`seal eval runs RUN... [options]`."),
    "bench": ("benchmarks (ratios against a reference measured in the same run)", "Benchmarks."),
}


class CommandTree:
    """Hands out the top-level subparsers and, on first use, each group's subparsers."""

    def __init__(self, top: argparse._SubParsersAction) -> None:
        self.top = top
        self._groups: dict[str, argparse._SubParsersAction] = {}
        self._defaults: dict[str, str] = {}

    def group(self, name: str) -> argparse._SubParsersAction:
        """Subparsers of group ``name`` (one of :data:`GROUPS`), created the first time it is asked for."""
        if name not in self._groups:
            help_text, description = GROUPS[name]
            parser = self.top.add_parser(name, help=help_text, description=description)
            self._groups[name] = parser.add_subparsers(dest=f"{name}_command", metavar="SUBCOMMAND", required=True)
        return self._groups[name]

    def set_default(self, group: str, subcommand: str) -> None:
        """Make ``seal GROUP ARG ...``, where ARG is neither a subcommand of ``group`` nor an option, mean
        ``seal GROUP SUBCOMMAND ARG ...`` (argparse cannot tell a subcommand from a positional by itself)."""
        self._defaults[group] = subcommand

    def expand_default(self, argv: list[str]) -> list[str]:
        """``argv`` with a group's default subcommand inserted where `set_default` applies."""
        if len(argv) >= 2 and argv[0] in self._defaults and argv[0] in self._groups:
            first = argv[1]
            if not first.startswith("-") and first not in self._groups[argv[0]].choices:
                return [argv[0], self._defaults[argv[0]], *argv[1:]]
        return argv
