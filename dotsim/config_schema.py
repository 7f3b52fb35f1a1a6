"""Config schema: TOML tables declared as frozen dataclasses whose fields say what they allow.

A configuration is declared once, as dataclasses whose fields are made with `setting` (default, help
text, allowed values). From that declaration this module validates a TOML file (`read_toml`,
`from_dict`), writes the resolved values back (`to_dict`) and writes its reference page
(`reference_markdown`). generator/config.py (docs/CONFIG.md) and trainer/config.py
(docs/TRAIN_CONFIG.md) are two such declarations.

The root dataclass holds the tables (fields whose type is a dataclass, written `[name]` in TOML) and
top-level keys (fields made with `setting`); any other field (the generator's `source`) is not a key.
A setting's type is bool, int, float or str; `IntRange` / `FloatRange` is a *range* `[low, high]`
with low <= high; `tuple[T, ...]` is a list of T; a fixed `tuple[T1, T2]` is a pair such as
(offset, width) or (cx, cy); lists and pairs may nest. Bounds apply to every number in a value, choices
to every string. Errors name the file, the key, the value and what is allowed, and suggest the
closest key or choice ("did you mean").

The same declarations serve records that are not read from TOML: a dataclass derived from
`Checked` checks its settings on construction (the generator's tables, the SceneSpec's records,
dotsim.rig.geometry's Rig), `record_from_dict` (`Checked.from_dict`) reads one from a JSON mapping in
which every field is given, and `check` is the one check of a loose value. All of them raise ConfigError
(a ValueError), one line naming the field and the value.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import numbers
import os
import tomllib
import types
import typing
from dataclasses import field
from pathlib import Path
from typing import Annotated, Any

_RANGE = "range"
IntRange = Annotated[tuple[int, int], _RANGE]  # [low, high] with low <= high
FloatRange = Annotated[tuple[float, float], _RANGE]
# setting(REQUIRED, ...): a field with no default (a record that is always given whole, such as a spec's).
REQUIRED: Any = dataclasses.MISSING


class ConfigError(ValueError):
    """A configuration problem, naming the file, the key, the value and what is allowed."""


def setting(default: Any, help: str, *, low: float | None = None, high: float | None = None,
            low_open: bool = False, high_open: bool = False, choices: tuple | None = None,
            path: bool = False, min_items: int = 0) -> Any:
    """A dataclass field with its help text and the values it allows.

    Parameters
    ----------
    default : the value when the key is left out (lists are given as tuples or lists).
    help : one line for docs and errors: what the value means, with its unit.
    low, high : bounds of every number in the value; `low_open` / `high_open` exclude the bound.
    choices : the strings allowed (for a string or every entry of a list of strings).
    path : a path, resolved against the config file's directory.
    min_items : fewest entries of a list (1 for a string: not empty).
    """
    return field(default=_tuples(default), metadata=_rule(help, low, high, low_open, high_open, choices,
                                                          path, min_items))


def bounds_of(owner: type, name: str) -> dict:
    """The bounds of `owner`'s setting `name` (low, high and whether each is open), for another field
    that must allow exactly the same numbers: `setting(default, help, **bounds_of(Rig, "max_depth"))`.

    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Lamp(Checked):
    ...     power: float = setting(1.0, "W", low=0.0, high=10.0, low_open=True)
    >>> bounds_of(Lamp, "power")
    {'low': 0.0, 'high': 10.0, 'low_open': True, 'high_open': False}
    """
    rule = owner.__dataclass_fields__[name].metadata
    return {key: rule[key] for key in ("low", "high", "low_open", "high_open")}


def _rule(help: str = "", low: float | None = None, high: float | None = None, low_open: bool = False,
          high_open: bool = False, choices: tuple | None = None, path: bool = False,
          min_items: int = 0) -> dict:
    return {"help": help, "low": low, "high": high, "low_open": low_open, "high_open": high_open,
            "choices": choices, "path": path, "min_items": min_items}


def _tuples(value: Any) -> Any:
    """Lists (from TOML, JSON or a default) as tuples, so configs compare and hash alike."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list | tuple) else value


def _json(value: Any) -> Any:
    return [_json(v) for v in value] if isinstance(value, list | tuple) else value


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


def _keys(schema: type) -> dict[str, dataclasses.Field]:
    """The fields of `schema` that are config keys: tables and settings, in declaration order."""
    return {f.name: f for f in dataclasses.fields(schema) if _is_table(schema, f) or "help" in f.metadata}


def _is_table(schema: type, f: dataclasses.Field) -> bool:
    return dataclasses.is_dataclass(_hints(schema)[f.name])


