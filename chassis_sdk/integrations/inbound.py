"""What every surface that takes commands from outside the process shares (the MQTT
bridge, the Foxglove server, and the ROS 2 bridge and dashboard to come): one strict
reading of a JSON command, one check of a command's timestamp, and one rate-limited,
summarised account of what was refused.

Why it is shaped this way
-------------------------
A command arrives from a network the robot does not control. Python's ``json`` module
is lenient in ways that matter there: ``json.loads(bytes)`` guesses UTF-16 and UTF-32
(RFC 8259 §8.1 allows UTF-8 only), takes the last of duplicate keys silently, accepts
``NaN`` and ``Infinity``, raises ``RecursionError`` for deep nesting and a bare
``ValueError`` for an integer of more than 4,300 digits (neither a ``JSONDecodeError``).
`command_object` closes every one of those: whatever the payload, it returns a
JSON object or raises `CommandError` with one line saying why, in time bounded by
the payload's size limit.

A refusal must be reported, but a flood of junk must not turn into a flood of reports:
`Refusals` (from ``chassis_sdk.core.refusals``, which the motion core counts its
refusals with too) says when to report: the first at once, then at most one summary
per interval with the count and the reasons.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import time
from typing import Any

from ..core.refusals import MAX_REASON_CHARS, RefusalReport, Refusals
from ..core.validation import check_real

__all__ = [
    "MAX_COMMAND_BYTES",
    "TIMESTAMP_SKEW",
    "CommandError",
    "RefusalReport",
    "Refusals",
    "check_fresh",
    "check_topic_level",
    "command_number",
    "command_object",
    "command_time",
]


def check_topic_level(value: object, name: str) -> str:
    """``value`` if it is one MQTT topic level a robot may be named by: letters, digits,
    ``-`` or ``_`` (``/``, ``#`` and ``+`` would make other topics or wildcards).

    Raises:
        TypeError: Not a string.
        ValueError: Empty, or another character.
    """
    if not isinstance(value, str):
        raise TypeError(f"{name} must be a string, got {value!r}")
    if not value or not all(c.isalnum() or c in "-_" for c in value):
        raise ValueError(f"{name} must be letters, digits, '-' or '_', got {value!r}")
    return value


#: The largest command payload read, in bytes (a velocity command is about 40).
MAX_COMMAND_BYTES = 4096
#: The longest number literal read (a double needs at most 24 characters).
_MAX_NUMBER_CHARS = 40
#: Seconds a command's timestamp may differ from this computer's clock (NTP keeps
#: clocks within milliseconds; this allows a loosely synchronised fleet).
TIMESTAMP_SKEW = 0.25


class CommandError(ValueError):
    """A command or request that is refused, and why (one line)."""


def _object(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    obj = dict(pairs)
    if len(obj) != len(pairs):
        seen: set[str] = set()
        for key, _ in pairs:
            if key in seen:
                raise CommandError(f"the key {key[:40]!r} appears twice")
            seen.add(key)
    return obj


def _number(text: str) -> float | int:
    if len(text) > _MAX_NUMBER_CHARS:
        raise CommandError(f"a number of {len(text)} characters (at most {_MAX_NUMBER_CHARS})")
    return float(text) if any(c in text for c in ".eE") else int(text)


def _constant(name: str) -> float:
    raise CommandError(f"{name} is not JSON (RFC 8259 has no NaN or Infinity)")


_DECODER = json.JSONDecoder(
    object_pairs_hook=_object, parse_int=_number, parse_float=_number, parse_constant=_constant
)


def command_object(raw: object, *, limit: int = MAX_COMMAND_BYTES) -> dict[str, Any]:
    """Read one JSON command strictly: UTF-8 (RFC 8259 §8.1), at most ``limit`` bytes,
    an object, no duplicate keys, no ``NaN``/``Infinity``, numbers of at most 40
    characters, nesting bounded.

    Args:
        raw: The payload as received (``bytes``, ``bytearray`` or ``memoryview``).
        limit: The most bytes read.

    Returns:
        The object, its numbers as ``int`` or ``float``.

    Raises:
        CommandError: The payload is refused; the message says why in one line.
    """
    if not isinstance(raw, bytes | bytearray | memoryview):
        raise CommandError(f"the payload is {type(raw).__name__}, not bytes")
    if len(raw) > limit:
        raise CommandError(f"the payload is {len(raw)} bytes; a command is at most {limit}")
    try:
        text = bytes(raw).decode("utf-8")
    except UnicodeDecodeError:
        raise CommandError("the payload is not UTF-8 (RFC 8259 §8.1)") from None
    if text.startswith("\ufeff"):
        raise CommandError("the payload starts with a byte order mark (RFC 8259 §8.1)")
    try:
        payload = _DECODER.decode(text)
    except CommandError:
        raise
    except RecursionError:
        raise CommandError("the payload is nested too deeply") from None
    except ValueError:  # JSONDecodeError, and anything else the scanner refuses
        raise CommandError("the payload is not JSON") from None
    if not isinstance(payload, dict):
        raise CommandError(f"the payload is a JSON {type(payload).__name__}, not an object")
    return payload


def command_number(body: dict[str, Any], key: str, name: str | None = None) -> float:
    """``body[key]`` as a finite ``float`` (checked as every number from a caller is,
    by [`check_real`][chassis_sdk.core.validation.check_real]).

    Raises:
        CommandError: Missing, not a number (a ``bool`` is not), or not finite; the
            message names the field (``name``, default ``key``) in one bounded line.
    """
    try:
        return check_real(body.get(key), key if name is None else name)
    except (TypeError, ValueError) as exc:
        raise CommandError(str(exc)[:MAX_REASON_CHARS]) from None


def command_time(value: object) -> float:
    """A command's ``timestamp`` as seconds since the epoch: a number of epoch seconds,
    or an ISO 8601 string with its offset (``2026-12-01T18:00:00.250Z``), as a VDA 5050
    header carries it.

    Raises:
        CommandError: Not a finite positive number nor an ISO 8601 time with an offset.
    """
    if isinstance(value, str):
        if len(value) > 64:
            raise CommandError("'timestamp' is too long for an ISO 8601 time")
        try:
            stamp = _dt.datetime.fromisoformat(value)
        except ValueError:
            raise CommandError(f"'timestamp' is not an ISO 8601 time: {value[:64]!r}") from None
        if stamp.tzinfo is None:
            raise CommandError("'timestamp' needs its UTC offset ('Z' or '+hh:mm')")
        return stamp.timestamp()
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CommandError("'timestamp' must be epoch seconds or an ISO 8601 string")
    seconds = float(value)
    if not math.isfinite(seconds) or seconds <= 0:
        raise CommandError(f"'timestamp' must be positive epoch seconds, got {value!r}")
    return seconds


def check_fresh(
    stamp: float, max_age: float, *, now: float | None = None, skew: float = TIMESTAMP_SKEW
) -> float:
    """Refuse a command stamped more than ``max_age`` (plus ``skew``) ago, or more than
    ``skew`` ahead of this computer's clock; return its age in seconds.

    Raises:
        CommandError: The command is stale or from the future.
    """
    age = (time.time() if now is None else now) - stamp
    if age > max_age + skew:
        raise CommandError(
            f"the command is {age:.3f} s old (older than {max_age:g} s + {skew:g} s skew): "
            "it would move the robot late"
        )
    if age < -skew:
        raise CommandError(
            f"the command is stamped {-age:.3f} s in the future (clocks out of sync by "
            f"more than {skew:g} s?)"
        )
    return age
