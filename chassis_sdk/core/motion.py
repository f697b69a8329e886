"""A device's motion: its commands over the
`VelocityWatchdog` that keeps, resends, limits and
expires the active command."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import TypeVar

from .watchdog import Axes, FrameBuilder, MotionLimits, VelocityWatchdog

__all__ = ["Motion", "frame_builder"]

T = TypeVar("T")


def frame_builder(
    make: Callable[[float, float], T], encode: Callable[[T], bytes], a: float, b: float
) -> FrameBuilder:
    """Check the command ``(a, b)`` by making its message now (``make`` raises
    ``ValueError`` before anything is written), and return the builder of the frames the
    watchdog writes for it: the message made here for the command itself (every resend
    of it), a new one only for a value that limits or a ramp changed."""
    command = make(a, b)

    def build(x: float, y: float) -> bytes:
        return encode(command if x == a and y == b else make(x, y))

    return build


class Motion:
    """A device's motion: the `VelocityWatchdog` that keeps, resends, limits and
    expires the active command, and the commands over it.

    Args:
        write_velocity: Writes a velocity frame (``frame, expires``).
        ensure_open: Raises ``NotConnectedError`` if the port is not open.
        zero_frame: Makes a zero-velocity frame.
        interval: Resend period (s).
        command_timeout: The deadman (s), or ``None``.
        logger: For the watchdog's messages.
    """

    def __init__(
        self,
        write_velocity: Callable[[bytes, float], None],
        ensure_open: Callable[[], None],
        zero_frame: Callable[[], bytes],
        *,
        interval: float,
        command_timeout: float | None,
        logger: logging.Logger,
    ) -> None:
        self.watchdog = VelocityWatchdog(
            write_velocity, interval=interval, command_timeout=command_timeout, logger=logger
        )
        self._ensure_open = ensure_open
        self._zero_frame = zero_frame

    def drive(
        self,
        target: tuple[float, float],
        build: FrameBuilder,
        duration: float | None,
        description: str,
        axes: Axes,
    ) -> None:
        """Make ``target`` the active command (``build`` makes its frames)."""
        self._ensure_open()
        self.watchdog.command(target, build, self._zero_frame, duration, description, axes)

    def stop(self) -> None:
        """End the active command and write zero now (raises if the port is not open,
        after ending the command)."""
        self.watchdog.clear()
        self._ensure_open()
        self.watchdog.stop(self._zero_frame)

    @property
    def limits(self) -> MotionLimits:
        return self.watchdog.limits

    @limits.setter
    def limits(self, limits: MotionLimits | None) -> None:
        if limits is not None and not isinstance(limits, MotionLimits):
            raise TypeError(f"limits must be a MotionLimits or None, got {limits!r}")
        self.watchdog.limits = limits if limits is not None else MotionLimits()

    @property
    def commanded(self) -> tuple[float, float] | None:
        active = self.watchdog.active
        return None if active is None else active.target
