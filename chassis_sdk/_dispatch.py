"""Dispatch: telemetry fan-out and the pending-request table, shared by both devices.

Both are driven synchronously from the link's ``data_received`` (no task per chunk,
no task per message): publishing appends to each subscriber's buffer and wakes it;
resolving a request sets a future's result.
"""

from __future__ import annotations

import asyncio
import copy
import weakref
from collections import deque
from collections.abc import Coroutine, Hashable
from types import TracebackType
from typing import Any, Generic, TypeVar

__all__ = ["Broadcast", "RequestTable", "Subscription"]

T = TypeVar("T")
K = TypeVar("K", bound=Hashable)


class Subscription(Generic[T]):
    """One consumer's view of a stream: an async iterator with its own bounded buffer.

    Every message published after the subscription was created is delivered, in order,
    unless the consumer falls more than ``maxlen`` messages behind: then the oldest
    buffered message is dropped (and counted), so a slow consumer always sees the newest
    data and never holds more than ``maxlen`` messages in memory.

    Leaving an ``async for`` over it (``break``, ``return``, an exception) unsubscribes
    at once, even while the application still holds the subscription object: the loop
    iterates a small companion object that ends the subscription the moment the loop
    lets go of it (CPython frees it there, by reference count, not at some later
    garbage collection). A subscription is iterated by one ``async for``; iterating
    it again after leaving the loop ends at once. An abandoned subscription that was
    never iterated is gone as soon as nothing refers to it (the broadcast holds
    subscriptions weakly). ``async with`` or :meth:`close` unsubscribes explicitly.
    """

    __slots__ = ("__weakref__", "_broadcast", "_buffer", "_ended", "_error", "_waiter", "dropped")

    def __init__(self, broadcast: Broadcast[T], maxlen: int) -> None:
        self._broadcast = broadcast
        self._buffer: deque[T] = deque(maxlen=maxlen)
        self._waiter: asyncio.Future[None] | None = None
        self._error: BaseException | None = None
        self._ended = False
        #: Messages dropped from this subscription's buffer because it fell behind.
        self.dropped = 0

    def _push(self, item: T) -> None:
        buffer = self._buffer
        if len(buffer) == buffer.maxlen:
            self.dropped += 1
            self._broadcast.dropped += 1
        buffer.append(item)
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def _finish(self, error: BaseException | None) -> None:
        self._ended = True
        self._error = error
        waiter = self._waiter
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    def close(self) -> None:
        """Unsubscribe; a pending or later ``__anext__`` ends the iteration."""
        self._broadcast._discard(self)
        self._buffer.clear()
        self._finish(None)

    def __aiter__(self) -> _Iteration[T]:
        return _Iteration(self)

    async def __anext__(self) -> T:
        while True:
            if self._buffer:
                return self._buffer.popleft()
            if self._ended:
                if self._error is not None:
                    raise self._error
                raise StopAsyncIteration
            waiter = asyncio.get_running_loop().create_future()
            self._waiter = waiter
            try:
                await waiter
            finally:
                self._waiter = None

    async def __aenter__(self) -> Subscription[T]:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class _Iteration(Generic[T]):
    """What ``async for`` holds while it iterates a :class:`Subscription`; when the
    loop ends, however it ends, the loop drops it and it ends the subscription."""

    __slots__ = ("_next", "_sub")

    def __init__(self, sub: Subscription[T]) -> None:
        self._sub = sub
        self._next = sub.__anext__

    def __aiter__(self) -> _Iteration[T]:
        return self

    def __anext__(self) -> Coroutine[Any, Any, T]:
        return self._next()

    def __del__(self) -> None:
        self._sub.close()


