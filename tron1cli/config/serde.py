"""Round-trip nested frozen dataclasses through plain dicts (JSON in run dirs and checkpoints)."""

from __future__ import annotations

import collections.abc
import dataclasses
import types
import typing
from typing import Any, TypeVar

T = TypeVar("T")


def to_plain(obj: Any) -> Any:
    """Dataclasses, tuples and mappings to JSON-ready dicts and lists."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    if isinstance(obj, typing.Mapping):
        return {str(k): to_plain(v) for k, v in obj.items()}
    return obj


def _kind(value: Any) -> str:
    """How a JSON value reads in an error message."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list | tuple):
        return "a list"
    if isinstance(value, typing.Mapping):
        return "an object"
    return type(value).__name__


def _wrong(where: str, want: str, value: Any) -> ValueError:
    shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
    return ValueError(f"{where} should be {want}, got {_kind(value)} ({shown})")


def check_value(hint: Any, value: Any, where: str) -> None:
    """ValueError naming ``where`` unless ``value`` (plain JSON data) has the form type ``hint``
    asks for: bool, int (not bool), float (int or float), str, a list for a tuple (its items
    checked, its length when fixed), an object for a dict or a dataclass, one of a union's
    members. Types it does not know pass."""
    if hint is Any:
        return
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return
        members = [a for a in args if a is not type(None)]
        errors = []
        for member in members:
            try:
                check_value(member, value, where)
                return
            except ValueError as e:
                errors.append(e)
        raise errors[0]
    if hint is type(None):
        if value is not None:
            raise _wrong(where, "null", value)
        return
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, typing.Mapping):
            raise _wrong(where, "an object", value)
        return
    if hint is bool:
        if not isinstance(value, bool):
            raise _wrong(where, "true or false", value)
    elif hint is int:
        if not isinstance(value, int) or isinstance(value, bool):
            raise _wrong(where, "an integer", value)
    elif hint is float:
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise _wrong(where, "a number", value)
    elif hint is str:
        if not isinstance(value, str):
            raise _wrong(where, "a string", value)
    elif origin is tuple or hint is tuple:
        if not isinstance(value, list | tuple):
            raise _wrong(where, "a list", value)
        if args and not (len(args) == 2 and args[1] is Ellipsis):
            if len(value) != len(args):
                raise _wrong(where, f"a list of {len(args)}", value)
            for k, (a, v) in enumerate(zip(args, value, strict=True)):
                check_value(a, v, f"{where}[{k}]")
        elif args:
            for k, v in enumerate(value):
                check_value(args[0], v, f"{where}[{k}]")
    elif origin in (dict, typing.Mapping, collections.abc.Mapping) or hint is dict:
        if not isinstance(value, typing.Mapping):
            raise _wrong(where, "an object", value)
        if len(args) == 2:
            for k, v in value.items():
                check_value(args[0], k, f"{where} key")
                check_value(args[1], v, f"{where}.{k}")


def from_plain(cls: type[T], data: typing.Mapping, where: str = "") -> T:
    """Rebuild dataclass ``cls`` from :func:`to_plain` output. Unknown keys, and values of the
    wrong kind (:func:`check_value`: a number where a list belongs, a list where an object does),
    raise ValueError naming the field (``where``: the dotted path of ``data`` itself)."""
    where = where or cls.__name__
    if not isinstance(data, typing.Mapping):
        raise _wrong(where, "an object", data)
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ValueError(f"{where}: unknown fields {sorted(map(str, unknown))}")
    kwargs = {}
    for name, value in data.items():
        hint = hints[name]
        check_value(hint, value, f"{where}.{name}")
        if dataclasses.is_dataclass(hint):
            kwargs[name] = from_plain(hint, value, f"{where}.{name}")
        elif typing.get_origin(hint) is tuple and isinstance(value, list):
            kwargs[name] = tuple(value)
        else:
            kwargs[name] = value
    return cls(**kwargs)
