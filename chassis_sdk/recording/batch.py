"""Recording work done after the frame's own: `AfterFrame`, which both recorders
(the Foxglove sink and the rosbag2 recorder) use.

A recorder hears of a frame synchronously, in the link's ``data_received``, before the
application's tasks woken by the same frame have run. Serialising and writing there
would delay them, so the work is queued and done in one batch two loop hops later: the
tasks the frame woke are queued behind the first hop and run before the batch.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any

__all__ = ["AfterFrame"]

_log = logging.getLogger("chassis_sdk.recording")


class AfterFrame:
    """Work queued now and done in one batch after the loop's current callbacks.

    Args:
        what: Names the recording in the log, should a piece of work fail.

    Without a running loop (converting a file), work is done at once.
    """

    def __init__(self, what: str) -> None:
        self.what = what
        self._pending: list[tuple[Callable[..., None], tuple[Any, ...]]] = []
        self._closed = False
        self._loop: asyncio.AbstractEventLoop | None
        try:
            self._loop = asyncio.get_running_loop()
        except RuntimeError:
            self._loop = None

    def later(self, work: Callable[..., None], *args: Any) -> None:
        """Queue ``work(*args)`` (dropped once `close` was called)."""
        if self._closed:
            return
        pending = self._pending
        pending.append((work, args))
        if self._loop is None:
            self.drain()
        elif len(pending) == 1:
            # Two hops: the tasks this frame wakes are queued behind the first, so
            # they run before the drain.
            self._loop.call_soon(self._loop.call_soon, self.drain)

    def drain(self) -> None:
        """Do what is queued now; a piece of work that fails is logged, never raised (a
        recording must never take the device down)."""
        batch, self._pending = self._pending, []
        for work, args in batch:
            try:
                work(*args)
            except Exception:
                _log.exception("recording %s: cannot write a message", self.what)

    def close(self) -> None:
        """Do what is queued, then take no more."""
        self.drain()
        self._closed = True
