"""TOML inputs: reading, one typed validator for every dataclass read from TOML, and writing.

Model specs and experiment designs are trees of frozen dataclasses; :func:`build` checks a
parsed TOML table against the type hints of such a tree (unknown keys, wrong types, bad
choices) and names the file and the dotted key of what is wrong, with the key meant when a
misspelt one is close.  :func:`dumps` writes the same layout back (``tomli-w``).
"""

from __future__ import annotations

import dataclasses
import difflib
import os
import tomllib
import types
import typing
from pathlib import Path
from typing import Any, Literal

from bayescal.errors import SpecError
from bayescal.io.files import read_text

__all__ = ["read_toml", "check_keys", "build", "dumps"]


def read_toml(path: str | os.PathLike, what: str, error: type[Exception] = SpecError) -> dict[str, Any]:
    """Parse a TOML file; ``error`` names the file and the line of a syntax error."""
    path = Path(path)
    try:
        return tomllib.loads(read_text(path, error, what))
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{path}: invalid TOML: {exc}") from None


def check_keys(data: dict[str, Any], known: set[str], source: str, prefix: str = "") -> None:
    """Reject keys a table does not define (a typo must not pass silently).

    Names the file, the misspelt key(s) and, where one is close, the key meant.
    """
    unknown = sorted(set(data) - known)
    if not unknown:
        return
    hints = []
    for k in unknown:
        close = difflib.get_close_matches(k, known, n=1)
        hints.append(f"{prefix}{k}" + (f" (did you mean '{prefix}{close[0]}'?)" if close else ""))
    raise SpecError(f"{source}: unknown key(s) {', '.join(hints)}; expected one of {sorted(known)}")


def build(cls: type, data: Any, source: str, prefix: str = "") -> Any:
    """An instance of the dataclass ``cls`` from a parsed TOML table, every value checked against
    its type hint (bool, int, float, str, ``Literal``, ``X | None``, ``tuple[X, ...]``,
    ``dict[K, V]``, nested dataclasses); raises :class:`~bayescal.errors.SpecError` naming
    ``source`` and the dotted key."""
    if not isinstance(data, dict):
        raise SpecError(f"{source}: [{prefix.rstrip('.') or 'top level'}] must be a table")
    hints = typing.get_type_hints(cls)
    fields = [f for f in dataclasses.fields(cls) if f.init]
    check_keys(data, {f.name for f in fields}, source, prefix)
    kwargs = {}
    for f in fields:
        if f.name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise SpecError(f"{source}: missing required key '{prefix}{f.name}'")
            continue
        kwargs[f.name] = _coerce(hints[f.name], data[f.name], source, prefix + f.name)
    try:
        return cls(**kwargs)
    except SpecError as exc:
        raise SpecError(f"{source}: {exc}") from None


def _coerce(hint: Any, value: Any, source: str, key: str) -> Any:
    if isinstance(hint, type) and dataclasses.is_dataclass(hint):
        return build(hint, value, source, key + ".")
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (types.UnionType, typing.Union):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        if len(options) == 1:
            return _coerce(options[0], value, source, key)
        for option in options:  # str | float: the first that fits
            try:
                return _coerce(option, value, source, key)
            except SpecError:
                continue
        raise SpecError(f"{source}: '{key}' = {value!r}; expected {' or '.join(_name(a) for a in options)}")
    if origin is Literal:
        if value not in args:
            raise SpecError(f"{source}: '{key}' = {value!r}; expected one of {list(args)}")
        return value
    if origin is tuple:
        item = args[0] if len(args) == 2 and args[1] is Ellipsis else None
        items = value if isinstance(value, list | tuple) else None
        if items is None and item is not None and not isinstance(value, dict):
            items = [value]  # a single value where a list is expected: a list of one
        if items is None:
            raise SpecError(f"{source}: '{key}' = {value!r}; expected a list")
        if item is None and len(args) != len(items):
            raise SpecError(f"{source}: '{key}' has {len(items)} entries; expected {len(args)}")
        kinds = [item] * len(items) if item is not None else list(args)
        return tuple(_coerce(k, v, source, f"{key}[{i}]") for i, (k, v) in enumerate(zip(kinds, items, strict=True)))
    if origin is dict:
        if not isinstance(value, dict):
            raise SpecError(f"{source}: '{key}' = {value!r}; expected a table")
        k_hint, v_hint = args
        return {_key(k_hint, k, source, key): _coerce(v_hint, v, source, f"{key}.{k}") for k, v in value.items()}
    if hint is bool:
        if not isinstance(value, bool):
            raise SpecError(f"{source}: '{key}' = {value!r}; expected true or false")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SpecError(f"{source}: '{key}' = {value!r}; expected an integer")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise SpecError(f"{source}: '{key}' = {value!r}; expected a number")
        return float(value)
    if hint is str:
        if not isinstance(value, str):
            raise SpecError(f"{source}: '{key}' = {value!r}; expected a string")
        return value
    return value


def _key(hint: Any, key: str, source: str, where: str) -> Any:
    """A table key (always a string in TOML) as the key type of a ``dict[K, V]`` hint."""
    if hint is float:
        try:
            return float(key)
        except ValueError:
            raise SpecError(f"{source}: key '{where}.{key}' is not a number") from None
    return str(key)


def _name(hint: Any) -> str:
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(hint, str(hint))


def dumps(data: dict[str, Any]) -> str:
    """TOML text of a nested dict (``None`` values, which TOML cannot hold, are left out)."""
    import tomli_w

    return tomli_w.dumps(_without_none(data))


def _without_none(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _without_none(v) for k, v in value.items() if v is not None}
    if isinstance(value, list | tuple):
        return [_without_none(v) for v in value]
    return value
