"""A sleep that can be cut short, shared by the watchdog and the simulators' clocks."""

from __future__ import annotations

import asyncio

__all__ = ["Alarm"]


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
