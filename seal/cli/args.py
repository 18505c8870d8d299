"""Argument types shared by the ``seal`` subcommands: each names the option in its error."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable, Iterator, Sequence
from typing import Any, overload

LAYOUTS = ("highway", "merge", "intersection", "roundabout")


class CliError(Exception):
    """A user error: printed without a traceback, exit status 2."""


class RegistryChoices(Sequence[str]):
    """``choices`` of an option read from the generator registry (`seal.adversaries.base`) on first use: argparse
    only looks at them when it parses that option or prints that command's help, so ``seal --help`` does not
    import the adversaries."""

    def __init__(self, function: str) -> None:
        self.function = function
        self._names: tuple[str, ...] | None = None

    def _load(self) -> tuple[str, ...]:
        if self._names is None:
            registry = importlib.import_module("seal.adversaries.base")
            self._names = tuple(getattr(registry, self.function)())
        return self._names

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> Sequence[str]: ...

    def __getitem__(self, index: int | slice) -> str | Sequence[str]:
        return self._load()[index]

    def __len__(self) -> int:
        return len(self._load())

    def __iter__(self) -> Iterator[str]:
        return iter(self._load())

    def __contains__(self, item: object) -> bool:
        return item in self._load()


def pipeline_choices() -> RegistryChoices:
    """The training pipelines (``noadv`` and each generator the registry marks as a pipeline)."""
    return RegistryChoices("pipeline_names")


def generator_choices() -> RegistryChoices:
    """Every registered generator name."""
    return RegistryChoices("available_generators")


def _number(name: str, convert: Callable[[str], Any], kind: str, ok: Callable[[Any], bool], allowed: str
            ) -> Callable[[str], Any]:
    """Parser for a number option called ``name``: ``convert`` it (else "must be KIND"), then check ``ok`` (else
    "must be ALLOWED")."""

    def parse(text: str) -> Any:
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be {kind}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"{name} must be {allowed}, got {value}")
        return value

    return parse


def positive_int(name: str) -> Callable[[str], int]:
    """Parser for a strictly positive integer option called ``name``."""
    return _number(name, int, "an integer", lambda v: v > 0, "positive")


def non_negative_int(name: str) -> Callable[[str], int]:
    """Parser for an integer option >= 0 called ``name``."""
    return _number(name, int, "an integer", lambda v: v >= 0, ">= 0")


def positive_float(name: str) -> Callable[[str], float]:
    """Parser for a strictly positive float option called ``name``."""
    return _number(name, float, "a number", lambda v: v > 0.0, "positive")


def share(name: str) -> Callable[[str], float]:
    """Parser for a share in [0, 1] called ``name``."""
    return _number(name, float, "a number", lambda v: 0.0 <= v <= 1.0, "in [0, 1]")


def layouts(text: str) -> list[str]:
    """Parser for ``--layouts``: names separated by spaces or commas."""
    names = [t.strip() for t in text.replace(",", " ").split() if t.strip()]
    unknown = [n for n in names if n not in LAYOUTS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"unknown layout(s) {unknown}; choose from {', '.join(LAYOUTS)}")
    return names


SET_HELP = ("override a config key (dotted, value read as YAML), e.g. {example}; repeatable; applied after the "
            "preset, --config and the named options")


def add_plugin_option(p: argparse.ArgumentParser) -> None:
    """``--plugin MODULE_OR_FILE`` (repeatable): imported before the command runs (`seal.core.plugins`), so the
    generators it registers can be named in this command."""
    p.add_argument("--plugin", action="append", default=[], metavar="MODULE_OR_FILE",
                   help="import a Python module (dotted name) or .py file first, e.g. one whose "
                   "@seal.adversaries.base.register('brake') adds a generator (repeatable; worker processes "
                   "load it too)")


def add_set_option(p: argparse.ArgumentParser, example: str) -> None:
    """``--set KEY=VALUE`` (repeatable) for a command whose config is loaded by `seal.core.config.load_config`;
    the strings are kept as given (``args.set``) and parsed by the loader, which names a bad key or value."""
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help=SET_HELP.format(example=example))


def add_fit_job_options(p: argparse.ArgumentParser, job: str, config_keys: str, set_example: str,
                        json_what: str, presets: Sequence[str] = ("quick", "standard")) -> None:
    """The options every preset-driven fitting job shares: DATASET, ``--preset`` (one of ``presets``, the YAML file
    ``experiments/configs/<job>_<preset>.yaml``), ``--config``, ``--seed``, ``--set``, ``--no-progress``, ``--json``."""
    p.add_argument("dataset", help="dataset directory with splits (seal data split)")
    p.add_argument("--preset", choices=tuple(presets), default="standard",
                   help=f"YAML preset experiments/configs/{job}_<preset>.yaml (default standard)")
    p.add_argument("--config", default=None, help=f"YAML config overriding the preset (keys: {config_keys})")
    p.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    add_set_option(p, set_example)
    p.add_argument("--no-progress", action="store_true", help="no progress bars")
    p.add_argument("--json", action="store_true", help=f"print the {json_what} as JSON")


def set_torch_threads(threads: int) -> None:
    """Torch's CPU threads for this process (entry points only: library code leaves the setting alone)."""
    import torch

    torch.set_num_threads(int(threads))


def print_result(result: dict, as_json: bool, width: int = 32) -> None:
    """Print a flat result dict as JSON or as aligned ``key: value`` lines."""
    import json

    if as_json:
        print(json.dumps(result, indent=2, default=str))
    else:
        for key, value in result.items():
            print(f"{key:>{width}}: {value}")
