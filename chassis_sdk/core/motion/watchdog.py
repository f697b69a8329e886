"""The velocity watchdog and deadman, shared by every device.

Why it exists
-------------
A robot base's firmware typically stops the wheels when no velocity command has arrived
for a while (its own deadman, often half a second): a host that crashes must not leave
the robot driving. So while a command is active the host has to keep re-sending it, and
it must stop re-sending when the application stops asking, or a hung application would
drive forever. This class does the two:

* ``command()`` makes a command the active one and writes its frame at once, or, if a
  velocity frame left less than `WRITE_PERIOD` ago, when that period is over (the newest
  command then: at most one velocity write per period, however fast commands come; a
  frame may come `WRITE_JITTER` early when the rate holds, so a control loop at the
  telemetry's 50 Hz is not delayed by its jitter);
* ``run()`` (a background task) re-writes the active command every ``interval`` on an
  absolute schedule (no drift), and when the command expires (``command_timeout`` after
  the last call, or exactly ``duration`` after it) writes one zero frame and goes idle.
  Its step is ``tick(now)``, due at ``due()``: decisions at a given time, no sleep;
* ``stop()`` writes zero now; ``clear()`` forgets the command without writing (the link
  is gone: nothing can be written, and nothing must be resumed later).

Optional `MotionLimits` shape what is *written*, never what was asked: the
target is clamped to the maximum speeds, and each write moves from the last written
value towards the target by at most acceleration (or deceleration, when slowing
towards zero) times the time since the last write, so a ramp advances at the resend
period or faster if the application calls faster. A stop is never ramped: ``stop()``,
the deadman, the end of a ``duration`` and the link going away all mean zero at once.

Frames are built by callables so each resend gets a fresh sequence number.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Literal

from ...errors import NotConnectedError
from ..alarm import Alarm
from ..validation import check_real
from .arbiter import WRITE_JITTER, WRITE_PERIOD

__all__ = ["MotionCommand", "MotionLimits", "VelocityWatchdog"]

FrameFactory = Callable[[], bytes]
#: Builds the frame for a pair of values: (linear, angular) or (left, right).
FrameBuilder = Callable[[float, float], bytes]
#: What the pair means: body velocities, or left and right wheel speeds.
Axes = Literal["velocity", "wheels"]


@dataclass(frozen=True, slots=True)
class MotionLimits:
    """Limits on what the watchdog writes; every one is optional (``None``: no limit).

    Attributes:
        max_linear: Largest linear speed written (m/s); also caps each side's speed in
            wheel mode.
        max_angular: Largest angular speed written (rad/s).
        linear_acceleration: Ramp rate away from zero (m/s²); wheel mode uses it per
            side.
        linear_deceleration: Ramp rate towards zero (m/s²); defaults to
            ``linear_acceleration``.
        angular_acceleration: Ramp rate away from zero (rad/s²).
        angular_deceleration: Ramp rate towards zero (rad/s²); defaults to
            ``angular_acceleration``.

    Raises:
        ValueError: A limit is not a finite number > 0.
    """

    max_linear: float | None = None
    max_angular: float | None = None
    linear_acceleration: float | None = None
    linear_deceleration: float | None = None
    angular_acceleration: float | None = None
    angular_deceleration: float | None = None

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None:
                continue
            check_real(value, f.name, low=0, low_open=True)

    def _axis(self, index: int, axes: Axes) -> tuple[float | None, float | None, float | None]:
        """(maximum, acceleration, deceleration) for value ``index`` of a command."""
        if axes == "wheels" or index == 0:
            accel = self.linear_acceleration
            decel = self.linear_deceleration or accel
            return self.max_linear, accel, decel
        accel = self.angular_acceleration
        return self.max_angular, accel, self.angular_deceleration or accel


def _clamp(value: float, limit: float | None) -> float:
    if limit is None:
        return value
    return max(-limit, min(limit, value))


def _ramp(
    current: float, goal: float, accel: float | None, decel: float | None, dt: float
) -> float:
    """One step from ``current`` towards ``goal``; slowing towards zero uses ``decel``
    and stops at zero for the step that would cross it."""
    if goal == current:
        return goal
    slowing = current != 0.0 and (goal - current) * current < 0
    rate = decel if slowing else accel
    if rate is None:
        return goal
    step = rate * dt
    nxt = current + max(-step, min(step, goal - current))
    if slowing and nxt * current < 0:
        return 0.0
    return nxt


@dataclass(slots=True)
class MotionCommand:
    """An active command: what was asked, how to build frames, when it expires."""

    target: tuple[float, float]
    build: FrameBuilder
    zero: FrameFactory
    deadline: float
    description: str
    axes: Axes = "velocity"


class VelocityWatchdog:
    """Re-sends the active velocity command and zeroes it when it expires.

    Args:
        write: Writes one velocity frame with the time (``clock()``) after which it is
            stale and must not be sent late (``math.inf`` for a zero frame); raises
            [`NotConnectedError`][chassis_sdk.NotConnectedError] when there is no link.
        interval: Resend period (s).
        command_timeout: Deadman (s) for commands without ``duration``; ``None`` holds
            them until `stop`.
        logger: Where expiries are logged.
        clock: Monotonic clock (replaceable in tests).
    """

    def __init__(
        self,
        write: Callable[[bytes, float], None],
        *,
        interval: float,
        command_timeout: float | None,
        logger: logging.Logger,
        limits: MotionLimits | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._write = write
        self.interval = interval
        self.command_timeout = command_timeout
        #: Limits applied to what is written (see :class:`MotionLimits`).
        self.limits = limits if limits is not None else MotionLimits()
        self._log = logger
        self._clock = clock
        self._active: MotionCommand | None = None
        #: The last values written for the active command (zero when idle).
        self.written: tuple[float, float] = (0.0, 0.0)
        self._last_write: float | None = None
        #: When the next velocity frame is due by the write period (GCRA's theoretical
        #: arrival time: every frame, a zero included, moves it one period on).
        self._slot = -math.inf
        #: The active command's first frame waits for the write period.
        self._deferred = False
        self._next = 0.0
        self._alarm = Alarm()
        #: Frames re-sent by the background task (not counting the first write).
        self.resends = 0
        #: Commands that ran out (deadman or duration) and were zeroed.
        self.expiries = 0
        #: Commands whose first frame waited for the write period (a faster caller).
        self.deferred = 0
        #: Whether any velocity frame (a zero included) was written.
        self.wrote = False
        #: Called at each resend with the time and how late the resend is (s), before
        #: writing: False if it ended the command (a reflex on a silent link);
        #: ``None``: nothing to check.
        self.guard: Callable[[float, float], bool] | None = None

    @property
    def active(self) -> MotionCommand | None:
        """The command being held, or ``None`` when idle."""
        return self._active

    def command(
        self,
        target: tuple[float, float],
        build: FrameBuilder,
        zero: FrameFactory,
        duration: float | None,
        description: str,
        axes: Axes = "velocity",
        *,
        age: float = 0.0,
    ) -> float:
        """Write towards ``target`` now (or at the end of the write period) and hold it
        until it expires.

        Args:
            target: The values asked for: (linear, angular) or (left, right).
            build: Builds the frame for a pair of values (each write calls it anew).
            zero: Builds the matching zero-velocity frame.
            duration: Hold exactly this long (s); ``None`` for the deadman timeout.
            description: For log messages.
            axes: What ``target`` holds, for the limits.
            age: How old the command already is (s): its deadline is that much sooner.

        Returns:
            The command's deadline (``clock()`` time; ``math.inf`` for none).
        """
        now = self._clock()
        deadline = self.deadline(duration, age, now)
        cmd = MotionCommand(target, build, zero, deadline, description, axes)
        earliest = self._slot - WRITE_JITTER
        if now < earliest:
            # Too soon after the last frame: this one (or a newer) goes at its slot.
            self._active = cmd
            if not self._deferred:
                self.deferred += 1
            self._deferred = True
            self._next = earliest
            self._alarm.wake()
            return deadline
        values = self._step(cmd, now)
        # Raises before any state changes if not connected.
        self._write(build(*values), deadline)
        self.written = values
        self._last_write = now
        self._sent(now)
        self._active = cmd
        self._deferred = False
        self._next = now + self.interval
        self._alarm.wake()
        return deadline

    def deadline(self, duration: float | None, age: float, now: float) -> float:
        """When a command given ``age`` s before ``now`` expires: after ``duration``,
        else after the deadman, else never (``math.inf``)."""
        if duration is not None:
            return now - age + duration
        if self.command_timeout is not None:
            return now - age + self.command_timeout
        return math.inf

    def stop(self, zero: FrameFactory) -> None:
        """Drop the active command and write a zero frame now (never ramped)."""
        self.clear()
        self._write(zero(), math.inf)
        self._sent(self._clock())

    def _sent(self, now: float) -> None:
        """A velocity frame was written at ``now``: the next is due one period on (a
        frame may come up to `WRITE_JITTER` early, as long as the rate holds)."""
        self._slot = max(self._slot, now) + WRITE_PERIOD
        self.wrote = True

    def clear(self) -> None:
        """Drop the active command without writing anything (the link is gone)."""
        self._active = None
        self._deferred = False
        self.written = (0.0, 0.0)
        self._last_write = None
        self._alarm.wake()

    def _step(self, cmd: MotionCommand, now: float) -> tuple[float, float]:
        """The values to write now for ``cmd``, within the limits."""
        limits = self.limits
        last = self._last_write
        # From rest, the first write is one resend period's worth of ramp.
        dt = self.interval if last is None else min(now - last, self.interval)
        out = []
        for i in (0, 1):
            maximum, accel, decel = limits._axis(i, cmd.axes)
            goal = _clamp(cmd.target[i], maximum)
            out.append(_ramp(self.written[i], goal, accel, decel, dt))
        return out[0], out[1]

    def due(self) -> float | None:
        """When (``clock()``) `tick` has something to do next: the next resend or
        the expiry, whichever comes first; ``None`` when idle."""
        active = self._active
        if active is None:
            return None
        return min(self._next, active.deadline)

    def tick(self, now: float) -> None:
        """Do what is due at ``now`` (the step of `run`, with the time given):
        write one zero and go idle if the command has expired, else re-write it if its
        resend is due; nothing before `due`."""
        active = self._active
        if active is None or now < min(self._next, active.deadline):
            return
        if now >= active.deadline:
            self.clear()
            self.expiries += 1
            self._log.debug("velocity command %s expired; writing zero", active.description)
            self._write_quietly(active.zero, math.inf)
            return
        guard = self.guard
        if guard is not None and not guard(now, now - self._next):
            return
        self._next += self.interval
        if self._next <= now:  # the loop was blocked: skip the missed slots
            self._next = now + self.interval
        if self._deferred:  # the command's first frame, held for the write period
            self._deferred = False
        else:
            self.resends += 1
        values = self._step(active, now)
        if self._write_quietly(functools.partial(active.build, *values), active.deadline):
            self.written = values
            self._last_write = now

    async def run(self) -> None:
        """Background loop; runs until cancelled: sleeps until `due` (or a new
        command or a stop), then `tick`."""
        clock = self._clock
        while True:
            due = self.due()
            if due is None:
                await self._alarm.sleep(None)
                continue
            now = clock()
            if now < due:
                await self._alarm.sleep(due - now)
                continue
            self.tick(now)

    def _write_quietly(self, frame: FrameFactory, expires: float) -> bool:
        try:
            self._write(frame(), expires)
            self._sent(self._clock())
        except NotConnectedError:
            # The link dropped between two resends: the supervisor clears us; never
            # resume this command later.
            self.clear()
            return False
        return True
