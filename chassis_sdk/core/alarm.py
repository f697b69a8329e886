"""A sleep that can be cut short, shared by the watchdog and the simulators' clocks, and
the bound past which a timer's lateness says the host's own loop was held up."""

from __future__ import annotations

import asyncio
from typing import Final

__all__ = ["LOOP_STALL", "Alarm"]

#: A timer this late (s) says the host's loop was held up, not that the device fell
#: silent: the frames that came meanwhile wait, unread, in the kernel. A judge of
#: silence that wakes this late looks again before it concludes (the link's health,
#: the link reflex).
LOOP_STALL: Final = 0.05


class Alarm:
    """Sleep until a delay passes or `wake` is called, whichever comes first.

    One future and one timer handle per sleep: lighter and more punctual than
    ``asyncio.wait_for(event.wait(), ...)``, which creates a task each time (and, on
    Python 3.11, can swallow a cancellation that races with the event).
    """

    __slots__ = ("_waiter",)

    def __init__(self) -> None:
        self._waiter: asyncio.Future[None] | None = None

    def wake(self, *_: object) -> None:
        """End the current sleep, if any (a wake with nobody asleep is not remembered)."""
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def sleep(self, delay: float | None) -> None:
        """Sleep ``delay`` seconds (forever if ``None``) or until `wake`."""
        loop = asyncio.get_running_loop()
        self._waiter = waiter = loop.create_future()
        handle = None if delay is None else loop.call_later(delay, self.wake)
        try:
            await waiter
        finally:
            self._waiter = None
            if handle is not None:
                handle.cancel()
