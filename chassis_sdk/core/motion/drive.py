"""A device's motion: every command from every source passes the
[`Arbiter`][chassis_sdk.core.motion.Arbiter], and what it takes is held by the
`VelocityWatchdog` (resends, limits, the deadman, the write period).

The application's own calls (``robot.set_velocity``, ``robot.stop``) are the ``"api"``
source; a surface (a dashboard page, an MQTT sender, a ROS 2 writer, teleop) makes a
source of its own with ``robot.motion.source(...)`` and drives through it:

```python
source = robot.motion.source("web page 2", kind="web")
refusal = source.set_velocity(0.3, 0.0)   # None: taken; else a Refusal, counted
source.stop()                             # always acts
source.close()                            # gone: stops the robot if it was driving
```
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Iterable
from typing import TypeVar

from ...errors import MotionBlockedError, NotConnectedError
from ..alarm import Alarm
from ..refusals import Refusals
from ..validation import check_duration, check_real
from .arbiter import Arbiter, Refusal, Source
from .watchdog import Axes, FrameBuilder, MotionLimits, VelocityWatchdog

__all__ = ["Motion", "MotionSource", "frame_builder"]

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


class MotionSource:
    """A handle one source drives through, made by `Motion.source`.

    Its velocities pass the arbiter: taken (``None``) or refused (a `Refusal`, counted
    and logged as a summary); its stop always acts. A ``with`` block, or `close`,
    removes it (and stops the robot if it was driving).
    """

    __slots__ = ("_motion", "source")

    def __init__(self, motion: Motion, source: Source) -> None:
        self._motion = motion
        #: The arbiter's record of this source.
        self.source = source

    @property
    def name(self) -> str:
        """The source's unique name (``"web page 2"``)."""
        return self.source.name

    @property
    def driving(self) -> bool:
        """Whether this source holds the lease (its command is in force)."""
        return self._motion.arbiter.holder is self.source

    def set_velocity(
        self,
        linear: float,
        angular: float,
        *,
        duration: float | None = None,
        age: float = 0.0,
        take_over: bool = False,
    ) -> Refusal | None:
        """Offer a velocity (m/s, rad/s); it holds for ``duration``, else the deadman,
        both counted from when it was given (``age`` s ago).

        Returns:
            ``None`` if it was taken; the `Refusal` if not (blocked, another source
            drives, a neutral is owed, or it is older than its deadman).

        Raises:
            TypeError, ValueError: A bad value; nothing is written.
            NotConnectedError: The port is not open.
        """
        return self._motion.offer(
            self.source,
            linear,
            angular,
            duration=duration,
            age=age,
            take_over=take_over,
        )

    def stop(self) -> None:
        """End the command in force, whoever gave it, and write zero now.

        Raises:
            NotConnectedError: The port is not open (the command is ended anyway).
        """
        self._motion.stop(self.source)

    def close(self) -> None:
        """Remove this source; if it was driving, the robot stops (quietly when the
        port is closed)."""
        if self.source.closed:
            return
        if self._motion.arbiter.remove(self.source):
            self._motion.halt()

    def __enter__(self) -> MotionSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"<MotionSource {self.name!r}>"


