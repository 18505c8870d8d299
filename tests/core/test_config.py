"""`seal.core.config`: layering order, unknown keys, bad values, nested and dict-of-dataclass overrides."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import pytest

from seal.core.config import (
    ConfigError,
    check_keys,
    load_config,
    overrides_field,
    parse_override,
    replace_values,
    to_dict,
)


@dataclass(frozen=True)
class Inner:
    """A nested section."""

    lr: float = 1e-3
    """Learning rate."""
    sizes: tuple[int, ...] = (8, 8)
    """Layer widths."""


@dataclass(frozen=True)
class Entry:
    """A dict entry with a required field."""

    name: str
    """Required."""
    kwargs: dict[str, Any] = field(default_factory=dict)
    """Free options."""


@dataclass(frozen=True)
class Partial:
    """A sub-config given as overrides."""

    a: int = 1
    """An int."""
    b: str = "x"
    """A string."""


@dataclass(frozen=True)
class Cfg:
    """The config under test."""

    seed: int = 0
    """Seed."""
    name: str = "default"
    """Name."""
    model: Path | None = None
    """A model file."""
    mode: Literal["fast", "slow"] = "fast"
    """Mode."""
    limit: int | None = None
    """Optional int."""
    flag: bool = False
    """A flag."""
    inner: Inner = field(default_factory=Inner)
    """Nested section."""
    entries: dict[str, Entry | None] = field(default_factory=lambda: {"e": Entry("one", {"p": 1}), "none": None})
    """Named entries."""
    sub: dict[str, Any] = overrides_field(Partial, a=2)
    """Partial overrides of `Partial`."""


def _yaml(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_defaults_without_layers() -> None:
    assert load_config(Cfg) == Cfg()


def test_layering_order_defaults_preset_file_values_set(tmp_path: Path) -> None:
    preset = _yaml(tmp_path, "preset.yaml", "seed: 1\nname: preset\nlimit: 5\nflag: true\n")
    file = _yaml(tmp_path, "file.yaml", "seed: 2\nname: file\n")
    cfg = load_config(Cfg, preset=preset, file=file, values={"seed": 3, "limit": None}, overrides=["seed=4"])
    assert (cfg.seed, cfg.name, cfg.limit, cfg.flag) == (4, "file", 5, True)  # None values leave the layer below
    assert load_config(Cfg, preset=preset, file=file, values={"seed": 3}).seed == 3
    assert load_config(Cfg, preset=preset, file=file).seed == 2
    assert load_config(Cfg, preset=preset).seed == 1
    assert load_config(Cfg, preset={"seed": 7}, overrides=["seed=8", "seed=9"]).seed == 9  # later --set wins


def test_unknown_key_names_key_file_and_known_keys(tmp_path: Path) -> None:
    bad = _yaml(tmp_path, "bad.yaml", "sed: 1\n")
    with pytest.raises(ConfigError) as err:
        load_config(Cfg, file=bad)
    text = str(err.value)
    assert str(bad) in text and "'sed'" in text and "known:" in text
    assert all(name in text for name in ("seed", "name", "inner", "entries"))
    with pytest.raises(ConfigError, match=r"--set inner.bogus=1.*inner\.bogus.*known: \['lr', 'sizes'\]"):
        load_config(Cfg, overrides=["inner.bogus=1"])
    with pytest.raises(ConfigError, match=r"sub\.c.*known: \['a', 'b'\]"):
        load_config(Cfg, overrides=["sub.c=1"])


def test_unknown_key_one_level_too_high_suggests_the_nested_key() -> None:
    with pytest.raises(ConfigError, match=r"unknown key\(s\) \['lr'\].*did you mean inner\.lr\?"):
        load_config(Cfg, overrides=["lr=0.1"])
    with pytest.raises(ConfigError) as err:  # nothing nested is called so: no guess
        load_config(Cfg, overrides=["nothing=1"])
    assert "did you mean" not in str(err.value)


@pytest.mark.parametrize(
    ("override", "match"),
    [
        ("seed=1.5", r"seed must be int, got 1\.5"),
        ("seed=true", "seed must be int"),
        ("name=3", "name must be str"),
        ("flag=1", "flag must be bool"),
        ("mode=medium", r"mode must be one of \['fast', 'slow'\]"),
        ("inner.lr=fast", "inner.lr must be float"),
        ("inner.sizes=[1, x]", r"inner\.sizes\[1\] must be int"),
        ("limit=[1]", "limit must be int | None"),
        ("sub.a=no", "sub.a must be int"),
        ("inner=3", "inner must be Inner"),
    ],
)
def test_bad_value_names_field_and_expected_type(override: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match) as err:
        load_config(Cfg, overrides=[override])
    assert f"--set {override}" in str(err.value)


def test_values_are_converted_to_their_types(tmp_path: Path) -> None:
    cfg = load_config(Cfg, overrides=["inner.lr=1", "inner.sizes=[4, 4, 4]", "model=runs/m.pt", "limit=null"])
    assert cfg.inner.lr == 1.0 and isinstance(cfg.inner.lr, float)
    assert cfg.inner.sizes == (4, 4, 4) and cfg.model == Path("runs/m.pt") and cfg.limit is None
    assert to_dict(cfg)["inner"] == {"lr": 1.0, "sizes": [4, 4, 4]} and to_dict(cfg)["model"] == "runs/m.pt"


def test_nested_override_keeps_sibling_keys(tmp_path: Path) -> None:
    file = _yaml(tmp_path, "f.yaml", "inner: {sizes: [2]}\n")
    cfg = load_config(Cfg, file=file, overrides=["inner.lr=0.5"])
    assert cfg.inner == Inner(lr=0.5, sizes=(2,))
    cfg = load_config(Cfg, values={"inner.lr": 0.25, "entries.e.kwargs.q": 2})
    assert cfg.inner.lr == 0.25 and cfg.entries["e"] == Entry("one", {"p": 1, "q": 2})


def test_dict_entries_complete_replace_partial_patch() -> None:
    cfg = load_config(Cfg, preset={"entries": {"e": {"name": "two", "kwargs": {"z": 0}}}})
    assert cfg.entries["e"] == Entry("two", {"z": 0})  # names its required field: the whole entry
    cfg = load_config(Cfg, preset={"entries": {"e": {"kwargs": {"z": 0}}, "none": {"name": "new"}}})
    assert cfg.entries["e"] == Entry("one", {"p": 1, "z": 0}) and cfg.entries["none"] == Entry("new")
    assert load_config(Cfg, overrides=["entries.e=null"]).entries["e"] is None
    with pytest.raises(ConfigError, match=r"missing key\(s\) \['name'\]"):
        load_config(Cfg, overrides=["entries.fresh.kwargs.x=1"])


def test_partial_sub_config_is_checked_and_kept_as_given() -> None:
    cfg = load_config(Cfg, preset={"sub": {"b": "y"}})
    assert cfg.sub == {"a": 2, "b": "y"}
    assert load_config(Cfg, overrides=["sub.a=3"]).sub == {"a": 3}


def test_parse_override_and_replace_values() -> None:
    assert parse_override("a.b=[1, 2]") == ("a.b", [1, 2])
    assert parse_override("x= hello ") == ("x", "hello")
    with pytest.raises(ConfigError, match="expected KEY=VALUE"):
        parse_override("novalue")
    cfg = replace_values(Cfg(), seed=5)
    assert cfg.seed == 5 and dataclasses.is_dataclass(cfg)
    with pytest.raises(ConfigError, match="seed must be int"):
        replace_values(Cfg(), seed="five")


def test_check_keys_names_where_and_known() -> None:
    check_keys(Inner, {"lr": 1}, "here")
    with pytest.raises(ConfigError, match=r"here: unknown key\(s\) \['x'\]; known: \['lr', 'sizes'\]"):
        check_keys(Inner, {"x": 1}, "here")


def test_section_of_a_file(tmp_path: Path) -> None:
    path = _yaml(tmp_path, "p.yaml", "train: {seed: 3}\nother: {x: 1}\n")
    assert load_config(Cfg, file=path, section="train").seed == 3
    with pytest.raises(ConfigError, match="no 'missing:' section"):
        load_config(Cfg, file=path, section="missing")


def test_apply_overrides_nested_and_errors() -> None:
    from seal.core.config import apply_overrides

    d = {"eval": {"limit": 10}, "seeds": [0, 1]}
    out = apply_overrides(d, ["eval.limit=5", "seeds=[0]", "eval.generators.cat.stride=10"])
    assert out == {"eval": {"limit": 5, "generators": {"cat": {"stride": 10}}}, "seeds": [0]}
    assert d == {"eval": {"limit": 10}, "seeds": [0, 1]}  # the input is left alone
    with pytest.raises(ConfigError, match="not a mapping"):
        apply_overrides(d, ["seeds.x=1"])


def test_float_fields_read_yaml_exponents_without_a_dot() -> None:
    """PyYAML reads ``1e-3`` as the string "1e-3"; a float field takes it, but not words or non-finite values."""
    import yaml

    from seal.core.config import coerce

    assert coerce(yaml.safe_load("1e-3"), float, "lr", "f.yaml") == 1e-3
    for text in ("fast", "nan", "inf"):
        with pytest.raises(ConfigError, match="lr"):
            coerce(text, float, "lr", "f.yaml")
