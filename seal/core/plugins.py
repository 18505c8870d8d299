"""Third-party extensions: generators and ego policies from installed packages (entry points) or local modules
(``--plugin``).

* An installed package declares entry points in the groups `GENERATOR_GROUP` (``seal.generators``) and
  `EGO_GROUP` (``seal.egos``); the entry point's name is the name used on the command line (``--generators
  brake``, ``--ego my-policy``) and its object is imported only when that name is first looked up
  (`entry_point_names`, `load_entry_point`).
* ``--plugin MODULE_OR_FILE`` imports a module by dotted name or a ``.py`` file by path (`load_plugins`); its
  ``@register("name")`` decorators run on import. The plugins are also put into the environment variable
  `PLUGIN_ENV` (``SEAL_PLUGINS``, ``os.pathsep``-separated), which worker processes (env workers of ``seal
  train``, evaluation workers) inherit and load on their first registry lookup (`load_env_plugins`), so a plugin
  given to the parent is known in every process; where a worker may not inherit the environment as it is now
  (a forkserver started earlier), the parent passes `plugin_specs` along with the job.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import sys
from collections.abc import Sequence
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path
from typing import Any

from seal.core.errors import SealError

GENERATOR_GROUP = "seal.generators"
"""Entry-point group of adversary generators: ``name = "package.module"`` (importing it runs
``@register(name)``) or ``name = "package.module:GeneratorClass"`` (registered under the entry point's name)."""
EGO_GROUP = "seal.egos"
"""Entry-point group of ego policies: ``name = "package.module:factory"``; ``factory()`` returns the policy (an
object with ``predict(obs)`` as in SB3, ``act(obs, step)``, or a callable ``obs -> action``)."""
PLUGIN_ENV = "SEAL_PLUGINS"
"""Environment variable listing the ``--plugin`` modules / files, inherited by worker processes."""

_LOADED: dict[str, Any] = {}


class PluginError(SealError):
    """A plugin module or entry point cannot be loaded."""


def entry_point_names(group: str) -> list[str]:
    """Names of the installed entry points of ``group`` (nothing is imported)."""
    return sorted({ep.name for ep in entry_points(group=group)})


def _entry_point(group: str, name: str) -> EntryPoint | None:
    return next(iter(entry_points(group=group, name=name)), None)


def load_entry_point(group: str, name: str) -> Any | None:
    """Import entry point ``name`` of ``group`` and return its object (a module or an attribute); None when no
    installed package declares it. Import failures name the entry point and its package."""
    ep = _entry_point(group, name)
    if ep is None:
        return None
    try:
        return ep.load()
    except Exception as exc:  # a broken third-party package: say which one, whatever it raised
        dist = getattr(ep.dist, "name", "?")
        raise PluginError(
            f"entry point {group}:{name} = {ep.value!r} (package {dist}) cannot be loaded: "
            f"{type(exc).__name__}: {exc}"
        ) from exc


def load_plugin(spec: str) -> Any:
    """Import ``spec``: a ``.py`` file path or a dotted module name; each is imported once per process (a file
    given by relative and by absolute path counts once)."""
    path = Path(spec).expanduser()
    key = str(path.resolve()) if path.is_file() else spec
    if key in _LOADED:
        return _LOADED[key]
    try:
        if spec.endswith(".py") or path.is_file():
            if not path.is_file():
                raise PluginError(f"--plugin {spec}: no such file")
            name = f"seal_plugin_{path.stem}"
            module_spec = importlib.util.spec_from_file_location(name, path.resolve())
            if module_spec is None or module_spec.loader is None:
                raise PluginError(f"--plugin {spec}: not an importable Python file")
            module = importlib.util.module_from_spec(module_spec)
            sys.modules[name] = module
            module_spec.loader.exec_module(module)
        else:
            module = importlib.import_module(spec)
    except PluginError:
        raise
    except Exception as exc:  # the plugin's own import error, with its name
        raise PluginError(f"--plugin {spec}: import failed: {type(exc).__name__}: {exc}") from exc
    _LOADED[key] = module
    return module


def load_plugins(specs: Sequence[str]) -> None:
    """Import every ``--plugin`` and record them in `PLUGIN_ENV` for worker processes. Files are recorded as
    absolute paths, so a worker with another working directory finds them."""
    recorded = [p for p in os.environ.get(PLUGIN_ENV, "").split(os.pathsep) if p]
    for spec in specs:
        load_plugin(spec)
        stored = str(Path(spec).expanduser().resolve()) if Path(spec).expanduser().is_file() else spec
        if stored not in recorded:
            recorded.append(stored)
    if recorded:
        os.environ[PLUGIN_ENV] = os.pathsep.join(recorded)


def plugin_specs() -> list[str]:
    """The ``--plugin`` modules / files of this process (`PLUGIN_ENV`), to hand to workers that do not inherit
    the environment as it is now (SB3's forkserver env workers fork from a server started earlier)."""
    return [spec for spec in os.environ.get(PLUGIN_ENV, "").split(os.pathsep) if spec]


def load_env_plugins() -> None:
    """Import the plugins `PLUGIN_ENV` lists (a worker process inheriting its parent's ``--plugin``)."""
    for spec in plugin_specs():
        load_plugin(spec)