class Motion:
    """A device's motion: the arbiter every source passes, and the `VelocityWatchdog`
    that keeps, resends, limits and expires what it takes.

    Args:
        write_velocity: Writes a velocity frame (``frame, expires``).
        ensure_open: Raises ``NotConnectedError`` if the port is not open.
        zero_frame: Makes a zero-velocity frame.
        velocity_builder: Checks ``(linear, angular)`` (raises ``ValueError``) and
            returns the builder of its frames.
        interval: Resend period (s).
        command_timeout: The deadman (s), or ``None``.
        logger: For the watchdog's messages and the summaries of refusals.
        clock: Monotonic clock (injected in tests).
    """

    def __init__(
        self,
        write_velocity: Callable[[bytes, float], None],
        ensure_open: Callable[[], None],
        zero_frame: Callable[[], bytes],
        velocity_builder: Callable[[float, float], FrameBuilder],
        *,
        interval: float,
        command_timeout: float | None,
        logger: logging.Logger,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.watchdog = VelocityWatchdog(
            write_velocity,
            interval=interval,
            command_timeout=command_timeout,
            logger=logger,
            clock=clock,
        )
        #: Decides which source's command acts (see `Arbiter`).
        self.arbiter = Arbiter(clock=clock, quiet=command_timeout)
        self._ensure_open = ensure_open
        self._zero_frame = zero_frame
        self._builder = velocity_builder
        self._log = logger
        self._clock = clock
        #: Refusals, for the log: the first at once, then a summary a second.
        self.refusals = Refusals(1.0, clock=clock)
        self._limits = MotionLimits()
        self._caps: dict[str, float] = {}
        #: Woken whenever what blocks motion changes.
        self.blocks_changed = Alarm()
        #: Whether closing the device writes a zero even if it never wrote a velocity
        #: (True, the default: the robot is left stopped whatever moved it). A surface
        #: that only lets its clients stop (a read-only dashboard) sets False, so it
        #: writes nothing a client did not ask for.
        self.zero_on_close = True
        #: The application's own calls (``robot.set_velocity``...), a one-shot source.
        self.api = MotionSource(self, self.arbiter.add("api", "api", streaming=False))

    # --- sources -----------------------------------------------------------------------------

    def source(self, name: str, *, kind: str, streaming: bool = True) -> MotionSource:
        """A new source to drive through (its name made unique: ``"web page 2"``).

        Args:
            name: For refusals and logs (``"web page"``, ``"ros2 cmd_vel"``).
            kind: Its kind, which sets its priority (`priorities`): ``"teleop"``,
                ``"gamepad"``, ``"web"``, ``"foxglove"``, ``"api"``, ``"goal"``,
                ``"ros2"``, ``"mqtt"``, or another (priority 0 unless set).
            streaming: It repeats its command (a stick, a ``cmd_vel`` publisher): after
                a block it must send a neutral before it drives again.
        """
        return MotionSource(self, self.arbiter.add(name, kind, streaming=streaming))

    @property
    def priorities(self) -> dict[str, int]:
        """Kind -> priority, higher wins the lease; change it at any time."""
        return self.arbiter.priorities

    @property
    def blocks(self) -> tuple[str, ...]:
        """What blocks motion now (``("HARDWARE_ESTOP",)``), empty when free."""
        return self.arbiter.blocks

    @property
    def driver(self) -> str | None:
        """The name of the source whose command is in force, or ``None``."""
        holder = self.arbiter.holder
        return None if holder is None else holder.name

    def check_open(self) -> None:
        """Raise ``NotConnectedError`` unless the port is open."""
        self._ensure_open()

    # --- commands ----------------------------------------------------------------------------

    def offer(
        self,
        source: Source,
        a: float,
        b: float,
        *,
        duration: float | None = None,
        age: float = 0.0,
        take_over: bool = False,
        build: FrameBuilder | None = None,
        axes: Axes = "velocity",
    ) -> Refusal | None:
        """``source``'s command ``(a, b)`` through the arbiter (see `MotionSource.set_velocity`);
        ``build`` makes its frames (default: the device's velocity frames)."""
        if build is None:
            build = self._builder(a, b)
        duration = check_duration(duration)
        age = check_real(age, "age", low=0, unit="s")
        self._ensure_open()
        watchdog = self.watchdog
        hold = duration if duration is not None else watchdog.command_timeout
        if hold is not None and age >= hold:
            return self._refused(
                self.arbiter.stale(
                    source, f"the command is {age:.3f} s old, more than its {hold:g} s"
                )
            )
        verdict = self.arbiter.velocity(source, neutral=a == 0 and b == 0, take_over=take_over)
        if verdict is False:
            return None
        if verdict is not True:
            return self._refused(verdict)
        description = f"({a}, {b}) from {source.name}"
        zero = self._zero_frame
        deadline = watchdog.command((a, b), build, zero, duration, description, axes, age=age)
        self.arbiter.granted(source, deadline)
        return None

    def drive(
        self,
        a: float,
        b: float,
        build: FrameBuilder,
        duration: float | None,
        axes: Axes,
    ) -> None:
        """The application's command (the ``"api"`` source); a refusal raises.

        Raises:
            MotionBlockedError: Motion is blocked, or another source drives.
            NotConnectedError: The port is not open.
        """
        refusal = self.offer(self.api.source, a, b, duration=duration, build=build, axes=axes)
        if refusal is not None:
            reasons = refusal.blocks if refusal.reason == "blocked" else ("DRIVEN",)
            raise MotionBlockedError(f"velocity refused: {refusal.detail}", reasons)

    def stop(self, source: Source | None = None) -> None:
        """End the command in force and write zero now (raises ``NotConnectedError`` if
        the port is not open, after ending the command)."""
        self.arbiter.stop(source if source is not None else self.api.source)
        self.watchdog.clear()
        self._ensure_open()
        self.watchdog.stop(self._zero_frame)

    def halt(self) -> None:
        """End the command in force and write zero if the port is open (never raises:
        a block began, a driving source went away)."""
        self.arbiter.stop()
        had = self.watchdog.active is not None
        self.watchdog.clear()
        if had:
            try:
                self._ensure_open()
                self.watchdog.stop(self._zero_frame)
            except NotConnectedError:
                pass

    def set_blocks(self, origin: str, reasons: Iterable[str]) -> None:
        """What ``origin`` says blocks motion now (see `Arbiter.set_blocks`); a block that
        begins ends the command in force."""
        before = self.arbiter.blocks
        if self.arbiter.set_blocks(origin, reasons):
            self._log.info("motion blocked by %s", ", ".join(self.arbiter.blocks))
            self.halt()
        if self.arbiter.blocks != before:
            self.blocks_changed.wake()

    def _refused(self, refusal: Refusal) -> Refusal:
        if refusal.source == self.api.name:
            return refusal  # the application's own call raises instead
        report = self.refusals.add(refusal.source, refusal.detail)
        if report is not None:
            self._log.warning("velocity refused: %s", report.summary())
        return refusal

    @property
    def limits(self) -> MotionLimits:
        """The device's limits, as set (the caps of `set_cap` are not in them)."""
        return self._limits

    @limits.setter
    def limits(self, limits: MotionLimits | None) -> None:
        if limits is not None and not isinstance(limits, MotionLimits):
            raise TypeError(f"limits must be a MotionLimits or None, got {limits!r}")
        self._limits = limits if limits is not None else MotionLimits()
        self._apply_limits()

    def set_cap(self, origin: str, speed: float | None) -> None:
        """Cap every command's linear speed at ``speed`` (m/s) for ``origin`` (a
        reflex's ``slow``), or lift ``origin``'s cap (``None``); the lowest cap holds,
        and the angular speed is capped in proportion (``speed`` over half a metre)."""
        if speed is None:
            self._caps.pop(origin, None)
        else:
            self._caps[origin] = speed
        self._apply_limits()

    def _apply_limits(self) -> None:
        limits = self._limits
        if self._caps:
            cap = min(self._caps.values())
            linear = cap if limits.max_linear is None else min(cap, limits.max_linear)
            angular = cap / 0.5
            if limits.max_angular is not None:
                angular = min(angular, limits.max_angular)
            limits = dataclasses.replace(limits, max_linear=linear, max_angular=angular)
        self.watchdog.limits = limits

    @property
    def commanded(self) -> tuple[float, float] | None:
        """The command in force as asked, or ``None``."""
        active = self.watchdog.active
        return None if active is None else active.target
