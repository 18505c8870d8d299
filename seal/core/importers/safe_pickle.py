"""A restricted unpickler for data files: numpy arrays and plain containers only.

Unpickling runs whatever callables a pickle names, so an untrusted pickle can execute code. `safe_load` only
resolves the names in `ALLOWED` - what numpy needs to rebuild arrays, dtypes and scalars, and the builtin
containers and scalars - and refuses every other class or function with an `UnsafePickleError` that names the
file and the class, before anything is called. ``collections.OrderedDict`` and ``collections.defaultdict``
(ScenarioNet summaries hold a ``defaultdict(int)``) load as plain ``dict``.
"""

from __future__ import annotations

import codecs
import io
import pickle
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from seal.core.importers.errors import ImportFormatError

try:  # numpy >= 2
    from numpy._core import multiarray as _multiarray
    from numpy._core import numeric as _numeric
except ImportError:  # numpy 1.x
    from numpy.core import multiarray as _multiarray  # type: ignore[no-redef]
    from numpy.core import numeric as _numeric  # type: ignore[no-redef]


class UnsafePickleError(ImportFormatError):
    """A pickle names a class or function outside `ALLOWED`."""


def _plain_dict(*_args: Any) -> dict:
    """``defaultdict(factory)`` / ``OrderedDict()`` replacement: an empty plain dict (items are set afterwards)."""
    return {}


_NUMPY: dict[str, Callable[..., Any]] = {
    "multiarray._reconstruct": _multiarray._reconstruct,
    "multiarray.scalar": _multiarray.scalar,
    "numeric._frombuffer": _numeric._frombuffer,  # type: ignore[attr-defined]  # private, absent from numpy's stubs
}
ALLOWED: dict[tuple[str, str], Callable[..., Any]] = {
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
    ("_codecs", "encode"): codecs.encode,  # bytes in protocol 0-2 pickles
    ("collections", "OrderedDict"): _plain_dict,
    ("collections", "defaultdict"): _plain_dict,
    **{("builtins", name): getattr(__import__("builtins"), name) for name in (
        "dict", "list", "tuple", "set", "frozenset", "str", "bytes", "bytearray", "int", "float", "complex", "bool",
    )},
    # numpy 1.x pickles say numpy.core, numpy 2.x numpy._core; both load with the installed numpy.
    **{(f"{pkg}.{name.split('.')[0]}", name.split(".")[1]): fn for pkg in ("numpy.core", "numpy._core")
       for name, fn in _NUMPY.items()},
}
"""(module, name) -> the callable unpickling may use."""
_PY2_NAMES = {("__builtin__", "long"): ("builtins", "int"), ("__builtin__", "unicode"): ("builtins", "str")}


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, file: io.BufferedIOBase, path: Path,
                 extra: Mapping[tuple[str, str], Callable[..., Any]] | None = None) -> None:
        super().__init__(file)
        self._path = path
        self._extra = dict(extra or {})

    def find_class(self, module: str, name: str) -> Any:
        key = _PY2_NAMES.get((module, name), ("builtins" if module == "__builtin__" else module, name))
        if key in ALLOWED:
            return ALLOWED[key]
        if key in self._extra:
            return self._extra[key]
        raise UnsafePickleError(
            self._path, "pickle",
            f"refused to load {module}.{name}: only numpy arrays and plain containers (dict, list, tuple, set, str, "
            "numbers) are allowed in a data file",
        )

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(self._path, "pickle", f"refused persistent id {pid!r}: not a plain data pickle")


def safe_load(path: str | Path, extra: Mapping[tuple[str, str], Callable[..., Any]] | None = None) -> Any:
    """Unpickle ``path`` with only `ALLOWED` names resolvable, plus ``extra`` ((module, name) -> the callable used
    instead: a caller maps the classes of a known file format to inert stand-ins that only keep their state).

    Raises:
        UnsafePickleError: the pickle names anything else (nothing of it has been called).
        ImportFormatError: the file is not a readable pickle.
    """
    path = Path(path)
    try:
        with path.open("rb") as f:
            return _RestrictedUnpickler(f, path, extra).load()
    except ImportFormatError:
        raise
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError, KeyError,
            MemoryError, UnicodeDecodeError) as exc:
        raise ImportFormatError(path, "", f"not a readable pickle ({type(exc).__name__}: {exc})") from None
