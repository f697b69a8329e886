"""Messages and results as plain, JSON-ready data, for every tool that prints, records
or publishes them (the CLI's ``--json``, ``replay``, recordings, the MQTT bridge)."""

from __future__ import annotations

import dataclasses
import datetime
import enum
from collections.abc import Callable
from typing import Any

__all__ = ["jsonable", "plain"]

# One converter per type, worked out once: a recorder or a bridge converts every
# message, and asking "is this a dataclass? an enum? ..." of each value every time
# cost more than the rest of the recording.
_CONVERTERS: dict[type, Callable[[Any], Any]] = {}


def plain(value: object) -> Any:
    """``value`` as JSON-ready data: dataclasses and NamedTuples as objects, enums by
    name, dates as ISO text, anything else as it is."""
    cls = type(value)
    convert = _CONVERTERS.get(cls)
    if convert is None:
        convert = _CONVERTERS[cls] = _converter(cls)
    return convert(value)


def _same(value: Any) -> Any:
    return value


def _enum(value: Any) -> Any:
    return value.name if value.name else int(value.value)


def _converter(cls: type) -> Callable[[Any], Any]:
    if dataclasses.is_dataclass(cls):
        names = tuple(f.name for f in dataclasses.fields(cls))
        return lambda value: {name: plain(getattr(value, name)) for name in names}
    if issubclass(cls, enum.Enum):
        return _enum
    if issubclass(cls, tuple) and hasattr(cls, "_fields"):
        fields = tuple(cls._fields)
        return lambda value: {name: plain(item) for name, item in zip(fields, value, strict=True)}
    if issubclass(cls, datetime.date):
        return lambda value: value.isoformat()
    return _same


def jsonable(msg: object) -> dict[str, Any]:
    """A message as a JSON-ready ``dict`` (a bare value as ``{"value": ...}``)."""
    result = plain(msg)
    return result if isinstance(result, dict) else {"value": result}
