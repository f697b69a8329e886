"""Messages and results as plain, JSON-ready data, for every tool that prints, records
or publishes them (the CLI's ``--json``, ``replay``, recordings, the live Foxglove
server, the MQTT bridge, the dashboard), and the JSON schema of that data: one encoding,
written here once.

Its rules, which the viewers people use read (Lichtblick and Foxglove take one type per
property, a string, and refuse a list of types, ``anyOf`` and ``null``):

* a dataclass or a NamedTuple is an object of its fields; a field that is ``None`` is
  left out, never ``null`` (its schema does not list it as required);
* an enum is its member's name (``"DOCKED"``); a flag is the names of its set bits,
  ``|``-joined, lowest first (``"HARDWARE_ESTOP|FRONT_BUMPER"``), an undocumented bit
  named ``BIT_n``, and ``""`` when none is set: always a string;
* a date is ISO text; a tuple or list is an array; anything else is as it is.
"""

from __future__ import annotations

import dataclasses
import datetime
import enum
import time
import types
import typing
from collections.abc import Callable
from typing import Any

from .enums import flag_names

__all__ = ["json_schema", "jsonable", "outbound", "plain", "wall_time"]

# One converter per type, worked out once: a recorder or a bridge converts every
# message, and asking "is this a dataclass? an enum? ..." of each value every time
# cost more than the rest of the recording.
_CONVERTERS: dict[type, Callable[[Any], Any]] = {}


def plain(value: object) -> Any:
    """``value`` as JSON-ready data (see the module docstring for the rules):
    dataclasses and NamedTuples as objects without their ``None`` fields, enums and
    flags by name, dates as ISO text, a tuple or list of those as a list, anything else
    as it is."""
    cls = type(value)
    convert = _CONVERTERS.get(cls)
    if convert is None:
        convert = _CONVERTERS[cls] = _converter(cls)
    return convert(value)


def _same(value: Any) -> Any:
    return value


def _enum(value: Any) -> Any:
    # ``_name_`` is what the ``name`` property returns.
    return value._name_


#: The text of each flag value written so far, by class and value, up to
#: :data:`_FLAGS_KEPT` of them (a device reports few distinct status words).
_flag_texts: dict[tuple[type, int], str] = {}
_FLAGS_KEPT = 4096


def _flag(value: Any) -> str:
    key = (value.__class__, value._value_)
    text = _flag_texts.get(key)
    if text is None:
        text = "|".join(flag_names(value))
        if len(_flag_texts) < _FLAGS_KEPT:
            _flag_texts[key] = text
    return text


#: Types that are their own plain form: a field holding one is copied without a call.
_ATOMS = frozenset({float, int, str, bool, type(None)})


def _fields_converter(
    title: str, fields: tuple[str, ...], optional: frozenset[str], tuple_like: bool
) -> Callable[[Any], Any]:
    """A function made for one class (as ``dataclasses`` makes ``__init__``) that turns
    an instance into a ``dict`` of its fields: one attribute read per field, a call to
    `plain` only for a value that is not already plain, and a field that may be
    ``None`` (those of ``optional``) left out when it is."""
    lines = [f"def to_plain(value):  # {title}"]
    for i, name in enumerate(fields):
        lines.append(f"    v{i} = value[{i}]" if tuple_like else f"    v{i} = value.{name}")

    def item(i: int) -> str:
        return f"v{i} if v{i}.__class__ in _atoms else _plain(v{i})"

    # The fields up to the first that may be None in one literal; each after it in turn,
    # so that the object keeps the fields' order.
    first = next((i for i, name in enumerate(fields) if name in optional), len(fields))
    literal = ", ".join(f"{name!r}: {item(i)}" for i, name in enumerate(fields[:first]))
    lines.append(f"    d = {{{literal}}}")
    for i, name in enumerate(fields[first:], first):
        if name in optional:
            lines.append(f"    if v{i} is not None:")
            lines.append(f"        d[{name!r}] = {item(i)}")
        else:
            lines.append(f"    d[{name!r}] = {item(i)}")
    lines.append("    return d")
    namespace: dict[str, Any] = {"_atoms": _ATOMS, "_plain": plain}
    exec("\n".join(lines), namespace)  # the source is built from field names only
    convert: Callable[[Any], Any] = namespace["to_plain"]
    return convert


def _converter(cls: type) -> Callable[[Any], Any]:
    if dataclasses.is_dataclass(cls) or (issubclass(cls, tuple) and hasattr(cls, "_fields")):
        names = _field_names(cls)
        hints = _hints(cls)
        # A field whose type cannot be read may be None: it is checked for it.
        optional = frozenset(n for n in names if hints is None or _may_be_none(hints.get(n)))
        tuple_like = not dataclasses.is_dataclass(cls)
        return _fields_converter(cls.__qualname__, names, optional, tuple_like)
    if issubclass(cls, enum.Flag):
        return _flag
    if issubclass(cls, enum.Enum):
        return _enum
    if issubclass(cls, datetime.date):
        return lambda value: value.isoformat()
    if cls is tuple or cls is list:
        return _sequence
    return _same


