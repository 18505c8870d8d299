"""The ``seal`` command line.

Each command module under ``seal/cli/`` registers its subcommands on the shared :class:`CommandTree` and imports
its implementation lazily inside the handler, so ``seal --help`` is instant and the core package does not import
the simulator, the adversaries or the experiments at module load. To add commands, write a module with a
``register(tree)`` function and list it in :data:`COMMAND_MODULES`.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence

from seal.cli.args import CliError
from seal.cli.tree import CommandTree

__all__ = ["COMMAND_MODULES", "CliError", "build_parser", "main"]

#: Exit status when stdout's reader went away: what a shell reports for a tool killed by SIGPIPE (128 + 13).
EXIT_BROKEN_PIPE = 141

#: Modules whose ``register(tree)`` adds commands, in the order they appear in ``seal --help``.
COMMAND_MODULES = (
    "seal.cli.data", "seal.cli.bench", "seal.cli.generators", "seal.cli.importers", "seal.cli.goose", "seal.cli.prior",
    "seal.cli.skills", "seal.cli.evaluate", "seal.cli.avoidability", "seal.cli.compare", "seal.cli.run",
    "seal.cli.train", "seal.cli.objective", "seal.cli.steering", "seal.cli.behavior", "seal.cli.background",
)


def build_parser() -> argparse.ArgumentParser:
    return build_tree()[0]


def build_tree() -> tuple[argparse.ArgumentParser, CommandTree]:
    """The parser and its command tree (which knows the groups' default subcommands)."""
    from seal import __version__

    parser = argparse.ArgumentParser(
        prog="seal",
        description="Closed-loop adversarial driving scenarios: build/inspect scenario datasets, roll out and "
        "render scenarios, train and evaluate models and generators, benchmark.",
    )
    parser.add_argument("--version", action="version", version=f"seal {__version__}")
    tree = CommandTree(parser.add_subparsers(dest="command", metavar="COMMAND", required=True))
    for name in COMMAND_MODULES:
        importlib.import_module(name).register(tree)
    return parser, tree


def configure_logging(level: int = logging.INFO) -> None:
    """Library code logs through ``logging.getLogger(__name__)``; the CLI shows INFO and above on stderr as plain
    lines (results and JSON go to stdout). Progress bars (tqdm) write to stderr on their own."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("%(message)s"))
    root = logging.getLogger("seal")
    root.handlers[:] = [handler]
    root.setLevel(level)
    root.propagate = False


def main(argv: Sequence[str] | None = None) -> int:
    parser, tree = build_tree()
    args = parser.parse_args(tree.expand_default(list(sys.argv[1:] if argv is None else argv)))
    configure_logging()
    import yaml

    from seal.core.errors import SealError
    from seal.core.road import RoadError
    from seal.core.scenario import ScenarioError

    try:
        if getattr(args, "plugin", None):
            from seal.core.plugins import load_plugins

            load_plugins(args.plugin)
        return int(args.func(args) or 0)
    except BrokenPipeError:
        # The reader of stdout went away (`seal data info | head`): stop quietly with the status a shell reports
        # for `ls` or `git log` killed by SIGPIPE there (128 + 13): not a success (pipefail sees it), not an error.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except (CliError, SealError, ScenarioError, RoadError, OSError, ValueError, yaml.YAMLError) as exc:
        if os.environ.get("SEAL_DEBUG"):
            raise
        message = " ".join(str(exc).split())  # one line, whatever the exception's own layout (YAML marks, ...)
        print(f"seal: error: {message} (SEAL_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("seal: interrupted (what had finished is kept: run the same command again to go on from there; "
              "`seal train` with --resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
