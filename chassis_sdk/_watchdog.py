"""The velocity watchdog and deadman, shared by both devices.

Why it exists
-------------
Both firmwares stop the wheels when no velocity command has arrived for a while (0.5 s):
a host that crashes must not leave the robot driving. So while a command is active the
host has to keep re-sending it, and it must stop re-sending when the application stops
asking, or a hung application would drive forever. This class does both:

* ``command()`` writes a frame at once and makes it the active command;
* ``run()`` (a background task) re-writes the active command every ``interval`` on an
  absolute schedule (no drift), and when the command expires (``command_timeout`` after
  the last call, or exactly ``duration`` after it) writes one zero frame and goes idle;
* ``stop()`` writes zero now; ``clear()`` forgets the command without writing (the link
  is gone: nothing can be written, and nothing must be resumed later).

Frames are built by callables so each resend gets a fresh sequence number.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from ._alarm import Alarm
from .errors import NotConnectedError

__all__ = ["MotionCommand", "VelocityWatchdog"]

FrameFactory = Callable[[], bytes]


@dataclass(slots=True)
class MotionCommand:
    """An active command: how to build it, how to build its zero, when it expires."""

    frame: FrameFactory
    zero: FrameFactory
    deadline: float
    description: str


class VelocityWatchdog:
    """Re-sends the active velocity command and zeroes it when it expires.

    Args:
        write: Writes one frame; raises :class:`NotConnectedError` when there is no link.
        interval: Resend period (s).
        command_timeout: Deadman (s) for commands without ``duration``; ``None`` holds
            them until :meth:`stop`.
        logger: Where expiries are logged.
        clock: Monotonic clock (replaceable in tests).
    """

    def __init__(
        self,
        write: Callable[[bytes], None],
        *,
        interval: float,
        command_timeout: float | None,
        logger: logging.Logger,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._write = write
        self.interval = interval
        self.command_timeout = command_timeout
        self._log = logger
        self._clock = clock
        self._active: MotionCommand | None = None
        self._next = 0.0
        self._alarm = Alarm()
        #: Frames re-sent by the background task (not counting the first write).
        self.resends = 0
        #: Commands that ran out (deadman or duration) and were zeroed.
        self.expiries = 0

    @property
    def active(self) -> MotionCommand | None:
        """The command being held, or ``None`` when idle."""
        return self._active

    def command(
        self, frame: FrameFactory, zero: FrameFactory, duration: float | None, description: str
    ) -> None:
        """Write ``frame()`` now and hold it until it expires.

        Args:
            frame: Builds the command frame (called for the first write and each resend).
            zero: Builds the matching zero-velocity frame.
            duration: Hold exactly this long (s); ``None`` for the deadman timeout.
            description: For log messages.
        """
        self._write(frame())  # raises before any state changes if not connected
        now = self._clock()
        if duration is not None:
            deadline = now + duration
        elif self.command_timeout is not None:
            deadline = now + self.command_timeout
        else:
            deadline = math.inf
        self._active = MotionCommand(frame, zero, deadline, description)
        self._next = now + self.interval
        self._alarm.wake()

    def stop(self, zero: FrameFactory) -> None:
        """Drop the active command and write a zero frame now."""
        self._active = None
        self._alarm.wake()
        self._write(zero())

    def clear(self) -> None:
        """Drop the active command without writing anything (the link is gone)."""
        self._active = None
        self._alarm.wake()

    async def run(self) -> None:
        """Background loop; runs until cancelled."""
        clock = self._clock
        while True:
            active = self._active
            if active is None:
                await self._alarm.sleep(None)
                continue
            now = clock()
            due = min(self._next, active.deadline)
            if now < due:
                await self._alarm.sleep(due - now)
                continue
            if now >= active.deadline:
                self._active = None
                self.expiries += 1
                self._log.debug("velocity command %s expired; writing zero", active.description)
                self._write_quietly(active.zero)
                continue
            self._next += self.interval
            if self._next <= now:  # the loop was blocked: skip the missed slots
                self._next = now + self.interval
            self.resends += 1
            self._write_quietly(active.frame)

    def _write_quietly(self, frame: FrameFactory) -> None:
        try:
            self._write(frame())
        except NotConnectedError:
            # The link dropped between two resends: the supervisor clears us; never
            # resume this command later.
            self._active = None