def _field_names(cls: type) -> tuple[str, ...]:
    if dataclasses.is_dataclass(cls):
        return tuple(f.name for f in dataclasses.fields(cls))
    return tuple(getattr(cls, "_fields", ()))


def _hints(cls: type) -> dict[str, Any] | None:
    """The fields' types, or ``None`` when they cannot be read."""
    try:
        return typing.get_type_hints(cls)
    except (NameError, TypeError):
        return None


def _may_be_none(tp: Any) -> bool:
    """Whether a field of type ``tp`` may hold ``None`` (``X | None``, ``Any``, unknown)."""
    if tp is None or tp is Any or tp is type(None):
        return True
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return type(None) in typing.get_args(tp)
    return False


def _sequence(value: Any) -> Any:
    """A tuple or list: as it is if of plain items (judged by the first: every message
    holds one kind), else a list of their plain forms (a reflex's measures)."""
    if not value or value[0].__class__ in _ATOMS:
        return value
    return [plain(item) for item in value]


def jsonable(msg: object) -> dict[str, Any]:
    """A message as a JSON-ready ``dict`` (a bare value as ``{"value": ...}``)."""
    result = plain(msg)
    return result if isinstance(result, dict) else {"value": result}


def outbound(msg: object, *, now: float | None = None) -> dict[str, Any]:
    """A message as JSON that leaves the process (MQTT, the dashboard, ``--json``):
    `jsonable`, with one clock: its ``timestamp`` is wall time (epoch seconds,
    `wall_time`), and the ``time.monotonic()`` reading it came from is kept as
    ``monotonic``, the only field named so."""
    body = jsonable(msg)
    stamp = body.get("timestamp")
    if isinstance(stamp, float | int) and not isinstance(stamp, bool):
        body["monotonic"] = stamp
        body["timestamp"] = wall_time(float(stamp), now=now)
    return body


def wall_time(monotonic: float, *, now: float | None = None) -> float:
    """The wall-clock time (epoch seconds) of a ``time.monotonic()`` reading: what
    leaves the process is wall time. A reading without a clock (0.0) is ``now``."""
    if now is None:
        now = time.time()
    return now - (time.monotonic() - monotonic) if monotonic > 0 else now


# --- the JSON schema of what plain writes -----------------------------------------------------


_ENUM_MISSING = enum.Enum._missing_.__func__  # type: ignore[attr-defined]


def json_schema(tp: Any) -> dict[str, Any]:
    """A JSON schema of how `plain` writes a value of type ``tp`` (a message
    dataclass, a NamedTuple, an enum, a number, ...), in the form the viewers read: one
    ``type`` per property, a string; no ``null`` (an optional field is not required);
    an enum's names as its ``enum`` where those are all it can be. ``{}`` for a type it
    cannot describe."""
    if tp is bool:
        return {"type": "boolean"}
    if tp is int:
        return {"type": "integer"}
    if tp is float:
        return {"type": "number"}
    if tp is str:
        return {"type": "string"}
    if tp is bytes:
        return {"type": "string", "contentEncoding": "base64"}
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        kinds = [a for a in args if a is not type(None)]  # None: the field is left out
        if set(kinds) == {int, float}:
            return {"type": "number"}
        return json_schema(kinds[0]) if len(kinds) == 1 else {}
    if origin in (tuple, list) or tp in (tuple, list):
        items = [a for a in args if a is not Ellipsis]
        if len(set(items)) == 1:
            return {"type": "array", "items": json_schema(items[0])}
        return {"type": "array"}
    if isinstance(tp, type):
        if issubclass(tp, enum.Flag):
            return {"type": "string"}
        if issubclass(tp, enum.Enum):
            # Its names, unless it has none (a field of any enum) or makes members for
            # values it does not list (``_missing_``: ``DockingState``'s ``UNKNOWN_9``).
            names = [m.name for m in tp]
            if not names or getattr(tp._missing_, "__func__", None) is not _ENUM_MISSING:
                return {"type": "string"}
            return {"type": "string", "enum": names}
        if issubclass(tp, datetime.date):
            return {"type": "string", "format": "date"}
        if dataclasses.is_dataclass(tp) or (issubclass(tp, tuple) and hasattr(tp, "_fields")):
            return _object_schema(tp)
    return {}


def _object_schema(cls: type) -> dict[str, Any]:
    hints = _hints(cls) or {}
    names = _field_names(cls)
    return {
        "title": cls.__qualname__,
        "type": "object",
        "properties": {name: json_schema(hints.get(name, Any)) for name in names},
        "required": [name for name in names if not _may_be_none(hints.get(name))],
    }
