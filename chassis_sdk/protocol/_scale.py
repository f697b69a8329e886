"""Checked conversion of SI values to wire integers, shared by both protocols."""

from __future__ import annotations

import math

__all__ = ["INT16", "UINT8", "UINT16", "check_duration", "scale_to_int"]

INT16 = (-32768, 32767)
UINT16 = (0, 65535)
UINT8 = (0, 255)


def scale_to_int(value: float, scale: float, bounds: tuple[int, int], name: str, unit: str) -> int:
    """Return ``round(value * scale)``, or raise ``ValueError`` if it is not representable.

    Args:
        value: The caller's value in SI units.
        scale: Wire units per SI unit (1000 for m/s to mm/s).
        bounds: Inclusive range of the wire field.
        name: Argument name, for the error message.
        unit: SI unit of ``value``, for the error message.

    Raises:
        ValueError: ``value`` is not a real number, is NaN or infinite, or is out of range.
    """
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    wire = round(value * scale)
    lo, hi = bounds
    if not lo <= wire <= hi:
        raise ValueError(
            f"{name}={value!r} {unit} is out of range: the wire field holds "
            f"{lo / scale:g} to {hi / scale:g} {unit}"
        )
    return wire


def check_duration(duration: float | None) -> float | None:
    """Validate a ``duration=`` argument: ``None`` or a finite number of seconds > 0."""
    if duration is None:
        return None
    if isinstance(duration, bool) or not isinstance(duration, int | float):
        raise ValueError(f"duration must be a number of seconds or None, got {duration!r}")
    if not math.isfinite(duration) or duration <= 0:
        raise ValueError(f"duration must be finite and > 0 seconds, got {duration!r}")
    return float(duration)
