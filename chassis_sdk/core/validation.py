"""The one place numbers from a caller are checked, and SI values scaled to wire integers.

Every public argument that is a number goes through `check_real` or
`check_int`, so every device and option refuses the same things with the same
words: ``bool`` is not a number, NaN and infinities are refused, an ``int`` too large
for a float is out of range, and the message names the argument and the range.

As the standard library does (``math.sqrt("4")`` against ``math.sqrt(-1)``), a value of
the wrong type (a ``str``, ``None``, a ``bool`` where a number is wanted, a ``float``
where an integer is) raises `TypeError`, and a value of the right type that is
not allowed (NaN, out of range, an unknown member) raises `ValueError`.
"""

from __future__ import annotations

import enum
import math
from typing import TypeVar

E = TypeVar("E", bound=enum.Enum)

__all__ = [
    "INT16",
    "UINT8",
    "UINT16",
    "check_duration",
    "check_int",
    "check_member",
    "check_optional",
    "check_probability",
    "check_real",
    "scale_to_int",
]

INT16 = (-32768, 32767)
UINT16 = (0, 65535)
UINT8 = (0, 255)


def check_real(
    value: object,
    name: str,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    unit: str = "",
) -> float:
    """Return ``value`` as a ``float`` if it is a real, finite number within bounds.

    The one check every number from a caller goes through: ``bool`` is not a number
    here, an ``int`` too large for a float is out of range (not an ``OverflowError``),
    NaN and infinities are refused.

    Args:
        value: What the caller passed.
        name: Argument name, for the error message.
        low: Inclusive lower bound (exclusive with ``low_open``), if any.
        high: Inclusive upper bound, if any.
        low_open: Make ``low`` exclusive.
        unit: For the error message.

    Raises:
        TypeError: ``value`` is not an ``int`` or a ``float`` (a ``bool`` is not).
        ValueError: NaN, infinite or out of bounds; the message names the argument and
            the range.
    """
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{name} must be a number, got {value!r}")
    try:
        number = float(value)
    except OverflowError:
        number = math.inf
    if not math.isfinite(number):
        raise ValueError(f"{name} must be finite, got {value!r}")
    too_low = low is not None and (number <= low if low_open else number < low)
    if too_low or (high is not None and number > high):
        u = f" {unit}" if unit else ""
        if high is None:
            rule = f"> {low:g}{u}" if low_open else f">= {low:g}{u}"
        elif low is None:
            rule = f"<= {high:g}{u}"
        else:
            rule = f"{low:g} to {high:g}{u}"
        raise ValueError(f"{name} must be a finite number {rule}, got {value!r}")
    return number


def scale_to_int(value: float, scale: float, bounds: tuple[int, int], name: str, unit: str) -> int:
    """Return ``round(value * scale)``, or raise ``ValueError`` if it is not representable.

    Args:
        value: The caller's value in SI units.
        scale: Wire units per SI unit (1000 for m/s to mm/s).
        bounds: Inclusive range of the wire field.
        name: Argument name, for the error message.
        unit: SI unit of ``value``, for the error message.

    Raises:
        TypeError: ``value`` is not a number.
        ValueError: ``value`` is NaN or infinite, or is out of range.
    """
    scaled = check_real(value, name) * scale
    lo, hi = bounds
    if not (math.isfinite(scaled) and lo <= round(scaled) <= hi):
        raise ValueError(
            f"{name}={value!r} {unit} is out of range: the wire field holds "
            f"{lo / scale:g} to {hi / scale:g} {unit}"
        )
    return round(scaled)


def check_duration(duration: float | None) -> float | None:
    """Validate a ``duration=`` argument: ``None`` or a finite number of seconds > 0."""
    if duration is None:
        return None
    return check_real(duration, "duration", low=0, low_open=True, unit="s")


def check_optional(value: float | None, name: str, **bounds: float | bool | str) -> float | None:
    """`check_real` for an option where ``None`` means "off"."""
    if value is None:
        return None
    return check_real(value, name, **bounds)  # type: ignore[arg-type]


def check_probability(value: object, name: str) -> float:
    """A chance per event: a finite number from 0 to 1."""
    return check_real(value, name, low=0.0, high=1.0)


def check_int(value: object, name: str, *, low: int | None = None, high: int | None = None) -> int:
    """Return ``value`` if it is an ``int`` (not a ``bool``) within the inclusive bounds.

    Raises:
        TypeError: Not an ``int`` (a ``bool`` or a ``float`` is not).
        ValueError: Out of range; the message names the argument and the range.
    """
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an integer, got {value!r}")
    if (low is not None and value < low) or (high is not None and value > high):
        if high is None:
            rule = f">= {low}"
        elif low is None:
            rule = f"<= {high}"
        else:
            rule = f"{low} to {high}"
        raise ValueError(f"{name}={value!r} is out of range: it must be an integer {rule}")
    return value


def check_member(cls: type[E], value: object, name: str, hint: str) -> E:
    """Return the member of ``cls`` whose value is ``value`` (an ``int``, not a ``bool``).

    Raises:
        TypeError: ``value`` is not an ``int`` (a ``bool`` is not).
        ValueError: ``unknown {name} {value!r}: {hint}``.
    """
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"unknown {name} {value!r} (not an integer): {hint}")
    try:
        return cls(value)
    except ValueError:
        raise ValueError(f"unknown {name} {value!r}: {hint}") from None