def tables(schema: type) -> dict[str, type]:
    """Name -> dataclass of every table of a root schema, in declaration order."""
    return {name: _hints(schema)[name] for name, f in _keys(schema).items() if _is_table(schema, f)}


def _is_range(hint: Any) -> bool:
    return typing.get_origin(hint) is Annotated and _RANGE in hint.__metadata__


def _range_items(hint: Any) -> str:
    return "integers" if typing.get_args(hint.__origin__)[0] is int else "numbers"


def _is_list(hint: Any) -> bool:
    args = typing.get_args(hint)
    return len(args) == 2 and args[1] is Ellipsis


def _optional_of(hint: Any) -> Any:
    """T of a hint `T | None`, else None."""
    if typing.get_origin(hint) not in (typing.Union, types.UnionType):
        return None
    others = [a for a in typing.get_args(hint) if a is not type(None)]
    return others[0] if len(others) == 1 else None


class _Invalid(Exception):
    """Why a value is not allowed (turned into a ConfigError naming file, key and value)."""


def _is_number(value: Any) -> bool:
    # Booleans are ints: never accept them as numbers. numbers.Real also takes numpy's scalars.
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _in_bounds(x: float, rule: dict) -> bool:
    low, high = rule["low"], rule["high"]
    if not math.isfinite(x):
        return False
    if low is not None and (x < low or (rule["low_open"] and x == low)):
        return False
    return high is None or (x < high if rule["high_open"] else x <= high)


def _did_you_mean(value: str, valid: typing.Iterable[str], cutoff: float = 0.6) -> str:
    close = difflib.get_close_matches(value, list(valid), n=1, cutoff=cutoff)
    return f' (did you mean "{close[0]}"?)' if close else ""


_SCALARS = {bool: lambda v: isinstance(v, bool),
            int: lambda v: _is_number(v) and isinstance(v, numbers.Integral),
            float: _is_number, str: lambda v: isinstance(v, str)}


def _convert(hint: Any, value: Any, rule: dict, top: bool = True) -> Any:
    """`value` as the type `hint` describes (lists become tuples), or raise _Invalid saying why."""
    if hint in _SCALARS:
        if not _SCALARS[hint](value):
            raise _Invalid(f"wrong type ({type(value).__name__})")
        if hint in (int, float) and not _in_bounds(value, rule):
            raise _Invalid("out of range" if math.isfinite(value) else "not finite")
        if rule["choices"] and value not in rule["choices"]:  # of numbers too ([model] stride: 1 or 2)
            raise _Invalid("not a valid choice" + (_did_you_mean(value, rule["choices"]) if hint is str
                                                   else ""))
        if hint is str and top and len(value) < rule["min_items"]:
            raise _Invalid("empty")
        return hint(value)
    if (inner := _optional_of(hint)) is not None:
        return None if value is None else _convert(inner, value, rule, top)
    if _is_range(hint):
        low, high = _convert(hint.__origin__, value, rule, top=False)
        if low > high:
            raise _Invalid("low > high")
        return low, high
    args = typing.get_args(hint)
    if _is_list(hint):
        if not isinstance(value, list | tuple):
            raise _Invalid(f"wrong type ({type(value).__name__}; expected an array)")
        if top and len(value) < rule["min_items"]:
            n = rule["min_items"]
            raise _Invalid(f"needs at least {n} {'entry' if n == 1 else 'entries'}")
        items = []
        for item in value:
            try:
                items.append(_convert(args[0], item, rule, top=False))
            except _Invalid as exc:
                raise _Invalid(f"entry {_json(item)!r}: {exc}") from None
        return tuple(items)
    if not isinstance(value, list | tuple) or len(value) != len(args):
        raise _Invalid(f"wrong type (expected a {_count(len(args))}-element array)")
    return tuple(_convert(a, v, rule, top=False) for a, v in zip(args, value, strict=True))


def _count(n: int) -> str:
    return {2: "two", 3: "three", 4: "four"}.get(n, str(n))


