"""The restricted unpickler's allow-list in detail (issue 24, mutation testing of
`seal.core.importers.safe_pickle`): old protocols and Python 2 names, numpy 1.x module names, persistent ids and
damaged files."""

from __future__ import annotations

import collections
import pickle
from pathlib import Path

import numpy as np
import pytest

from seal.core.importers import ImportFormatError, UnsafePickleError, safe_load


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_protocol_0_plain_containers(tmp_path: Path) -> None:
    obj = {"o": collections.OrderedDict([("b", 1), ("a", 2)]), "fs": frozenset({1, 2}), "c": 1 + 2j,
           "ba": bytearray(b"xy"), "b": b"\x00\xff", "t": (True, 3.5)}
    got = safe_load(_write(tmp_path / "p0.pkl", pickle.dumps(obj, protocol=0)))
    assert type(got["o"]) is dict and list(got["o"].items()) == [("b", 1), ("a", 2)]
    assert got["fs"] == frozenset({1, 2}) and got["c"] == 1 + 2j and got["ba"] == bytearray(b"xy")
    assert got["b"] == b"\x00\xff" and got["t"] == (True, 3.5)


@pytest.mark.parametrize(("data", "expected"), [
    (b"c__builtin__\nlong\n(I5\ntR.", 5),
    (b"c__builtin__\nunicode\n(Vab\ntR.", "ab"),
    (b"c__builtin__\nset\n((lp0\nI1\naI2\natR.", {1, 2}),
])
def test_python_2_names_load_as_their_python_3_types(tmp_path: Path, data: bytes, expected: object) -> None:
    got = safe_load(_write(tmp_path / "py2.pkl", data))
    assert got == expected and type(got) is type(expected)


def test_numpy_1_module_names_load_with_numpy_2(tmp_path: Path) -> None:
    array = np.arange(6, dtype=np.int16).reshape(2, 3)
    data = pickle.dumps({"a": array, "s": np.float32(1.5)}, protocol=2)
    assert b"numpy._core" in data or b"numpy.core" in data
    old = data.replace(b"numpy._core", b"numpy.core")
    got = safe_load(_write(tmp_path / "np1.pkl", old))
    assert got["a"].dtype == np.int16 and np.array_equal(got["a"], array) and got["s"] == np.float32(1.5)


def test_a_persistent_id_is_refused(tmp_path: Path) -> None:
    path = _write(tmp_path / "persid.pkl", b"Pmy-object\n.")
    with pytest.raises(UnsafePickleError, match=r"persid.pkl.*refused persistent id 'my-object'"):
        safe_load(path)


@pytest.mark.parametrize("data", [b"", b"\x80\x04\x95", b"not a pickle at all", b"(I1\nI2\nt"])
def test_a_damaged_file_is_a_format_error_naming_it(tmp_path: Path, data: bytes) -> None:
    path = _write(tmp_path / "bad.pkl", data)
    with pytest.raises(ImportFormatError, match=r"bad.pkl.*not a readable pickle") as info:
        safe_load(path)
    assert not isinstance(info.value, UnsafePickleError)


@pytest.mark.parametrize(("module", "name"), [("builtins", "eval"), ("__builtin__", "getattr"), ("os", "system"),
                                              ("numpy", "load"), ("collections", "Counter")])
def test_everything_outside_the_allow_list_is_refused_by_name(tmp_path: Path, module: str, name: str) -> None:
    path = _write(tmp_path / "x.pkl", f"c{module}\n{name}\n(tR.".encode())
    with pytest.raises(UnsafePickleError, match=rf"refused to load {module}\.{name}"):
        safe_load(path)
