"""One loader for every typed config: frozen dataclasses layered defaults < preset < file < values < ``--set``.

A config is a frozen dataclass whose fields carry a docstring each (the string literal under the field, as in
CleanRL's ``Args``) and a default, so ``Cls()`` is the default config. `load_config` merges layers of plain
mappings onto those defaults, checks every key and value against the field types as it goes (so an error names the
layer it came from) and builds the dataclass (nested dataclasses included, whose ``__post_init__`` checks run)::

    from seal.core.config import load_config

    cfg = load_config(GooseFitConfig, preset="experiments/configs/goose_quick.yaml", file="mine.yaml",
                      values={"seed": 3}, overrides=["spec.max_updates=3", "net_arch=[64, 64]"])

Layers, lowest first: the dataclass defaults; ``preset`` and ``file`` (a YAML path, or a mapping already read);
``values`` (dotted keys -> values, None values skipped: what named command-line options give); ``overrides``
(``"key.sub=value"`` strings, the value parsed as a YAML scalar / flow: ``--set`` on the command line).

Supported field types: ``int``, ``float`` (an int is accepted and converted), ``str``, ``bool``, `pathlib.Path`
(from a string), ``Literal[...]``, ``X | None``, ``tuple[X, ...]`` (from a YAML list), nested dataclasses, and
``dict[str, X]`` / ``Mapping`` / ``Any`` (merged key by key; a dict entry that is ``None`` or a complete mapping of a
dataclass ``X`` -- every field without a default given -- replaces the old entry, a partial one patches it).

`to_dict` turns a config back into plain YAML-safe data (tuples -> lists, paths -> strings); `check_keys` is the one
"unknown key" check for code that builds a dataclass from a mapping itself.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import yaml

T = TypeVar("T")

Layer = str | Path | Mapping[str, Any] | None
"""A config layer: a YAML file path, a mapping already read, or None (no layer)."""


class ConfigError(ValueError):
    """A config that does not fit its dataclass: an unknown key or a value of the wrong type."""


def parse_override(text: str) -> tuple[str, Any]:
    """``"a.b=VALUE"`` -> ``("a.b", VALUE parsed as YAML)``, e.g. ``"net_arch=[64, 64]"`` ->
    ``("net_arch", [64, 64])``."""
    key, sep, value = text.partition("=")
    if not (sep and key.strip()):
        raise ConfigError(f"--set {text!r}: expected KEY=VALUE, e.g. hyperparams.td3.batch_size=128")
    try:
        return key.strip(), yaml.safe_load(value)
    except yaml.YAMLError as exc:
        raise ConfigError(f"--set {text!r}: the value is not YAML ({exc})") from None


def dotted_to_nested(flat: Mapping[str, Any]) -> dict[str, Any]:
    """``{"a.b": 1, "c": 2}`` -> ``{"a": {"b": 1}, "c": 2}``."""
    nested: dict[str, Any] = {}
    for key, value in flat.items():
        parts = key.split(".")
        node = nested
        for part in parts[:-1]:
            child = node.get(part)
            if not isinstance(child, dict):
                child = node[part] = {}
            node = child
        node[parts[-1]] = value
    return nested


def apply_overrides(data: Mapping[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    """A copy of the plain mapping ``data`` with each ``"a.b=VALUE"`` of ``overrides`` set (nested mappings created
    where missing), for configs that stay plain mappings (a ``seal run`` preset, the eval settings); the caller
    checks the result's keys and types."""
    out = _deep_copy_mappings(data)
    for text in overrides:
        key, value = parse_override(text)
        node = out
        parts = key.split(".")
        for part in parts[:-1]:
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            elif not isinstance(child, dict):
                raise ConfigError(f"--set {text!r}: {part!r} holds {child!r}, not a mapping of keys")
            node = child
        node[parts[-1]] = value
    return out


def _deep_copy_mappings(data: Mapping[str, Any]) -> dict[str, Any]:
    return {k: _deep_copy_mappings(v) if isinstance(v, Mapping) else v for k, v in data.items()}


def safe_load_file(path: str | Path) -> Any:
    """The YAML document in ``path``; a syntax error becomes a `ConfigError` naming the file, line and column."""
    path = Path(path)
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}, line {mark.line + 1}, column {mark.column + 1}" if mark is not None else str(path)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{where}: not valid YAML ({problem})") from None