def _fmt(x: Any) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def toml_text(value: Any) -> str:
    """A value as it is written in TOML (for docs and messages)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(toml_text(v) for v in value) + "]"
    return _fmt(value)


def _bounds(rule: dict) -> str:
    text = "x"
    if rule["low"] is not None:
        text = f"{_fmt(rule['low'])} {'<' if rule['low_open'] else '<='} x"
    if rule["high"] is not None:
        text += f" {'<' if rule['high_open'] else '<='} {_fmt(rule['high'])}"
    return "" if text == "x" else text


def _noun(hint: Any, plural: bool, float_word: str = "number") -> str:
    """What a value of type `hint` is called: "integer", "lists of numbers", "[integer, integer] pairs",
    "list of 3 numbers" (a vector), "list of 3 lists of 3 numbers" (a matrix)."""
    s = "s" if plural else ""
    if hint in _SCALARS:
        return {bool: "boolean", int: "integer", float: float_word, str: "string"}[hint] + s
    if _is_list(hint):
        return f"list{s} of {_noun(typing.get_args(hint)[0], True, float_word)}"
    args = typing.get_args(hint)
    if len(args) > 2 and len(set(args)) == 1:
        return f"list{s} of {len(args)} {_noun(args[0], True, float_word)}"
    inner = ", ".join(_noun(a, False, float_word) for a in args)
    return f"[{inner}] {'pair' if len(args) == 2 else 'array'}{s}"


def _allowed(hint: Any, rule: dict) -> str:
    """What a setting allows, in words (used by errors and docs)."""
    choices = ", ".join(f'"{c}"' for c in rule["choices"] or ())
    bounds = _bounds(rule)
    each = f", each {bounds}" if bounds else ""
    if (inner := _optional_of(hint)) is not None:
        return f"{_allowed(inner, rule)}, or null"
    if hint is bool:
        return "true or false"
    if hint is str:
        if rule["path"]:
            return "a path (string; relative to the config file)"
        return f"one of {choices}" if choices else "a non-empty string" if rule["min_items"] else "a string"
    if hint in (int, float):
        if rule["choices"]:
            return "one of " + ", ".join(_fmt(c) for c in rule["choices"])
        text = "an integer" if hint is int else "a number"
        return f"{text}, {bounds}" if bounds else text
    if _is_range(hint):
        return f"[low, high], two {_range_items(hint)} with low <= high{each}"
    if not _is_list(hint):
        return f"a {_noun(hint, False)}{each}"
    n = rule["min_items"]
    size = "a list of" if n == 0 else "a non-empty list of" if n == 1 else f"a list of at least {n}"
    if choices:
        return f"{size} {choices}"
    return f"{size} {_noun(typing.get_args(hint)[0], True)}{each}"


def _type_name(hint: Any) -> str:
    if _is_range(hint):
        return "range of " + _range_items(hint).replace("numbers", "floats")
    return _noun(hint, False, float_word="float")


def value_error(where: str, value: Any, problem: str, allowed: str) -> ConfigError:
    """The one shape of a config error: `where = value: problem; allowed: ...`."""
    return ConfigError(f"{where} = {_json(value)!r}: {problem}; allowed: {allowed}")


def _unknown_key_error(where: str, key: str, valid: list[str]) -> ConfigError:
    # A table is only suggested for a table and a key for a key: "[scene]" is no misspelt "seed".
    alike = [v for v in valid if v.startswith("[") == key.startswith("[")]
    return ConfigError(f"{where}unknown key \"{key}\"{_did_you_mean(key, alike, cutoff=0.5)}; "
                       f"valid keys: {', '.join(valid)}")


def _checked(hint: Any, value: Any, rule: dict, where: str) -> Any:
    """The one check of a value: `value` as type `hint` if `rule` allows it, else ConfigError."""
    try:
        return _convert(hint, value, rule)
    except _Invalid as exc:
        raise value_error(where, value, str(exc), _allowed(hint, rule)) from None


def check(value: Any, hint: Any, where: str, **rule: Any) -> Any:
    """`value` as type `hint` (lists as tuples, integers as floats where a float is asked for) if the
    rule allows it (`setting`'s keywords: low, high, low_open, high_open, choices, min_items); else
    ConfigError `where = value: problem; allowed: ...`. For a value that is no field of a record."""
    return _checked(hint, value, _rule(**rule), where)


def check_field(owner: type, name: str, value: Any, where: str) -> Any:
    """`value` checked as the setting `name` of dataclass `owner` declares it (see `check`)."""
    return _checked(_hints(owner)[name], value, owner.__dataclass_fields__[name].metadata, where)


@functools.cache
def _settings(cls: type) -> tuple[tuple[str, Any, Any], ...]:
    """(name, type hint, rule) of each field of `cls` made with `setting`."""
    return tuple((f.name, _hints(cls)[f.name], f.metadata) for f in dataclasses.fields(cls)
                 if "help" in f.metadata)


class Checked:
    """Base of a frozen dataclass whose `setting` fields are checked on construction (and normalised:
    lists become tuples, integers floats where a float is declared), so a record made in code is held
    to the bounds a file is. ConfigError names Class.field and the value."""

    def __post_init__(self) -> None:
        cls = type(self)
        for name, hint, rule in _settings(cls):
            value = _checked(hint, getattr(self, name), rule, f"{cls.__name__}.{name}")
            object.__setattr__(self, name, value)

    def to_dict(self) -> dict:
        """JSON-safe dict of the fields (lists for tuples), in declaration order."""
        return {f.name: _json(getattr(self, f.name)) for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, data: Any, where: str) -> Any:
        """The record of a mapping that gives every field (`record_from_dict`)."""
        return record_from_dict(cls, data, where)


def record_from_dict(cls: type, data: Any, where: str, optional: tuple[str, ...] = (),
                     **readers: typing.Callable[[Any, str], Any]) -> Any:
    """A `Checked` record from a mapping (JSON) that gives every field but `optional` and no other
    key. Settings are checked with errors naming `where.key`; `readers` make the fields that are
    records themselves: reader(value, where) (nested mappings, with their own errors).
    """
    names = [f.name for f in dataclasses.fields(cls)]
    if not isinstance(data, dict):
        raise value_error(where, data, "not a mapping", f"a mapping with the keys {', '.join(names)}")
    if missing := [name for name in names if name not in data and name not in optional]:
        raise ConfigError(f"{where}.{missing[0]} is missing")
    if unknown := [key for key in data if key not in names]:
        raise _unknown_key_error(f"{where}: ", str(unknown[0]), names)
    values = {key: readers[key](value, f"{where}.{key}") if key in readers
              else check_field(cls, key, value, f"{where}.{key}") for key, value in data.items()}
    return cls(**values)


def _setting(owner: type, f: dataclasses.Field, value: Any, where: str, base_dir: Path) -> Any:
    value = check_field(owner, f.name, value, where)
    if f.metadata["path"] and value:
        value = str((base_dir / value).resolve())
    return value


def _table(cls: type, given: dict, where: str, base_dir: Path) -> Any:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    values = {}
    for key, value in given.items():
        if key not in fields:
            raise _unknown_key_error(f"{where} ", key, list(fields))
        values[key] = _setting(cls, fields[key], value, f"{where} {key}", base_dir)
    return cls(**values)


def from_dict(schema: type, data: dict, origin: str, base_dir: Path | None = None, **fixed: Any) -> Any:
    """Validate a nested dict (as read from TOML) into `schema`; missing keys take their defaults.

    Paths are made absolute against `base_dir` (default: the current directory). `fixed` are further
    constructor arguments that are not keys (the generator's `source`). Raises ConfigError naming
    `origin` (the file), the key, the value and what is allowed.
    """
    base_dir = Path.cwd() if base_dir is None else base_dir
    keys = _keys(schema)
    valid = [f"[{name}]" if _is_table(schema, f) else name for name, f in keys.items()]
    for name, value in data.items():
        if name not in keys:
            raise _unknown_key_error(f"{origin}: ", f"[{name}]" if isinstance(value, dict) else name, valid)
        if _is_table(schema, keys[name]) and not isinstance(value, dict):
            raise ConfigError(f"{origin}: {name} = {_json(value)!r}: expected a [{name}] table")
    values = {}
    for name, f in keys.items():
        if _is_table(schema, f):
            values[name] = _table(_hints(schema)[name], data.get(name, {}), f"{origin}: [{name}]", base_dir)
        elif name in data:
            values[name] = _setting(schema, f, data[name], f"{origin}: {name}", base_dir)
    return schema(**values, **fixed)


def to_dict(config: Any) -> dict:
    """JSON-safe nested dict of every key of a config (lists for tuples), in declaration order."""
    out: dict = {}
    for name, f in _keys(type(config)).items():
        value = getattr(config, name)
        out[name] = ({g.name: _json(getattr(value, g.name)) for g in dataclasses.fields(value)}
                     if _is_table(type(config), f) else _json(value))
    return out


def read_toml(path: str | os.PathLike) -> dict:
    """The tables of a TOML file. Raises ConfigError naming the file when it is missing or not TOML."""
    path = Path(path)
    try:
        text = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config file ({exc.strerror})") from None
    try:
        return tomllib.loads(text.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None


def reference_markdown(schema: type, title: str, intro: str) -> str:
    """A config's reference page: every top-level key and table with type, allowed, default, meaning."""

    def rows(owner: type, fields: list[dataclasses.Field]) -> list[str]:
        out = ["| key | type | allowed | default | meaning |", "|---|---|---|---|---|"]
        for f in fields:
            hint = _hints(owner)[f.name]
            out.append(f"| `{f.name}` | {_type_name(hint)} | {_allowed(hint, f.metadata)} | "
                       f"`{toml_text(f.default)}` | {f.metadata['help']} |")
        return out + [""]

    lines = [f"# {title}", "", intro, ""]
    top = [f for f in _keys(schema).values() if not _is_table(schema, f)]
    if top:
        lines += ["## Top-level keys", "", *rows(schema, top)]
    for name, cls in tables(schema).items():
        lines += [f"## [{name}]", "", *rows(cls, list(dataclasses.fields(cls)))]
    return "\n".join(lines)
