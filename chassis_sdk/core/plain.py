"""Messages and results as plain, JSON-ready data, for every tool that prints, records
or publishes them (the CLI's ``--json``, ``replay``, recordings, the MQTT bridge)."""

from __future__ import annotations

import dataclasses
import datetime
import enum
import time
from collections.abc import Callable
from typing import Any

__all__ = ["jsonable", "outbound", "plain", "wall_time"]

# One converter per type, worked out once: a recorder or a bridge converts every
# message, and asking "is this a dataclass? an enum? ..." of each value every time
# cost more than the rest of the recording.
_CONVERTERS: dict[type, Callable[[Any], Any]] = {}


def plain(value: object) -> Any:
    """``value`` as JSON-ready data: dataclasses and NamedTuples as objects, enums by
    name, dates as ISO text, a tuple or list of those as a list, anything else as it
    is."""
    cls = type(value)
    convert = _CONVERTERS.get(cls)
    if convert is None:
        convert = _CONVERTERS[cls] = _converter(cls)
    return convert(value)


def _same(value: Any) -> Any:
    return value


def _enum(value: Any) -> Any:
    # ``_name_`` and ``_value_`` are what the ``name`` and ``value`` properties return.
    return value._name_ or int(value._value_)


#: Types that are their own plain form: a field holding one is copied without a call.
_ATOMS = frozenset({float, int, str, bool, type(None)})


def _fields_converter(
    title: str, fields: tuple[str, ...], tuple_like: bool
) -> Callable[[Any], Any]:
    """A function made for one class (as ``dataclasses`` makes ``__init__``) that turns
    an instance into a ``dict`` of its fields: one attribute read per field, and a call
    to `plain` only for a value that is not already plain."""
    lines = [f"def to_plain(value):  # {title}"]
    for i, name in enumerate(fields):
        lines.append(f"    v{i} = value[{i}]" if tuple_like else f"    v{i} = value.{name}")
    items = [
        f"{name!r}: v{i} if v{i}.__class__ in _atoms else _plain(v{i})"
        for i, name in enumerate(fields)
    ]
    lines.append(f"    return {{{', '.join(items)}}}")
    namespace: dict[str, Any] = {"_atoms": _ATOMS, "_plain": plain}
    exec("\n".join(lines), namespace)  # the source is built from field names only
    convert: Callable[[Any], Any] = namespace["to_plain"]
    return convert


def _converter(cls: type) -> Callable[[Any], Any]:
    if dataclasses.is_dataclass(cls):
        names = tuple(f.name for f in dataclasses.fields(cls))
        return _fields_converter(cls.__qualname__, names, tuple_like=False)
    if issubclass(cls, enum.Enum):
        return _enum
    if issubclass(cls, tuple) and hasattr(cls, "_fields"):
        return _fields_converter(cls.__qualname__, tuple(cls._fields), tuple_like=True)
    if issubclass(cls, datetime.date):
        return lambda value: value.isoformat()
    if cls is tuple or cls is list:
        return _sequence
    return _same


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
