"""Messages and results as plain, JSON-ready data, for every tool that prints or
publishes them (the CLI's ``--json``, ``replay``, the MQTT bridge)."""

from __future__ import annotations

import dataclasses
import datetime
import enum
from typing import Any

__all__ = ["jsonable", "plain"]


def plain(value: object) -> Any:
    """``value`` as JSON-ready data: dataclasses and NamedTuples as objects, enums by
    name, dates as ISO text, anything else as it is."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, enum.Enum):
        return value.name if value.name else int(value.value)
    if isinstance(value, tuple) and hasattr(value, "_asdict"):
        return {k: plain(v) for k, v in value._asdict().items()}
    if isinstance(value, datetime.date):
        return value.isoformat()
    return value


def jsonable(msg: object) -> dict[str, Any]:
    """A message as a JSON-ready ``dict`` (a bare value as ``{"value": ...}``)."""
    result = plain(msg)
    return result if isinstance(result, dict) else {"value": result}