def read_yaml(path: str | Path, section: str | None = None) -> dict[str, Any]:
    """The mapping in the YAML file ``path`` (or its ``section:`` mapping); an error names the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such config file")
    loaded = safe_load_file(path) or {}
    if not isinstance(loaded, dict):
        raise ConfigError(f"{path}: expected a mapping of options")
    if section is None:
        return loaded
    if not isinstance(loaded.get(section), dict):
        raise ConfigError(f"{path}: no '{section}:' section (a mapping)")
    return dict(loaded[section])


def field_types(cls: type) -> dict[str, Any]:
    """Field name -> resolved type annotation of dataclass ``cls`` (Any where it cannot be resolved)."""
    try:
        hints = typing.get_type_hints(cls)
    except (NameError, TypeError):
        hints = {}
    return {f.name: hints.get(f.name, Any) for f in dataclasses.fields(cls)}


def overrides_field(of: type, **defaults: Any) -> Any:
    """A dataclass field holding a partial mapping of the dataclass ``of``'s fields (keys and values checked
    against ``of`` by the loader, kept as plain data): for sub-configs whose missing fields are filled in later
    (e.g. from the data, or the run's seed). ``defaults``: the field's default mapping."""
    return dataclasses.field(default_factory=lambda: dict(defaults), metadata={"overrides_of": of})


def _overrides_of(cls: type) -> dict[str, type]:
    return {f.name: f.metadata["overrides_of"] for f in dataclasses.fields(cls) if "overrides_of" in f.metadata}


def check_keys(cls: type, d: Mapping[str, Any], where: str) -> None:
    """Raise `ConfigError` naming ``where``, each key of ``d`` that is not a field of ``cls`` and the known keys."""
    known = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(d) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {unknown}; known: {sorted(known)}")


def _describe(tp: Any) -> str:
    return getattr(tp, "__name__", None) or str(tp).replace("typing.", "")


def _is_dataclass_type(tp: Any) -> bool:
    return isinstance(tp, type) and dataclasses.is_dataclass(tp)


def _union_args(tp: Any) -> tuple[Any, ...] | None:
    origin = typing.get_origin(tp)
    return typing.get_args(tp) if origin in (typing.Union, types.UnionType) else None


def _dataclass_in(tp: Any) -> type | None:
    """The dataclass of ``tp`` = ``D`` or ``D | None``, else None."""
    if _is_dataclass_type(tp):
        return typing.cast(type, tp)
    args = _union_args(tp)
    if args is not None:
        found = [a for a in args if _is_dataclass_type(a)]
        return found[0] if len(found) == 1 else None
    return None


def _mapping_value_type(tp: Any) -> Any | None:
    """The value type of a mapping type (``dict[str, X]`` -> X, ``Mapping``/``dict`` -> Any), else None."""
    args = _union_args(tp)
    if args is not None:
        found = [v for v in (_mapping_value_type(a) for a in args if a is not type(None)) if v is not None]
        return found[0] if found else None
    origin = typing.get_origin(tp) or tp
    if origin in (dict, Mapping) or (isinstance(origin, type) and issubclass(origin, Mapping)):
        args = typing.get_args(tp)
        return args[1] if len(args) == 2 else Any
    return None


def coerce(value: Any, tp: Any, key: str, where: str) -> Any:
    """``value`` checked against type ``tp`` (converted where lossless: int -> float, str -> Path, list -> tuple);
    a mismatch raises `ConfigError` naming ``where``, the field ``key`` and the expected type."""
    if tp is Any:
        return value
    args = _union_args(tp)
    if args is not None:
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return coerce(value, arg, key, where)
            except ConfigError:
                continue
        raise _bad(value, tp, key, where)
    origin = typing.get_origin(tp)
    if origin is typing.Literal:
        if value not in typing.get_args(tp):
            raise ConfigError(f"{where}: {key} must be one of {list(typing.get_args(tp))}, got {value!r}")
        return value
    if origin is tuple:
        return _coerce_tuple(value, tp, key, where)
    if _mapping_value_type(tp) is not None:
        if not isinstance(value, Mapping):
            raise _bad(value, tp, key, where)
        inner = _mapping_value_type(tp)
        return {k: _coerce_entry(v, inner, f"{key}.{k}", where) for k, v in value.items()}
    if _is_dataclass_type(tp):
        if isinstance(value, tp):
            return to_dict(value)
        if not isinstance(value, Mapping):
            raise _bad(value, tp, key, where)
        return _apply(tp, defaults_of(tp), value, where, f"{key}.")
    return _coerce_scalar(value, tp, key, where)


def _coerce_entry(value: Any, tp: Any, key: str, where: str) -> Any:
    cls = _dataclass_in(tp)
    if cls is not None and isinstance(value, Mapping):
        return _apply(cls, {}, value, where, f"{key}.")
    return coerce(value, tp, key, where)


def _coerce_tuple(value: Any, tp: Any, key: str, where: str) -> tuple[Any, ...]:
    if not isinstance(value, list | tuple):
        raise _bad(value, tp, key, where)
    args = typing.get_args(tp)
    if len(args) == 2 and args[1] is Ellipsis:
        return tuple(coerce(v, args[0], f"{key}[{i}]", where) for i, v in enumerate(value))
    if len(args) != len(value):
        raise _bad(value, tp, key, where)
    return tuple(coerce(v, a, f"{key}[{i}]", where) for i, (v, a) in enumerate(zip(value, args, strict=True)))


def _coerce_scalar(value: Any, tp: Any, key: str, where: str) -> Any:
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, int | float) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str):  # PyYAML reads `1e-3` (no dot) as a string; a finite number in it is meant
            try:
                number = float(value)
            except ValueError:
                number = math.nan
            if math.isfinite(number):
                return number
    elif tp is str:
        if isinstance(value, str):
            return value
    elif tp is Path:
        if isinstance(value, str | Path):
            return Path(value)
    elif isinstance(tp, type) and isinstance(value, tp):
        return value
    raise _bad(value, tp, key, where)


def _bad(value: Any, tp: Any, key: str, where: str) -> ConfigError:
    return ConfigError(f"{where}: {key} must be {_describe(tp)}, got {value!r} ({type(value).__name__})")


def defaults_of(cls: type) -> dict[str, Any]:
    """Plain data of the field defaults of ``cls`` (fields without one left out), without running its
    ``__post_init__`` (a config may only be valid once a layer has set something, e.g. a candidate source)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = to_dict(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = to_dict(f.default_factory())
    return out


def _required(cls: type) -> set[str]:
    return {f.name for f in dataclasses.fields(cls)
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING}


def _apply(cls: type, base: Mapping[str, Any], layer: Mapping[str, Any], where: str,
           prefix: str = "") -> dict[str, Any]:
    """``base`` (plain data of a ``cls``) updated with ``layer``: every key checked against ``cls``' fields and every
    value against its field type; errors name ``where`` and the dotted key."""
    if not isinstance(layer, Mapping):
        raise ConfigError(f"{where}: {prefix.rstrip('.') or 'the config'} must be a mapping, got {layer!r}")
    types_ = field_types(cls)
    unknown = sorted(set(layer) - set(types_))
    if unknown:
        hints = [hint for k in unknown if (hint := _nested_hint(cls, k, prefix))]
        raise ConfigError(f"{where}: unknown key(s) {[prefix + k for k in unknown]}; known: {sorted(types_)}"
                          + (f" (under {prefix.rstrip('.')})" if prefix else "")
                          + (f"; did you mean {', '.join(hints)}?" if hints else ""))
    out = dict(base)
    partial = _overrides_of(cls)
    for name, value in layer.items():
        tp, key = types_[name], prefix + name
        sub = _dataclass_in(tp)
        if name in partial:
            _apply(partial[name], {}, value, where, key + ".")  # checked; kept as given (fingerprints use it)
            out[name] = {**(out.get(name) or {}), **to_dict(value)}
        elif sub is not None and isinstance(value, Mapping) and isinstance(out.get(name), Mapping):
            out[name] = _apply(sub, out[name], value, where, key + ".")
        elif _mapping_value_type(tp) is not None and isinstance(value, Mapping) and isinstance(out.get(name), Mapping):
            out[name] = _merge_mapping(out[name], value, _mapping_value_type(tp), key, where)
        else:
            out[name] = coerce(value, tp, key, where)
    return out


def _nested_hint(cls: type, name: str, prefix: str, depth: int = 3) -> str:
    """The dotted keys (comma-separated, '' if none) of the fields called ``name`` in the dataclasses nested below
    ``cls`` (up to ``depth`` levels): a key given one level too high, e.g. ``hyperparams.noise_bound`` for
    ``hyperparams.reskill.noise_bound``."""
    found: list[str] = []

    def walk(c: type, path: str, left: int) -> None:
        nested = {**{n: sub for n, tp in field_types(c).items() if (sub := _dataclass_in(tp)) is not None},
                  **_overrides_of(c)}
        for child, sub in nested.items():
            if name in field_types(sub):
                found.append(f"{path}{child}.{name}")
            elif left > 1:
                walk(sub, f"{path}{child}.", left - 1)

    walk(cls, prefix, depth)
    return ", ".join(found)


def _merge_mapping(base: Mapping[str, Any], layer: Mapping[str, Any], inner: Any, key: str,
                   where: str) -> dict[str, Any]:
    """Key-by-key merge of a ``dict[str, inner]`` field (see the module docstring for when an entry is replaced)."""
    out = dict(base)
    cls = _dataclass_in(inner)
    for k, v in layer.items():
        old = out.get(k)
        if cls is not None and isinstance(v, Mapping):
            patch = isinstance(old, Mapping) and not _required(cls) <= set(v)
            out[k] = _apply(cls, old if patch and isinstance(old, Mapping) else {}, v, where, f"{key}.{k}.")
        elif inner is Any and isinstance(v, Mapping) and isinstance(old, Mapping):
            out[k] = _merge_mapping(old, v, Any, f"{key}.{k}", where)
        else:
            out[k] = coerce(v, inner, f"{key}.{k}", where)
    return out


def build(cls: type[T], data: Mapping[str, Any], where: str = "config") -> T:
    """An instance of ``cls`` from checked plain data (nested dataclasses built, lists -> tuples, str -> Path)."""
    kwargs: dict[str, Any] = {}
    types_ = field_types(typing.cast(type, cls))
    missing = sorted(_required(typing.cast(type, cls)) - set(data))
    if missing:
        raise ConfigError(f"{where}: missing key(s) {missing} of {cls.__name__}")
    for name, tp in types_.items():
        if name in data:
            kwargs[name] = _build_value(data[name], tp, name, where)
    return cls(**kwargs)


def _build_value(value: Any, tp: Any, key: str, where: str) -> Any:
    sub = _dataclass_in(tp)
    if sub is not None and isinstance(value, Mapping):
        return build(sub, value, f"{where}: {key}")
    inner = _mapping_value_type(tp)
    if inner is not None and isinstance(value, Mapping) and _dataclass_in(inner) is not None:
        return {k: _build_value(v, inner, f"{key}.{k}", where) for k, v in value.items()}
    return coerce(value, tp, key, where)


def load_config(cls: type[T], preset: Layer = None, file: Layer = None, overrides: Sequence[str] = (), *,
                values: Mapping[str, Any] | None = None, section: str | None = None) -> T:
    """The config ``cls`` layered defaults < ``preset`` < ``file`` < ``values`` < ``overrides`` (module docstring).

    ``section``: read that top-level mapping of the YAML files (e.g. ``"train"``) instead of the whole file.
    Raises `ConfigError` on an unknown key (naming the key, the file and the known keys) or a value of the wrong
    type (naming the field and the expected type)."""
    return build(cls, resolve_layers(cls, preset, file, overrides, values=values, section=section))


def resolve_layers(cls: type, preset: Layer = None, file: Layer = None, overrides: Sequence[str] = (), *,
                   values: Mapping[str, Any] | None = None, section: str | None = None) -> dict[str, Any]:
    """The checked plain data `load_config` builds its dataclass from."""
    data = defaults_of(cls)
    for label, layer in (("preset", preset), ("config file", file)):
        if layer is None:
            continue
        if isinstance(layer, Mapping):
            data = _apply(cls, data, layer, f"{label} mapping")
        else:
            data = _apply(cls, data, read_yaml(layer, section), f"{layer}" + (f": {section}" if section else ""))
    given = {k: v for k, v in (values or {}).items() if v is not None}
    if given:
        data = _apply(cls, data, dotted_to_nested(given), "options")
    for text in overrides:
        key, value = parse_override(text)
        data = _apply(cls, data, dotted_to_nested({key: value}), f"--set {text}")
    return data


def replace_values(config: T, **changes: Any) -> T:
    """A copy of the frozen config with top-level fields changed (type-checked like a layer)."""
    cls = type(config)
    return build(cls, _apply(cls, to_dict(config), changes, "replace_values"))


def to_dict(value: Any) -> Any:
    """Plain YAML-safe data of a config (dataclasses -> dicts, tuples -> lists, paths -> strings)."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_dict(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, Mapping):
        return {k: to_dict(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_dict(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value
