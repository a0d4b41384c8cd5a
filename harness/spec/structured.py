"""Frozen dataclasses as the schema of a file: read a loaded YAML mapping onto them.

A field's type is what the program holds. Where a file writes the field differently,
``key(...)`` says how: under another key name, as another type that a function turns into the
field's, or mandatory in the file although Python callers may leave it out. ``derived(...)``
marks a field the program fills in after reading; a file may not set it. An ``Enum`` type
names its values in errors with ``noun = enum.nonmember("...")``.

``read(raw, cls, where)`` checks the keys, enum values and scalar places first (the path of
the first problem, ``profiles.quick.scenes[0].zzz``), then types and mandatory keys with OmegaConf
against ``cls`` as the file writes it (``file_form``: tuples as lists, ``key`` applied), and
builds ``cls``. Every problem is one ``InputError`` naming ``where`` and the key.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import types
import typing
from collections.abc import Callable
from typing import Any

from ftgspp.errors import InputError


def key(name: str = "", *, default: Any = dataclasses.MISSING, factory: Any = dataclasses.MISSING,
        required: bool = False, written: Any = None, read: Callable[[Any], Any] | None = None) -> Any:
    """A field the file writes differently: under the key ``name``, as the type ``written``
    (``read`` turns it into the field's type; None stays None), or ``required`` in the file
    although Python callers may leave it out (``default``, ``factory``)."""
    return dataclasses.field(default=default, default_factory=factory,
                             metadata={"key": name, "required": required, "written": written, "read": read})


def derived(default: Any) -> Any:
    """A field the program fills in after reading; never a key of the file."""
    return dataclasses.field(default=default, metadata={"derived": True})


def _optional(tp: Any) -> Any:
    """``X`` for ``X | None``, else None."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp):
        return next(a for a in typing.get_args(tp) if a is not type(None))
    return None


def _file_type(tp: Any) -> Any:
    """The schema type ``tp`` as OmegaConf reads it: tuples as lists, dataclasses as their file form."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if (inner := _optional(tp)) is not None:
        return _file_type(inner) | None
    if dataclasses.is_dataclass(tp):
        return file_form(tp)
    if origin in (tuple, list):
        return list[_file_type(args[0])]  # type: ignore[misc]
    if origin is dict:
        return dict[_file_type(args[0]), _file_type(args[1])]  # type: ignore[misc]
    return tp


@functools.cache
def file_form(cls: type) -> type:
    """The dataclass ``cls`` as a file writes it (keys, types, defaults): what OmegaConf checks."""
    hints = typing.get_type_hints(cls)
    fields = []
    for f in dataclasses.fields(cls):
        if f.metadata.get("derived"):
            continue
        written = f.metadata.get("written")
        tp = _file_type(written or hints[f.name])
        no_default = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if f.metadata.get("required") or no_default:
            default = dataclasses.field(default="???")  # OmegaConf's mandatory value
        elif written is not None:  # omitted: None, or an empty list or mapping
            default = dataclasses.field(default=None) if _optional(written) else \
                dataclasses.field(default_factory=typing.get_origin(written))
        elif dataclasses.is_dataclass(hints[f.name]):
            default = dataclasses.field(default_factory=file_form(hints[f.name]))
        elif f.default_factory is not dataclasses.MISSING:
            default = dataclasses.field(default_factory=f.default_factory)
        elif isinstance(f.default, tuple):
            default = dataclasses.field(default_factory=functools.partial(list, f.default))
        else:
            default = dataclasses.field(default=f.default)
        fields.append((f.metadata.get("key") or f.name, tp, default))
    return dataclasses.make_dataclass(cls.__name__, fields)


def _check_keys(raw: Any, tp: Any, at: str, where: str) -> None:
    """Raise for the first key of ``raw`` (at path ``at``) that its file form ``tp`` lacks, the
    first value outside its ``StrEnum``, or a mapping or list where a scalar belongs."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    inside = f"{at}." if at else ""
    if (inner := _optional(tp)) is not None:
        _check_keys(raw, inner, at, where)
    elif isinstance(tp, type) and issubclass(tp, enum.Enum):
        if raw is not None and raw not in tuple(tp):
            noun = getattr(tp, "noun", "value")
            raise InputError(f"{where}: {at}", f"unknown {noun} '{raw}' (use {', '.join(tp)})")
    elif tp in (str, int, float, bool) and isinstance(raw, (dict, list)):  # OmegaConf lets these through
        what = {str: "a string", int: "an integer", float: "a number", bool: "true or false"}[tp]
        raise InputError(f"{where}: {at}", f"must be {what}, not a {'mapping' if isinstance(raw, dict) else 'list'}")
    elif dataclasses.is_dataclass(tp) and isinstance(raw, dict):
        hints = typing.get_type_hints(tp)
        for k, value in raw.items():
            if k not in hints:
                raise InputError(f"{where}: {inside}{k}", f"unknown key(s) {k} (use {', '.join(hints)})")
            _check_keys(value, hints[k], f"{inside}{k}", where)
    elif origin is list and isinstance(raw, list):
        for i, value in enumerate(raw):
            _check_keys(value, args[0], f"{at}[{i}]", where)
    elif origin is dict and isinstance(raw, dict):
        for k, value in raw.items():
            _check_keys(k, args[0], f"{inside}{k}", where)
            _check_keys(value, args[1], f"{inside}{k}", where)


def read(raw: Any, cls: type, where: str) -> Any:
    """``raw`` (a loaded YAML mapping) as an instance of the dataclass ``cls``; the first problem
    is one ``InputError`` naming ``where`` and the key."""
    from omegaconf import OmegaConf
    from omegaconf.errors import MissingMandatoryValue, OmegaConfBaseException

    if not isinstance(raw, dict):
        raise InputError(where, "must be a mapping")
    _check_keys(raw, file_form(cls), "", where)
    try:
        # strings keep their ${oc.env:...} text (escaped here): Hydra resolves them per run
        cfg = OmegaConf.merge(OmegaConf.structured(file_form(cls)), _escaped(raw))
        typed = OmegaConf.to_object(cfg)
    except OmegaConfBaseException as exc:
        at = str(getattr(exc, "full_key", "") or "").strip()
        if isinstance(exc, MissingMandatoryValue):
            problem = f"missing key '{at.rsplit('.', 1)[-1]}'"
        else:
            text = str(exc).strip().splitlines()[0]
            problem = "must be a list" if "is not a ListConfig" in text else \
                "must be a mapping" if "DictConfig" in text else text
        raise InputError(f"{where}: {at}" if at else where, problem) from None
    return _build(cls, typed)


def _escaped(value: Any) -> Any:
    """``value`` with every ``${`` escaped, so OmegaConf keeps interpolations as text."""
    if isinstance(value, str):
        return value.replace("${", "\\${")
    if isinstance(value, dict):
        return {k: _escaped(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_escaped(v) for v in value]
    return value


def _build(tp: Any, value: Any) -> Any:
    """OmegaConf's reading ``value`` (file forms, lists) as the schema type ``tp``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if value is None:
        return None
    if (inner := _optional(tp)) is not None:
        return _build(inner, value)
    if dataclasses.is_dataclass(tp):
        hints, kwargs = typing.get_type_hints(tp), {}
        for f in dataclasses.fields(tp):
            if not f.metadata.get("derived"):
                v = _build(f.metadata.get("written") or hints[f.name], getattr(value, f.metadata.get("key") or f.name))
                convert = f.metadata.get("read")
                kwargs[f.name] = convert(v) if convert is not None and v is not None else v
        return tp(**kwargs)
    if origin is tuple:
        return tuple(_build(args[0], v) for v in value)
    if origin is list:
        return [_build(args[0], v) for v in value]
    if origin is dict:
        return {k: _build(args[1], v) for k, v in value.items()}
    return value
