"""Dispatch: stream fan-out and the pending-request table, shared by every device.

Both are driven synchronously from the link's ``data_received`` (no task per chunk,
no task per message): publishing appends to each subscriber's buffer and wakes it;
resolving a request sets a future's result.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import enum
import functools
import logging
import time
import weakref
from collections import deque
from collections.abc import Callable, Coroutine, Hashable
from dataclasses import dataclass
from types import TracebackType
from typing import TYPE_CHECKING, Any, Generic, TypeVar

import anyio

from ..errors import NotConnectedError, RequestTimeoutError
from .validation import check_real

__all__ = [
    "SLOW_CALLBACK",
    "SLOW_SUMMARY_INTERVAL",
    "Broadcast",
    "Listener",
    "ListenerStats",
    "Reply",
    "RequestTable",
    "Streams",
    "Subscription",
    "first_match",
]

_log = logging.getLogger("chassis_sdk")
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
    subscriptions weakly). ``async with`` or `close` unsubscribes explicitly.
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

    def __anext__(self) -> Coroutine[Any, Any, T]:
        return _next(self)

    @property
    def _sub(self) -> Subscription[T]:
        """Itself, as `_next` reads it (an `_Iteration`'s is its subscription)."""
        return self

    async def __aenter__(self) -> Subscription[T]:
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


#: How long a listener's callback may take, seconds, before it is reported as slow
#: (the default of ``slow=`` in [`Notifier.listen`][chassis_sdk.core.notifier.Notifier.listen]).
#: Callbacks run in the read path: at 50 Hz per stream, a millisecond is already 5 % of
#: the loop for one stream, and every message behind it waits.
SLOW_CALLBACK = 0.001
#: After a slow callback's first warning, at most one summary of its further slow calls
#: is logged per this many seconds (so a callback slow on every frame cannot flood the
#: log); its stats count every one.
SLOW_SUMMARY_INTERVAL = 10.0


@dataclass(frozen=True, slots=True)
class ListenerStats:
    """What one listener's callback has cost, as [`Listener.stats`][chassis_sdk.Listener.stats]
    reports it (a snapshot; times in seconds).

    Attributes:
        stream: The stream's name (``"telemetry"``, ...), if known.
        callback: The callback's name (its ``__qualname__``, else its ``repr``).
        calls: Messages it was called with.
        total: Time spent in it over all calls.
        max: Its longest call.
        slow: Calls that took longer than ``bound``.
        bound: The time past which a call is slow.
        error: What it raised, which removed it; ``None`` while it never raised.
    """

    stream: str | None
    callback: str
    calls: int
    total: float
    max: float
    slow: int
    bound: float
    error: BaseException | None

    @property
    def mean(self) -> float:
        """The mean time of a call, seconds (0 before the first)."""
        return self.total / self.calls if self.calls else 0.0


def _name(callback: Callable[..., object]) -> str:
    if isinstance(callback, functools.partial):
        return f"partial({_name(callback.func)})"
    name = getattr(callback, "__qualname__", None)
    return name if isinstance(name, str) else repr(callback)


class Listener(Generic[T]):
    """A synchronous subscriber: ``callback(item)`` runs inside `Broadcast.publish`
    (in wire order, nothing buffered, no task woken), so it runs in the device's read
    path and must be quick. For recorders, bridges and live sinks, which must see every
    message and cost nothing when absent. Held weakly, as subscriptions are: keep it
    (a [`Notifier`][chassis_sdk.core.notifier.Notifier] keeps its own), and `close` it
    to stop listening. A stream that fails (the link lost) does not end it: it is not
    an iteration that could end.

    A callback that raises is removed at once: it gets nothing more, the error is
    logged once (with its traceback, the callback's name and the stream's) and kept in
    ``error``, and the other listeners and subscribers still get that message; the link
    goes on. ``KeyboardInterrupt`` and ``SystemExit`` are not the callback's fault and
    are not caught: they go on up, as asyncio lets them. Any other ``BaseException``
    (a ``CancelledError`` from a future the callback looked at, a ``GeneratorExit``)
    is the callback's failure, handled as above: the read path has no task of the
    callback's to cancel, and letting it out would end the link.

    Every call is timed: `stats` gives the calls, the total and longest time, and the
    calls slower than the bound (``slow``, ``SLOW_CALLBACK`` = 1 ms by default). The
    first slow call logs a warning naming the callback, its time and the bound; later
    ones, at most one summary per ``SLOW_SUMMARY_INTERVAL`` (10 s).

    Attributes:
        stream: The stream's name, if known (for the log and `stats`).
        error: What the callback raised, which removed it; ``None`` until then.
    """

    __slots__ = (
        "__weakref__",
        "_bound",
        "_broadcast",
        "_callback",
        "_calls",
        "_joined",
        "_max",
        "_pending",
        "_pending_max",
        "_slow",
        "_total",
        "_warned_at",
        "_watch",
        "error",
        "stream",
    )

    def __init__(
        self,
        broadcast: Broadcast[T],
        callback: Callable[[T], None],
        *,
        slow: float = SLOW_CALLBACK,
        stream: str | None = None,
    ) -> None:
        self._broadcast = broadcast
        self._callback = callback
        self.stream = stream
        self.error: BaseException | None = None
        # Calls are counted by the broadcast, once per publish, not once per listener:
        # this one's are those since it joined (frozen in ``_calls`` when it leaves).
        self._joined = broadcast._publishes
        self._calls: int | None = None
        self._total = 0.0
        self._max = 0.0
        self._slow = 0
        # Publishing looks further only at a call longer than this: min(max, bound),
        # so one comparison per call keeps both the maximum and the slow count.
        self._watch = 0.0
        self._bound = 0.0
        self._set_bound(slow)
        self._warned_at: float | None = None
        self._pending = 0
        self._pending_max = 0.0

    @property
    def callback(self) -> Callable[[T], None]:
        """The callback this listener calls."""
        return self._callback

    @property
    def closed(self) -> bool:
        """Whether it no longer listens: closed, or removed because its callback raised."""
        return self._calls is not None

    @property
    def stats(self) -> ListenerStats:
        """What its callback has cost so far (see [`ListenerStats`][chassis_sdk.ListenerStats])."""
        calls = self._calls
        return ListenerStats(
            stream=self.stream,
            callback=_name(self._callback),
            calls=self._broadcast._publishes - self._joined if calls is None else calls,
            total=self._total,
            max=self._max,
            slow=self._slow,
            bound=self._bound,
            error=self.error,
        )

    def close(self) -> None:
        """Stop listening, from the next message published (one closed by another
        callback during a publish still gets that message); safe to call again."""
        if self._calls is None:
            self._calls = self._broadcast._publishes - self._joined
            self._broadcast._discard_listener(self)

    def _set_bound(self, slow: float) -> None:
        self._bound = check_real(slow, "slow", low=0, low_open=True, unit="s")
        self._watch = min(self._max, self._bound)

    def _where(self) -> str:
        return _name(self._callback) + ("" if self.stream is None else f" on {self.stream!r}")

    def _failed(self, error: BaseException) -> None:
        """Its callback raised ``error``: remove it, keep and count the error, log it."""
        self.close()
        self.error = error
        self._broadcast.listener_errors += 1
        _log.error(
            "listener %s raised %s and was removed (it gets no more messages)",
            self._where(),
            type(error).__name__,
            exc_info=error,
        )

    def _timed(self, took: float, now: float) -> None:
        """A call took ``took`` s, more than ``_watch``; ``now`` is the clock's."""
        if took > self._max:
            self._max = took
        bound = self._bound
        self._watch = min(self._max, bound)
        if took <= bound:
            return
        self._slow += 1
        if self._warned_at is None:
            self._warned_at = now
            _log.warning(
                "listener %s took %.2f ms, over its bound of %g ms: callbacks run in the "
                "read path, so every message behind it waits (hand slow work off with "
                "loop.call_soon or a queue)",
                self._where(),
                took * 1e3,
                bound * 1e3,
            )
            return
        self._pending += 1
        self._pending_max = max(self._pending_max, took)
        since = now - self._warned_at
        if since >= SLOW_SUMMARY_INTERVAL:
            _log.warning(
                "listener %s: %d more calls over %g ms in the last %.1f s (the longest %.2f ms)",
                self._where(),
                self._pending,
                bound * 1e3,
                since,
                self._pending_max * 1e3,
            )
            self._warned_at = now
            self._pending = 0
            self._pending_max = 0.0


async def _next(holder: Subscription[T] | _Iteration[T]) -> T:
    """The next message of ``holder._sub``: what ``anext(subscription)`` awaits, and,
    as `_Iteration.__anext__` itself, what every step of an ``async for`` awaits, with
    no Python call before the coroutine (a method returning one would be a call per
    message)."""
    sub = holder._sub
    # A traceback through this frame (a cancelled or timed-out loop) keeps its locals:
    # it must not keep the _Iteration, whose collection ends the subscription at once.
    del holder
    while True:
        if sub._buffer:
            return sub._buffer.popleft()
        if sub._ended:
            if sub._error is not None:
                raise sub._error
            raise StopAsyncIteration
        waiter = asyncio.get_running_loop().create_future()
        sub._waiter = waiter
        try:
            await waiter
        finally:
            sub._waiter = None


class _Iteration(Generic[T]):
    """What ``async for`` holds while it iterates a `Subscription`; when the
    loop ends, however it ends, the loop drops it and it ends the subscription."""

    __slots__ = ("_sub",)

    def __init__(self, sub: Subscription[T]) -> None:
        self._sub = sub

    def __aiter__(self) -> _Iteration[T]:
        return self

    if TYPE_CHECKING:

        def __anext__(self) -> Coroutine[Any, Any, T]: ...

    else:
        __anext__ = _next

    def __del__(self) -> None:
        self._sub.close()


class Broadcast(Generic[T]):
    """A stream with any number of subscribers, each of which gets every message, and
    the latest message (``latest``: kept across reconnects, ``None`` before the first).

    Args:
        maxlen: Per-subscriber buffer size (``queue_size`` of the device).
        name: The stream's name, for its listeners' log lines and stats.
        clock: What times listeners' callbacks: seconds, monotonic (replaceable in
            tests).
    """

    # Subscribers and listeners are held weakly (an abandoned iterator unsubscribes
    # itself), as tuples of weak references rebuilt when one comes or goes: publishing,
    # which runs for every frame, is then a loop over a tuple, with nothing allocated
    # (a WeakSet's iterator costs more than a whole decode: docs/figures.md).
    __slots__ = (
        "__weakref__",
        "_clock",
        "_closed",
        "_error",
        "_listeners",
        "_publishes",
        "_refs",
        "dropped",
        "latest",
        "listened",
        "listener_errors",
        "maxlen",
        "name",
    )

    def __init__(
        self,
        maxlen: int,
        *,
        name: str | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.maxlen = maxlen
        self.name = name
        self._clock = clock
        self._refs: tuple[weakref.ref[Subscription[T]], ...] = ()
        self._listeners: tuple[weakref.ref[Listener[T]], ...] = ()
        self._publishes = 0  # (that had listeners: how listeners count their calls)
        self._closed = False
        self._error: BaseException | None = None
        #: Messages dropped across all subscribers because one fell behind.
        self.dropped = 0
        #: Listeners removed because their callback raised.
        self.listener_errors = 0
        #: The latest message published, or ``None``.
        self.latest: T | None = None
        #: Whether anyone subscribes or listens (so a message is worth building): a
        #: plain attribute, kept by every change of the members (read on every frame).
        self.listened = False

    def __len__(self) -> int:
        subs = sum(1 for ref in self._refs if ref() is not None)
        return subs + sum(1 for ref in self._listeners if ref() is not None)

    def subscribe(self) -> Subscription[T]:
        """Return a new subscription; it receives everything published from now on.

        If the stream has failed (link lost, no reconnect), the subscription raises that
        error at once; if it has been closed, it ends at once.
        """
        sub = Subscription(self, self.maxlen)
        if self._closed:
            sub._finish(copy.copy(self._error))
        else:
            self._add(sub)
        return sub

    def listen(
        self,
        callback: Callable[[T], None],
        *,
        slow: float = SLOW_CALLBACK,
        stream: str | None = None,
    ) -> Listener[T]:
        """Call ``callback(item)`` synchronously for every item published from now on,
        until the returned `Listener` is closed or dropped, or the callback raises.

        Args:
            callback: Called with each item, inside `publish`.
            slow: Seconds past which a call is reported as slow.
            stream: The stream's name for the log and the stats (this broadcast's
                ``name`` if not given).

        Raises:
            ValueError: ``slow`` is not a finite number > 0.
        """
        listener = Listener(
            self, callback, slow=slow, stream=self.name if stream is None else stream
        )
        self._hold(listener, "_listeners")
        return listener

    def _add(self, sub: Subscription[T]) -> None:
        self._hold(sub, "_refs")

    def _hold(self, member: Subscription[T] | Listener[T], where: str) -> None:
        """Add a weak reference to ``member`` to the tuple attribute ``where``; it
        removes itself from there when ``member`` is collected."""
        this = weakref.ref(self)

        def gone(ref: weakref.ref[Any]) -> None:
            broadcast = this()
            if broadcast is not None:
                broadcast._set(where, tuple(r for r in getattr(broadcast, where) if r is not ref))

        self._set(where, (*getattr(self, where), weakref.ref(member, gone)))

    def _set(self, where: str, members: tuple[weakref.ref[Any], ...]) -> None:
        """Replace the members in ``where`` (``_refs`` or ``_listeners``)."""
        setattr(self, where, members)
        self.listened = bool(self._refs or self._listeners)

    def publish(self, item: T) -> None:
        """Deliver ``item`` to every listener and subscriber (synchronous, never
        blocks). A listener whose callback raises is removed (see `Listener`); the
        rest still get ``item``."""
        self.latest = item
        listeners = self._listeners
        if listeners:
            # One clock read per call, chained (each call's end is the next one's
            # start), and one comparison: what Listener._timed does is rare. Floats,
            # not perf_counter_ns: their freelist makes them the cheaper.
            self._publishes += 1
            clock = self._clock
            start = clock()
            for ref in listeners:
                listener = ref()
                if listener is not None:
                    try:
                        listener._callback(item)
                    except (KeyboardInterrupt, SystemExit):
                        raise
                    except BaseException as error:  # the callback's failure: see Listener
                        listener._failed(error)
                    end = clock()
                    took = end - start
                    start = end
                    listener._total += took
                    if took > listener._watch:
                        listener._timed(took, end)
        for sub_ref in self._refs:
            sub = sub_ref()
            if sub is not None:  # into its buffer (the oldest dropped when full)
                buffer = sub._buffer
                if len(buffer) == buffer.maxlen:
                    sub.dropped += 1
                    self.dropped += 1
                buffer.append(item)
                waiter = sub._waiter
                if waiter is not None and not waiter.done():
                    waiter.set_result(None)

    def fail(self, error: BaseException | None) -> None:
        """End every subscription after its buffered items: with ``error`` raised, or,
        if it is ``None``, with a normal end of iteration. Later subscriptions end the
        same way at once, until `reopen`. Listeners stay (they are not
        iterations that could end)."""
        self._closed = True
        self._error = error
        subs = [sub for ref in self._refs if (sub := ref()) is not None]
        self._set("_refs", ())
        for sub in subs:
            # One instance each: an exception raised in several tasks would collect
            # all their tracebacks.
            sub._finish(copy.copy(error))

    def reopen(self) -> None:
        """Accept subscribers again (after `fail`, on a new connection)."""
        self._closed = False
        self._error = None

    def _discard(self, sub: Subscription[T]) -> None:
        self._set("_refs", tuple(ref for ref in self._refs if ref() is not sub))

    def _discard_listener(self, listener: Listener[T]) -> None:
        self._set("_listeners", tuple(ref for ref in self._listeners if ref() is not listener))


async def first_match(
    stream: Broadcast[T],
    subscribe: Callable[[Broadcast[T]], Subscription[T]],
    predicate: Callable[[T], bool],
    timeout: float,
    what: str,
    port: str,
) -> T:
    """The latest message of ``stream`` if it satisfies ``predicate``, else the next
    one that does (read through ``subscribe(stream)``, made before the latest is looked
    at, so nothing in between is missed); ``what`` and ``port`` are for the errors.

    Raises:
        RequestTimeoutError: None did within ``timeout`` seconds (a
            [`ChassisError`][chassis_sdk.ChassisError] that is also a `TimeoutError`).
        ValueError: ``timeout`` is not a finite number > 0.
        NotConnectedError: The device was closed meanwhile.
    """
    timeout = check_real(timeout, "timeout", low=0, low_open=True, unit="s")
    async with subscribe(stream) as items:
        latest = stream.latest
        if latest is not None and predicate(latest):
            return latest
        with anyio.move_on_after(timeout):
            async for item in items:
                if predicate(item):
                    return item
            raise NotConnectedError(f"{port} was closed while waiting")
    raise RequestTimeoutError(f"{port}: no {what} satisfied the condition in {timeout:g} s")


class Streams:
    """Every stream of one device: made alike, reopened on connect, ended together."""

    __slots__ = ("_all", "maxlen", "named")

    def __init__(self, maxlen: int) -> None:
        self.maxlen = maxlen
        self._all: list[Broadcast[Any]] = []
        #: The streams made with a name (what recorders and live views publish).
        self.named: dict[str, Broadcast[Any]] = {}

    def new(self, name: str | None = None) -> Broadcast[Any]:
        """A new stream of this device; ``name`` (its method's name, such as
        ``"telemetry"``) makes it a topic of recordings and live views."""
        stream: Broadcast[Any] = Broadcast(self.maxlen, name=name)
        self._all.append(stream)
        if name is not None:
            if name in self.named:
                raise ValueError(f"two streams named {name!r}")
            self.named[name] = stream
        return stream

    def reopen(self) -> None:
        """Accept subscribers again (on connect)."""
        for stream in self._all:
            stream.reopen()

    def fail(self, error: BaseException | None) -> None:
        """End every subscription of every stream (see `Broadcast.fail`)."""
        for stream in self._all:
            stream.fail(error)

    @property
    def dropped(self) -> int:
        """Messages dropped by subscribers that fell behind, over every stream."""
        return sum(stream.dropped for stream in self._all)


class Reply(enum.Enum):
    """What `RequestTable.resolve` made of a reply."""

    MATCHED = "matched"  #: given to the call waiting for it
    LATE = "late"  #: the answer to a request whose call already gave up: dropped
    UNMATCHED = "unmatched"  #: nobody asked for it


class _Slot(Generic[T]):
    """One key's state: the call holding it, its replies in flight, who waits for it."""

    __slots__ = ("call", "quarantine_until", "queue", "sent_at", "waiter")

    def __init__(self) -> None:
        self.call: asyncio.Future[T] | None = None
        #: The task waiting for ``call`` (see :meth:`RequestTable.wait`), woken directly.
        self.waiter: asyncio.Future[None] | None = None
        #: When each request whose reply is still expected was written, oldest first.
        self.sent_at: deque[float] = deque()
        self.quarantine_until = 0.0
        self.queue: deque[_Turn] = deque()

    @property
    def in_flight(self) -> int:
        return len(self.sent_at)


def _wake(fut: asyncio.Future[None] | None) -> None:
    if fut is not None and not fut.done():
        fut.set_result(None)


class _Turn:
    """A call's place in the line for a key; woken when it may look again."""

    __slots__ = ("_fut", "_loop")

    def __init__(self, loop: asyncio.AbstractEventLoop) -> None:
        self._loop = loop
        self._fut: asyncio.Future[None] = loop.create_future()

    def wake(self, error: BaseException | None = None) -> None:
        if not self._fut.done():
            if error is None:
                self._fut.set_result(None)
            else:
                self._fut.set_exception(error)

    async def wait(self, delay: float | None) -> None:
        """Until woken, or ``delay`` seconds; a wake before the wait is not lost."""
        handle = None if delay is None else self._loop.call_later(max(delay, 0.0), self.wake)
        try:
            await self._fut
        finally:
            if handle is not None:
                handle.cancel()
            fut = self._fut
            if fut.done() and not fut.cancelled() and fut.exception() is None:
                self._fut = self._loop.create_future()  # ready for the next wake


#: A key stays out of use until this many times the worst latency seen has passed since
#: its last request was written (jitter on top of the latency measured).
LATENCY_MARGIN = 2.0
#: The most latency the table believes unless told otherwise (a reply that lost its
#: request, counted against an older write, must not shut a key for minutes).
MAX_LATENCY = 30.0


class RequestTable(Generic[K, T]):
    """Calls waiting for replies, keyed by what the reply carries; built so that a late
    reply can never answer a later call.

    The rule, which holds by construction:

    * **One call per key at a time.** A call *acquires* its key; another call for the
      same key waits its turn. A protocol whose replies carry no tag (the reply id is
      the key) needs this for a reply to be attributed at all; one with request ids allocates a
      free request id per call, so it never waits.
    * **Replies are counted per key.** Each request written adds one reply in flight;
      each reply that arrives takes one away. A reply arriving while its key's call is
      waiting answers it (a reply to an earlier *attempt of the same call* is as good an
      answer as the reply to the latest one); a reply arriving when the call has gone
      is **late**: dropped, and reported as such.
    * **Quarantine.** When a call gives up with replies still in flight, its key is not
      handed to the next call until those replies have arrived (and been dropped) or
      they are overdue by the latency this device has shown; after that they are
      taken as lost.

    Why the quarantine follows the device's latency: a fixed one (``request_timeout``)
    expires before the late reply of a device slower than that arrives, and the next
    call takes it (seen: latency 0.35 s, timeout 0.3 s, a call answered with the reply
    to the previous call's second attempt). So every reply's latency is measured (from
    the write of the oldest request still waiting for one: replies come back in order),
    and a key with replies in flight stays out of use until ``quarantine`` after its
    release *and* `LATENCY_MARGIN` times the worst latency seen after its last
    write. The first late reply of a slow device teaches the table that latency, and
    extends the quarantine of the replies still behind it at once.

    The cost: after a timeout, the next request for that key waits for the late reply
    or the quarantine; concurrent calls for one untagged reply id are served one
    after another. What no table can know: the replies of a device that has never
    answered anything, slower than ``quarantine`` past the call's last attempt.

    Args:
        quarantine: Seconds a key whose replies are overdue stays out of use at least.
        clock: Monotonic clock (replaceable in tests).
    """

    __slots__ = ("_clock", "_slots", "_watchers", "latency", "max_latency", "quarantine")

    def __init__(self, quarantine: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.quarantine = quarantine
        #: The worst reply latency seen, seconds (at most :attr:`max_latency`).
        self.latency = 0.0
        #: The most latency believed: a reply later than a whole call with its retries
        #: (the requester sets it) is a lost request's, not a measure of the device.
        self.max_latency = MAX_LATENCY
        self._clock = clock
        self._slots: dict[K, _Slot[T]] = {}
        self._watchers: list[asyncio.Future[None]] = []

    async def released(self, timeout: float) -> None:
        """Wait until some key is released or answered (or ``timeout`` s pass)."""
        fut = asyncio.get_running_loop().create_future()
        self._watchers.append(fut)
        try:
            await asyncio.wait((fut,), timeout=timeout)
        finally:
            with contextlib.suppress(ValueError):
                self._watchers.remove(fut)

    def __len__(self) -> int:
        """The number of calls holding a key."""
        return sum(1 for slot in self._slots.values() if slot.call is not None)

    def in_flight(self, key: K) -> int:
        """Replies still expected for ``key``."""
        slot = self._slots.get(key)
        return 0 if slot is None else slot.in_flight

    def is_free(self, key: K) -> bool:
        """True if a call could take ``key`` now, without waiting."""
        slot = self._slots.get(key)
        return slot is None or (
            slot.call is None
            and not slot.queue
            and (slot.in_flight == 0 or self._clock() >= slot.quarantine_until)
        )

    async def acquire(self, key: K) -> asyncio.Future[T]:
        """Take ``key`` for one call, waiting (in order of arrival) for the call holding
        it and for its quarantine to end; return the future the call's reply resolves.

        Raises:
            BaseException: What `fail_all` was given, if it ran meanwhile.
        """
        slot = self._slots.get(key)
        if slot is None:
            slot = self._slots[key] = _Slot()
        loop = asyncio.get_running_loop()
        if slot.call is not None or slot.queue or not self._past_quarantine(slot):
            turn = _Turn(loop)
            slot.queue.append(turn)
            try:
                while (
                    slot.call is not None
                    or slot.queue[0] is not turn
                    or (not self._past_quarantine(slot))
                ):
                    delay = None
                    if slot.call is None and slot.queue[0] is turn:
                        delay = slot.quarantine_until - self._clock()
                    await turn.wait(delay)
            except BaseException:
                slot.queue.remove(turn)
                self._next(key, slot)
                raise
            slot.queue.remove(turn)
        # Replies still counted past the quarantine are taken as lost.
        slot.sent_at.clear()
        slot.call = call = loop.create_future()
        return call

    async def wait(self, key: K, call: asyncio.Future[T], timeout: float) -> bool:
        """Wait up to ``timeout`` seconds for ``call`` (the future `acquire` gave
        for ``key``) to be answered or failed; return whether it was. The call's future
        is left as it is on a timeout, so a reply to this attempt still answers a later
        one. Like ``asyncio.wait((call,), timeout=...)``, but the reply wakes the waiting
        task itself, one loop turn sooner than a done-callback would."""
        slot = self._slots.get(key)
        if call.done() or slot is None or slot.call is not call:
            # (Already answered, or failed and dropped by fail_all.)
            return call.done()
        loop = asyncio.get_running_loop()
        waiter = slot.waiter = loop.create_future()
        handle = loop.call_later(timeout, _wake, waiter)
        try:
            await waiter
        finally:
            handle.cancel()
            if slot.waiter is waiter:
                slot.waiter = None
        return call.done()

    def _past_quarantine(self, slot: _Slot[T]) -> bool:
        return slot.in_flight == 0 or self._clock() >= slot.quarantine_until

    def sent(self, key: K) -> None:
        """Count one request written for ``key``: one more reply in flight."""
        self._slots[key].sent_at.append(self._clock())

    def resolve(self, key: K, value: T) -> Reply:
        """Attribute a reply for ``key``; see the class docstring for the rule."""
        slot = self._slots.get(key)
        if slot is None:
            return Reply.UNMATCHED
        expected = bool(slot.sent_at)
        if expected:
            now = self._clock()
            if slot.call is None and now >= slot.quarantine_until:
                # Its requests were taken as lost already: nothing to measure by.
                slot.sent_at.clear()
            else:
                latency = now - slot.sent_at.popleft()
                if latency > self.latency:
                    self.latency = min(latency, self.max_latency)
        call = slot.call
        if call is not None and not call.done():
            call.set_result(value)
            _wake(slot.waiter)
            return Reply.MATCHED
        if slot.call is None:
            if slot.sent_at:  # more late replies behind this one: hold them as long
                slot.quarantine_until = max(slot.quarantine_until, self._overdue(slot))
            self._next(key, slot)
        return Reply.LATE if expected else Reply.UNMATCHED

    def _overdue(self, slot: _Slot[T]) -> float:
        """When the replies still in flight for ``slot`` are overdue by this device's
        latency."""
        return slot.sent_at[-1] + LATENCY_MARGIN * self.latency

    def release(self, key: K) -> None:
        """End the call holding ``key`` (answered, timed out or cancelled); replies still
        in flight put the key in quarantine."""
        slot = self._slots.get(key)
        if slot is None:
            return
        slot.call = None
        if slot.sent_at:
            slot.quarantine_until = max(self._clock() + self.quarantine, self._overdue(slot))
        self._next(key, slot)

    def _next(self, key: K, slot: _Slot[T]) -> None:
        """Wake the first call waiting for ``key``, or forget an idle key."""
        watchers, self._watchers = self._watchers, []
        for fut in watchers:
            if not fut.done():
                fut.set_result(None)
        if slot.queue:
            slot.queue[0].wake()
        elif slot.call is None and slot.in_flight == 0 and self._slots.get(key) is slot:
            del self._slots[key]  # (a slot fail_all dropped is not the table's any more)

    def fail_all(self, error: BaseException) -> None:
        """Fail every call, and every call waiting for a key, with ``error`` (the link
        is gone: nothing in flight will be answered on it)."""
        slots, self._slots = self._slots, {}
        for slot in slots.values():
            if slot.call is not None and not slot.call.done():
                slot.call.set_exception(copy.copy(error))
            _wake(slot.waiter)
            for turn in slot.queue:
                turn.wake(copy.copy(error))
