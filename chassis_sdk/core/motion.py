"""The motion facet of a device: its velocity API over the
:class:`~chassis_sdk.core.watchdog.VelocityWatchdog` that keeps, resends, limits and
expires the active command."""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, TypeVar

import anyio.lowlevel

from .supervisor import LinkSupervisor
from .validation import check_duration
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


class Motion(abc.ABC):
    """``set_velocity``, ``stop``, ``limits`` and what was commanded and written.

    A device implements the two motion hooks, :meth:`_zero_frame` and
    :meth:`_velocity_builder`.
    """

    _watchdog: VelocityWatchdog
    _link: LinkSupervisor[Any]

    @abc.abstractmethod
    def _zero_frame(self) -> bytes:
        """A zero-velocity frame."""

    @abc.abstractmethod
    def _velocity_builder(self, linear: float, angular: float) -> FrameBuilder:
        """Check ``(linear, angular)`` (raises ``ValueError``) and return a builder of
        velocity frames for any values between zero and them."""

    async def set_velocity(
        self, linear: float, angular: float, *, duration: float | None = None
    ) -> None:
        """Drive with a linear (m/s) and angular (rad/s) velocity.

        The frame is written at once and re-sent every ``resend_interval``. Without
        ``duration`` it stays active until ``command_timeout`` after the *last* call
        (keep calling, as with ROS ``cmd_vel``); with ``duration`` it holds exactly that
        long. Then one zero frame is written. With :attr:`limits`, what is written is
        clamped and ramped towards the command; stopping is always immediate.

        Raises:
            ValueError: NaN, infinity, a value that overflows the wire field, or a bad
                ``duration``; nothing is written.
            NotConnectedError: The port is not open.
        """
        build = self._velocity_builder(linear, angular)
        duration = check_duration(duration)
        self._drive((linear, angular), build, duration, f"({linear}, {angular})", "velocity")
        await anyio.lowlevel.checkpoint()

    def _drive(
        self,
        target: tuple[float, float],
        build: FrameBuilder,
        duration: float | None,
        description: str,
        axes: Axes,
    ) -> None:
        self._link.writer.ensure_open()
        self._watchdog.command(target, build, self._zero_frame, duration, description, axes)

    @property
    def limits(self) -> MotionLimits:
        """The :class:`MotionLimits` applied to what is written; assign to change them
        (the next write uses the new ones)."""
        return self._watchdog.limits

    @limits.setter
    def limits(self, limits: MotionLimits | None) -> None:
        if limits is not None and not isinstance(limits, MotionLimits):
            raise ValueError(f"limits must be a MotionLimits or None, got {limits!r}")
        self._watchdog.limits = limits if limits is not None else MotionLimits()

    @property
    def commanded_velocity(self) -> tuple[float, float] | None:
        """The active command as asked: ``(linear, angular)`` (``(left, right)`` in
        wheel mode), or ``None`` when no command is active."""
        active = self._watchdog.active
        return None if active is None else active.target

    @property
    def written_velocity(self) -> tuple[float, float]:
        """What was last written for the active command, after limits and ramps
        (zeros when none is active)."""
        return self._watchdog.written

    async def stop(self) -> None:
        """Write zero velocity now and end the active command.

        Raises:
            NotConnectedError: The port is not open (the command is ended anyway).
        """
        self._watchdog.clear()
        self._link.writer.ensure_open()
        self._watchdog.stop(self._zero_frame)
        await anyio.lowlevel.checkpoint()
