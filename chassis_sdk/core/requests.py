"""Requests and their replies: write, wait a bounded time, retry what may be retried,
and attribute every reply by the rule of `RequestTable`
(a late reply never answers a later call)."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable, Hashable
from typing import Any, Generic, TypeVar

from ..errors import NotConnectedError, RequestTimeoutError
from .dispatch import Reply, RequestTable

__all__ = ["Requester"]

K = TypeVar("K", bound=Hashable)


class Requester(Generic[K]):
    """One device's requests: the table of calls in flight and the retry loop.

    Args:
        port: For messages.
        write: Writes a frame (raises when the link cannot take it).
        ensure_open: Raises `NotConnectedError` unless a call may write now.
        timeout: Seconds per attempt.
        retries: Extra attempts of read-only requests.
        log: Where late and unmatched replies are logged.
    """

    def __init__(
        self,
        port: str,
        write: Callable[[bytes], None],
        ensure_open: Callable[[], None],
        *,
        timeout: float,
        retries: int,
        log: logging.Logger,
    ) -> None:
        self.port = port
        self.timeout = timeout
        self.retries = retries
        self.table: RequestTable[K, Any] = RequestTable(quarantine=timeout)
        self._write = write
        self._ensure_open = ensure_open
        self._log = log
        #: Replies nobody waited for, and replies to calls that had timed out.
        self.unmatched = 0
        self.late = 0

    def __len__(self) -> int:
        """Calls in flight."""
        return len(self.table)

    async def call(
        self, build: Callable[[], tuple[bytes, K]], *, read_only: bool, name: str
    ) -> Any:
        """Write a request and wait for its reply, retrying read-only requests.

        Args:
            build: Returns ``(frame, reply key)``; called per attempt, so each attempt
                gets a fresh sequence number or request id.
            read_only: Retry up to ``retries`` times on timeout.
            name: Names the request in errors.

        Raises:
            RequestTimeoutError: No attempt was answered in time.
            NotConnectedError, ConnectionLostError: The link is down or dropped.
        """
        attempts = self.retries + 1 if read_only else 1
        table = self.table
        table.max_latency = self.timeout * (self.retries + 1)
        key: K | None = None
        call: asyncio.Future[Any] | None = None
        try:
            for attempt in range(1, attempts + 1):
                self._ensure_open()
                frame, new_key = build()
                if call is None or new_key != key:
                    # A new key (a protocol with request ids allocates one per
                    # attempt) gives up the old; the same key (untagged replies) keeps
                    # the call, so a reply to an earlier attempt answers it.
                    if key is not None:
                        table.release(key)
                        key = None
                    call = await table.acquire(new_key)
                    key = new_key
                    self._ensure_open()
                self._write(frame)
                table.sent(key)
                # Unlike a cancel scope, this leaves the call's future intact for the
                # next attempt.
                if await table.wait(key, call, self.timeout):
                    return call.result()
                self._log.debug("%s: %s attempt %d timed out", self.port, name, attempt)
        finally:
            if key is not None:
                table.release(key)
        raise RequestTimeoutError(
            f"no reply to {name} from {self.port} within {self.timeout:g} s "
            f"({attempts} attempt{'s' if attempts > 1 else ''})"
        )

    def reply(self, key: K, msg: Any) -> None:
        """Attribute a reply that arrived for ``key``."""
        outcome = self.table.resolve(key, msg)
        if outcome is Reply.LATE:
            self.late += 1
            self._log.info("%s: late reply %r dropped (its request had timed out)", self.port, msg)
        elif outcome is Reply.UNMATCHED:
            self.unmatched += 1
            self._log.info("%s: unmatched reply %r", self.port, msg)

    def fail_all(self, error: BaseException | None) -> None:
        """Fail every call in flight with ``error`` (``None``: the device was closed)."""
        if error is None:
            error = NotConnectedError(f"{self.port} was closed")
        self.table.fail_all(error)