class Broadcast(Generic[T]):
    """A stream with any number of subscribers; each gets every message.

    Args:
        maxlen: Per-subscriber buffer size (``queue_size`` of the device).
    """

    # Subscribers are held weakly (an abandoned iterator unsubscribes itself), as a
    # tuple of weak references rebuilt when one comes or goes: publishing, which runs
    # for every frame, is then one loop over a tuple, with nothing allocated. (A
    # WeakSet's iterator costs more than the whole decode at 50 Hz on an idle core.)
    __slots__ = ("__weakref__", "_closed", "_error", "_refs", "dropped", "maxlen")

    def __init__(self, maxlen: int) -> None:
        self.maxlen = maxlen
        self._refs: tuple[weakref.ref[Subscription[T]], ...] = ()
        self._closed = False
        self._error: BaseException | None = None
        #: Messages dropped across all subscribers because one fell behind.
        self.dropped = 0

    def __len__(self) -> int:
        return sum(1 for ref in self._refs if ref() is not None)

    def subscribe(self) -> Subscription[T]:
        """Return a new subscription; it receives everything published from now on.

        If the stream has failed (link lost, no reconnect), the subscription raises that
        error at once; if it has been closed, it ends at once.
        """
        sub = Subscription(self, self.maxlen)
        if self._closed:
            sub._finish(copy.copy(self._error))
        else:
            this = weakref.ref(self)

            def gone(ref: weakref.ref[Subscription[T]]) -> None:
                broadcast = this()
                if broadcast is not None:
                    broadcast._refs = tuple(r for r in broadcast._refs if r is not ref)

            self._refs = (*self._refs, weakref.ref(sub, gone))
        return sub

    def publish(self, item: T) -> None:
        """Deliver ``item`` to every subscriber (synchronous, never blocks)."""
        for ref in self._refs:
            sub = ref()
            if sub is not None:
                sub._push(item)

    def fail(self, error: BaseException | None) -> None:
        """End every subscription after its buffered items: with ``error`` raised, or,
        if it is ``None``, with a normal end of iteration. Later subscriptions end the
        same way at once, until :meth:`reopen`."""
        self._closed = True
        self._error = error
        subs = [sub for ref in self._refs if (sub := ref()) is not None]
        self._refs = ()
        for sub in subs:
            # One instance each: an exception raised in several tasks would collect
            # all their tracebacks.
            sub._finish(copy.copy(error))

    def reopen(self) -> None:
        """Accept subscribers again (after :meth:`fail`, on a new connection)."""
        self._closed = False
        self._error = None

    def _discard(self, sub: Subscription[T]) -> None:
        self._refs = tuple(ref for ref in self._refs if ref() is not sub)


class RequestTable(Generic[K, T]):
    """Futures waiting for replies, keyed by what the reply carries.

    Several waiters may share a key (protocol A replies carry no tag, so concurrent
    requests for the same reply id are answered in order): they queue, first in, first
    served. Protocol B keys are unique while in flight; :meth:`pending` lets the
    allocator skip ids in use.
    """

    __slots__ = ("_waiters",)

    def __init__(self) -> None:
        self._waiters: dict[K, deque[asyncio.Future[T]]] = {}

    def __len__(self) -> int:
        return sum(len(q) for q in self._waiters.values())

    def expect(self, key: K) -> asyncio.Future[T]:
        """Register a waiter for ``key`` and return its future."""
        fut: asyncio.Future[T] = asyncio.get_running_loop().create_future()
        self._waiters.setdefault(key, deque()).append(fut)
        return fut

    def pending(self, key: K) -> bool:
        """True if a waiter for ``key`` is registered."""
        return key in self._waiters

    def resolve(self, key: K, value: T) -> bool:
        """Give ``value`` to the oldest live waiter for ``key``.

        Returns:
            False if nobody was waiting (the caller counts it as unmatched).
        """
        queue = self._waiters.get(key)
        while queue:
            fut = queue.popleft()
            if not queue:
                del self._waiters[key]
            if not fut.done():
                fut.set_result(value)
                return True
            queue = self._waiters.get(key)
        return False

    def discard(self, key: K, fut: asyncio.Future[T]) -> None:
        """Remove a waiter (after its timeout or cancellation)."""
        queue = self._waiters.get(key)
        if queue is None:
            return
        try:
            queue.remove(fut)
        except ValueError:
            return
        if not queue:
            del self._waiters[key]

    def fail_all(self, error: BaseException) -> None:
        """Fail every waiter with ``error`` (the link is gone)."""
        waiters, self._waiters = self._waiters, {}
        for queue in waiters.values():
            for fut in queue:
                if not fut.done():
                    fut.set_exception(error)
