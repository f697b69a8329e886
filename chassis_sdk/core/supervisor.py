"""The link supervisor: one device's lifetime, its link, reconnects and link health.

Lifetime
--------
``connect()`` opens the port, then starts a runner task that owns an anyio task group
with the background tasks (the device's own, such as the watchdog, plus the supervisor
and the link-health monitor). Running the group in its own task, rather than in the
caller's, keeps the caller's cancel scopes out of it, so ``connect()`` and ``close()``
may be called from different tasks, and a failure in the background never cancels
application code in the middle of a request.

``close()`` first fences off every writer, synchronously, before anything that can be
interrupted: from then on every call that would write raises ``NotConnectedError``,
and the link takes one last velocity frame, zero, and refuses any after it. It then
waits a bounded time for what was written to leave, stops the background tasks (a
reconnect in progress with them), and closes whatever link is installed then; a link
that a reconnect opens after the fence is closed unused. That second part runs as a
task of its own which ``close()`` waits out even when it is cancelled (anyio's shield
does not hold back a plain ``task.cancel()``), so leaving ``async with`` on
cancellation still stops the robot and never leaves a port open.

Every loop-bound primitive (the events below) is made by ``connect()``, so a device
object works in any event loop it is connected in, one ``asyncio.run()`` after another.

The supervisor knows no protocol: what it needs of the device it serves is the
`Supervised` interface (a decoder and a message sink per link, the zero frame,
what to do when the link goes down), which [`Device`][chassis_sdk.core.device.Device]
implements.
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import time
from collections.abc import Awaitable, Callable, Coroutine, Sequence
from typing import Any, Generic, Protocol, TypeVar

import anyio

from ..errors import (
    ChassisError,
    ConnectionLostError,
    NotConnectedError,
    PortOpenError,
    RequestTimeoutError,
)
from .alarm import LOOP_STALL
from .backoff import Backoff
from .dispatch import SLOW_CALLBACK, Broadcast, Listener, Subscription
from .transport import QUEUE_LIMIT, Decoder, Link, Tap, backend_name, open_link

__all__ = ["ConnectionState", "ConnectionStates", "LinkSupervisor", "Supervised", "Writer"]

M = TypeVar("M")
T = TypeVar("T")

#: Reconnect backoff: first delay, growth factor, cap (seconds).
BACKOFF_START = 0.1
BACKOFF_FACTOR = 2.0
BACKOFF_CAP = 2.0
#: How long close() waits for the zero frame to leave, and for the port to close.
DRAIN_TIMEOUT = 0.25
CLOSE_TIMEOUT = 1.0


class ConnectionState(enum.Enum):
    """Where a device is in its lifetime."""

    DISCONNECTED = "disconnected"  #: constructed, or closed; no I/O
    CONNECTING = "connecting"  #: opening the port
    CONNECTED = "connected"  #: the port is open and frames arrive
    #: the port is open but no valid frame has arrived for ``link_timeout``; requests
    #: and commands are still sent (a frame ends this state at once)
    STALE = "stale"
    RECONNECTING = "reconnecting"  #: the link dropped; reopening with backoff
    LOST = "lost"  #: the link dropped and ``reconnect`` is off; call ``close()``


OPEN = frozenset({ConnectionState.CONNECTED, ConnectionState.STALE})


class Fenced(Protocol):
    """What the writer needs of the device it writes for."""

    def closing_frame(self) -> bytes | None:
        """The last velocity frame, written at the fence: zero (``None``: none is owed,
        the device never wrote a velocity and was asked not to write one at close)."""
        ...

    def fenced(self) -> None:
        """Writers are fenced off: forget any active command."""
        ...


class Supervised(Fenced, Protocol[M]):
    """What the supervisor needs of the device it serves."""

    def link_opening(self) -> tuple[Decoder[M], Callable[[list[M], float], None]]:
        """A link is about to open: reset per-connection state and return the decoder
        and the sink of its messages."""
        ...

    def state_changed(self, old: ConnectionState, new: ConnectionState) -> None:
        """Report a state change (events, logs)."""
        ...

    def link_down(self, error: BaseException | None, final: bool) -> None:
        """The link dropped (``error``), or the device closed (``None``): fail what
        waits on it; ``final``: no reconnect follows, so end the streams too."""
        ...

    async def settle(self) -> None:
        """Closing: the final zero has left and the port is still open (writers
        fenced off, frames still read); return when the port may close. Bounded: a
        recording keeps the robot coming to rest (see ``Device._settle``)."""
        ...


async def reopen(
    open_once: Callable[[], Awaitable[T]],
    backoff: Backoff,
    *,
    until: Callable[[], bool] = lambda: False,
    each: Callable[[], None] | None = None,
    log: logging.Logger | None = None,
    what: str = "",
) -> T | None:
    """Open a port again after it dropped: wait ``backoff.next()``, try ``open_once()``,
    and again on [`PortOpenError`][chassis_sdk.PortOpenError], until it opens (its result) or
    ``until()`` is true before an attempt (``None``). ``each`` runs before every wait
    (progress). The caller bounds it in time with a cancel scope. Every reconnect of
    the SDK goes through this: a device's supervisor and the passive recorder.
    """
    while not until():
        if each is not None:
            each()
        await anyio.sleep(backoff.next())
        if until():
            break
        try:
            return await open_once()
        except PortOpenError as exc:
            if log is not None:
                log.debug("%s: reopen failed: %s", what, exc)
    return None


class ConnectionStates:
    """A device's `ConnectionState`, its changes as a stream, and waiting on them.

    Args:
        port: For messages.
        on_change: Called with ``(old, new)`` on every change, before anyone hears of it.
        queue_size: Buffer of each subscriber of `subscribe`.
        log: Where changes are logged.
    """

    def __init__(
        self,
        port: str,
        on_change: Callable[[ConnectionState, ConnectionState], None],
        queue_size: int,
        log: logging.Logger,
    ) -> None:
        self.port = port
        self.state = ConnectionState.DISCONNECTED
        self._on_change = on_change
        self._log = log
        self._stream: Broadcast[ConnectionState] = Broadcast(queue_size)
        # Events bind to the loop that first waits on them, so renew() makes new ones
        # on every connect(). ``changed`` is also replaced on every change, so each
        # waiter sees the change it waited on.
        self.changed = asyncio.Event()

    def renew(self) -> None:
        """Make the loop-bound event anew (on connect)."""
        self.changed = asyncio.Event()

    def set(self, state: ConnectionState) -> None:
        """Enter ``state`` (nothing happens if it is the current one)."""
        old = self.state
        if state is old:
            return
        self._log.info("%s: %s -> %s", self.port, old.value, state.value)
        self.state = state
        self._on_change(old, state)
        self._stream.publish(state)
        changed, self.changed = self.changed, asyncio.Event()
        changed.set()

    def subscribe(self) -> Subscription[ConnectionState]:
        """An async iterator of state changes, from the next one on."""
        return self._stream.subscribe()

    def listen(
        self,
        callback: Callable[[ConnectionState], None],
        *,
        slow: float = SLOW_CALLBACK,
        stream: str | None = None,
    ) -> Listener[ConnectionState]:
        """Call ``callback(state)`` synchronously on every change (see
        `Broadcast.listen`)."""
        return self._stream.listen(callback, slow=slow, stream=stream)

    def end_subscriptions(self) -> None:
        """End the iterators (after ``DISCONNECTED``); new ones may subscribe again."""
        self._stream.fail(None)
        self._stream.reopen()

    async def wait_open(self, timeout: float | None) -> None:
        """Wait until the port is open; see ``Device.wait_connected``.

        Raises:
            RequestTimeoutError: Not open within ``timeout`` (also a ``TimeoutError``).
        """
        with anyio.move_on_after(timeout):
            while self.state not in OPEN:
                if self.state in (ConnectionState.DISCONNECTED, ConnectionState.LOST):
                    raise NotConnectedError(f"{self.port} is {self.state.value}")
                await self.changed.wait()
            return
        raise RequestTimeoutError(f"{self.port} was not connected within {timeout:g} s")


class Writer(Generic[M]):
    """Every write of a device, through whichever link is installed, and the fence that
    ``close()`` puts up first.

    Args:
        owner: The device (for its zero frame, and to forget its command at the fence).
        states: The device's connection state.
    """

    def __init__(self, owner: Fenced, states: ConnectionStates) -> None:
        self._owner = owner
        self._states = states
        self.port = states.port
        #: The installed link, or ``None``.
        self.link: Link[M] | None = None
        # Set the moment close() starts (and by a failed runner): from then on nothing
        # is written but the zero frame, and every call gets NotConnectedError.
        self.is_fenced = False
        #: Set for a viewer (``read_only=True``): every write is refused and close
        #: writes no zero either (viewers never write).
        self.read_only = False
        self.bytes_sent = 0
        self.frames_sent = 0

    def not_connected(self) -> NotConnectedError:
        """The error of a call that cannot write now."""
        state = "closing" if self.is_fenced else self._states.state.value
        return NotConnectedError(f"{self.port} is {state}, not connected")

    def read_only_error(self) -> ChassisError:
        """The error of a call that would write to a read-only device."""
        return ChassisError(f"{self.port} was opened read-only: nothing is written to it")

    def ensure_open(self) -> None:
        """Raise [`NotConnectedError`][chassis_sdk.NotConnectedError] unless a call may write now (a
        [`ChassisError`][chassis_sdk.ChassisError] on a read-only device)."""
        if self.read_only:
            raise self.read_only_error()
        if self.link is None or self.is_fenced or self._states.state not in OPEN:
            raise self.not_connected()

    def _count_sent(self, n_bytes: int) -> None:
        self.bytes_sent += n_bytes
        self.frames_sent += 1

    def write(self, frame: bytes) -> None:
        """Write a frame that is not a velocity command (queued, in order, if the device
        is not reading; bounded)."""
        link = self.link
        if link is None or self.is_fenced:
            raise self.not_connected()
        if not link.write(frame):
            if link.is_open:
                raise ChassisError(
                    f"{self.port}: the device is not reading; {QUEUE_LIMIT} bytes already "
                    "wait to be sent, so this frame was discarded"
                )
            raise self.not_connected()
        self._count_sent(len(frame))

    def write_velocity(self, frame: bytes, expires: float) -> None:
        """Write a velocity frame (the watchdog's writer): state, not a queue."""
        if self.read_only:
            raise self.read_only_error()
        link = self.link
        if link is None or self.is_fenced or not link.write_velocity(frame, expires):
            raise self.not_connected()
        self._count_sent(len(frame))

    def fence(self) -> None:
        """Fence off every writer: from here on every call that would write gets
        NotConnectedError, the owner forgets its command, and the link takes one last
        velocity frame, zero, and refuses any after it, so zero is the last one on the
        wire (a racing set_velocity() included)."""
        self.is_fenced = True
        self._owner.fenced()
        link = self.link
        if link is not None and not self.read_only:
            zero = self._owner.closing_frame()
            if zero is not None and link.close_velocity(zero):
                self._count_sent(len(zero))


class _Taps:
    """Several taps as one (the link calls one object; most devices have one tap or
    none, which the link then calls directly)."""

    __slots__ = ("_taps",)

    def __init__(self, taps: tuple[Tap, ...]) -> None:
        self._taps = taps

    def rx(self, data: bytes, now: float) -> None:
        for tap in self._taps:
            tap.rx(data, now)

    def tx(self, data: bytes, now: float) -> None:
        for tap in self._taps:
            tap.tx(data, now)


class LinkSupervisor(Generic[M]):
    """Opens, watches, reopens and closes one device's link; owns its state and writes.

    Args:
        owner: The device served.
        port: Device path, pty path, ``usb:VID:PID[:SERIAL]`` or ``socket://host:port``;
            looked up again (a ``usb:`` port) or followed again (a symlink) at every
            open and every reconnect attempt.
        background: ``(name, coroutine function)`` pairs run while connected.
        Other arguments: as the device options of the same names.
    """

    def __init__(
        self,
        owner: Supervised[M],
        port: str,
        *,
        baudrate: int,
        connect_timeout: float,
        close_linger: float = 0.0,
        link_timeout: float | None,
        reconnect: bool,
        queue_size: int,
        log: logging.Logger,
        background: Sequence[tuple[str, Callable[[], Coroutine[Any, Any, None]]]] = (),
    ) -> None:
        self._owner = owner
        self.port = port
        self.baudrate = baudrate
        self.connect_timeout = connect_timeout
        self.close_linger = close_linger
        self.link_timeout = link_timeout
        self.reconnect = reconnect
        self._log = log
        self._background = tuple(background)
        self.states = ConnectionStates(port, owner.state_changed, queue_size, log)
        self.writer: Writer[M] = Writer(owner, self.states)
        # Loop-bound, so made anew by every connect() (see ConnectionStates).
        self._lost = asyncio.Event()
        self._closing = asyncio.Event()
        self._opened_at = 0.0
        # The link that reads now or read last, and the last frame's time before it.
        self._reader: Link[M] | None = None
        self._frame_before: float | None = None
        self._lost_exc: Exception | None = None
        self._runner: asyncio.Task[None] | None = None
        self._shutdown: asyncio.Future[None] | None = None
        # Set while connect() opens the port; a close() meanwhile waits for it.
        self._connecting: asyncio.Future[None] | None = None
        self.reconnects = 0
        #: The device node the last link opened (``None`` before the first open): what
        #: a ``usb:`` port or a ``/dev/serial/by-id`` link reached then.
        self.last_node: str | None = None
        self._discarded = 0  # by links already closed
        self._taps: tuple[Tap, ...] = ()
        self._tap: Tap | None = None  # what the link calls: the one tap, or all of them

    def add_tap(self, tap: Tap) -> None:
        """Let ``tap`` see every byte of every link of this device, both ways."""
        self._set_taps((*self._taps, tap))

    def remove_tap(self, tap: Tap) -> None:
        """Stop ``tap`` seeing the traffic (nothing happens if it does not)."""
        self._set_taps(tuple(t for t in self._taps if t is not tap))

    @property
    def tap(self) -> Tap | None:
        """What the link calls for every byte (``None``, the one tap, or all of them)."""
        return self._tap

    def _set_taps(self, taps: tuple[Tap, ...]) -> None:
        self._taps = taps
        self._tap = None if not taps else taps[0] if len(taps) == 1 else _Taps(taps)
        if self.writer.link is not None:
            self.writer.link.tap = self._tap

    # --- state --------------------------------------------------------------------------

    @property
    def last_frame_time(self) -> float | None:
        """The ``time.monotonic()`` of the last chunk of bytes that held a valid frame
        (any link so far), or ``None``."""
        reader = self._reader
        if reader is not None and reader.received_at is not None:
            return reader.received_at
        return self._frame_before

    @property
    def state(self) -> ConnectionState:
        """The current [`ConnectionState`][chassis_sdk.ConnectionState]."""
        return self.states.state

    @property
    def is_open(self) -> bool:
        """True while the port is open (``CONNECTED`` or ``STALE``)."""
        return self.states.state in OPEN

    @property
    def node(self) -> str | None:
        """The device node of the link open now (``None`` while none is)."""
        link = self.writer.link
        return link.node if link is not None else None

    @property
    def discarded(self) -> int:
        """Frames not sent because the device was not reading (every link so far)."""
        link = self.writer.link
        return self._discarded + (link.discarded if link is not None else 0)

    # --- connect ----------------------------------------------------------------------------

    async def connect(self, on_connecting: Callable[[], None]) -> None:
        """Open the port and start the background tasks; see ``Device.connect``.

        ``on_connecting`` runs once the state is ``CONNECTING``, before the port opens.
        """
        if self._shutdown is not None:  # a close() in progress: let it finish
            await asyncio.shield(self._shutdown)
        if self._runner is not None or self._connecting is not None:
            raise ChassisError(f"{self.port} is already connected; close() it first")
        connecting = self._connecting = asyncio.get_running_loop().create_future()
        self.writer.is_fenced = False
        self.states.renew()
        self._lost = asyncio.Event()
        self._closing = asyncio.Event()
        self.states.set(ConnectionState.CONNECTING)
        on_connecting()
        try:
            await self._open()
            if self.writer.link is None:  # close() was called while the port was opening
                raise NotConnectedError(f"{self.port} was closed while connecting")
        except BaseException:
            self.states.set(ConnectionState.DISCONNECTED)
            raise
        finally:
            self._connecting = None
            connecting.set_result(None)
        self._runner = asyncio.create_task(self._run(), name=f"chassis_sdk:{self.port}")
        self.states.set(ConnectionState.CONNECTED)

    async def _open(self) -> None:
        self._lost.clear()
        self._lost_exc = None
        decoder, sink = self._owner.link_opening()

        def make_link() -> Link[M]:
            # The messages go straight to the sink: the link keeps the time of the last
            # (`last_frame_time`), and `_monitor_link` puts `_restore` in between only
            # while the link is stale.
            link: Link[M] = Link(decoder, sink, lambda exc: self._on_lost(link, exc), self._log)
            link.tap = self._tap
            return link

        link = await open_link(self.port, self.baudrate, make_link, timeout=self.connect_timeout)
        if self.writer.is_fenced:  # close() started while the port was opening: never use it
            await self._close_link(link)
            return
        self.writer.link = link
        self._frame_before, self._reader = self.last_frame_time, link
        self._opened_at = time.monotonic()
        if link.node != self.last_node:
            # A usb: port or a by-id link that reached another node than last time (a
            # replug renumbered it): worth a line at INFO; a plain path never changes.
            if link.node != self.port:
                self._log.info("%s is now %s", self.port, link.node)
            self.last_node = link.node
        self._log.info("%s: opened at %d baud via %s", self.port, self.baudrate, backend_name())

    def _on_lost(self, link: Link[M], exc: Exception | None) -> None:
        if link.accounted:
            return
        link.accounted = True
        self._discarded += link.discarded
        if link is not self.writer.link:  # one that close() kept from being installed
            return
        self.writer.link = None
        self._lost_exc = exc
        self._lost.set()

    async def _close_link(self, link: Link[M]) -> None:
        await link.aclose(CLOSE_TIMEOUT, self.close_linger)
        self._on_lost(link, None)  # in case connection_lost did not come in time

    # --- background -------------------------------------------------------------------------

    async def _run(self) -> None:
        try:
            async with anyio.create_task_group() as tg:
                for name, task in self._background:
                    tg.start_soon(task, name=f"{name}:{self.port}")
                tg.start_soon(self._supervise, name=f"supervisor:{self.port}")
                if self.link_timeout is not None:
                    tg.start_soon(
                        self._monitor_link,
                        self.link_timeout,
                        name=f"link health:{self.port}",
                    )
                await self._closing.wait()
                tg.cancel_scope.cancel()
        except Exception as exc:  # a bug in a background task: fail loudly, stop safely
            self._log.exception("%s: background task failed", self.port)
            # Nothing will resend or expire a command from here on: zero goes out first.
            self.writer.fence()
            self._owner.link_down(ChassisError(f"background task failed: {exc!r}"), True)
            self.states.set(ConnectionState.LOST)

    async def _monitor_link(self, timeout: float) -> None:
        """Mark the link ``STALE`` when no valid frame has come for ``timeout`` s.

        A check that wakes more than `LOOP_STALL` after it was due does not conclude:
        the host's own loop was held up, and the frames that came meanwhile are not read
        yet. It looks again `LOOP_STALL` later, once the reader has had its turn."""
        due: float | None = None
        while True:
            changed = self.states.changed
            if self.state is not ConnectionState.CONNECTED:
                await changed.wait()
                due = None
                continue
            last = self._opened_at
            last_frame = self.last_frame_time
            if last_frame is not None and last_frame > last:
                last = last_frame
            now = time.monotonic()
            wait = last + timeout - now
            if wait > 0:
                due = now + wait
                await anyio.sleep(wait)
                continue
            if due is not None and now - due > LOOP_STALL:
                due = now + LOOP_STALL
                await anyio.sleep(LOOP_STALL)
                continue
            self._log.warning(
                "%s: no valid frame for %.1f s; link stale (is the device on and sending?)",
                self.port,
                timeout,
            )
            link = self.writer.link
            if link is not None:
                link.intercept(self._restore)
            self.states.set(ConnectionState.STALE)

    def _restore(self, link: Link[M]) -> None:
        """The first frame on a stale link: it is ``CONNECTED`` again."""
        if (
            link is self.writer.link
            and not self.writer.is_fenced
            and self.states.state is ConnectionState.STALE
        ):
            self._log.warning("%s: frames arrive again; link restored", self.port)
            self.states.set(ConnectionState.CONNECTED)

    async def _supervise(self) -> None:
        while True:
            await self._lost.wait()
            if self._closing.is_set():
                return
            cause = self._lost_exc
            error = ConnectionLostError(
                f"lost connection to {self.port}" + (f": {cause}" if cause else "")
            )
            self._log.warning("%s", error)
            if not self.reconnect:
                self._owner.link_down(error, False)
                self.states.set(ConnectionState.LOST)  # first, so LINK_LOST reaches events()
                self._owner.link_down(error, True)
                return
            self._owner.link_down(error, False)
            self.states.set(ConnectionState.RECONNECTING)
            await self._reopen()

    async def _reopen(self) -> None:
        async def open_once() -> bool:
            await self._open()
            return True

        backoff = Backoff(BACKOFF_START, BACKOFF_CAP, BACKOFF_FACTOR)
        opened = await reopen(
            open_once, backoff, until=self._closing.is_set, log=self._log, what=self.port
        )
        if opened is None or self.writer.link is None:  # closing
            return
        self.reconnects += 1
        self.states.set(ConnectionState.CONNECTED)

    # --- close ------------------------------------------------------------------------------

    async def close(self) -> None:
        """Stop the robot, close the port and stop the background tasks; see
        ``Device.close``."""
        shutdown = self._shutdown
        if shutdown is None:
            # First, synchronously, before anything that can be interrupted.
            self.writer.fence()
            # The last frame is the last one before close(): what a closing link
            # still reads reaches no one.
            self._frame_before, self._reader = self.last_frame_time, None
            runner = self._runner
            if runner is None:
                connecting = self._connecting
                if connecting is not None:
                    # connect() sees the fence once the port is open and closes it
                    # again; return only then (bounded by connect_timeout).
                    await asyncio.shield(connecting)
                return
            self._runner = None
            shutdown = self._shutdown = asyncio.ensure_future(
                self._shut_down(self.writer.link, runner)
            )
        try:
            await asyncio.shield(shutdown)
        except asyncio.CancelledError:
            # An open port and live background tasks must not outlive a cancelled
            # close(); finishing is bounded by the drain and close timeouts.
            while not shutdown.done():
                with contextlib.suppress(asyncio.CancelledError):
                    await asyncio.shield(shutdown)
            raise

    async def _shut_down(self, link: Link[M] | None, runner: asyncio.Task[Any]) -> None:
        try:
            # The zero left: what the device shows next may still be worth reading
            # (bounded by the owner) before the port closes; not if it is not reading.
            if link is not None and await link.drain(DRAIN_TIMEOUT):
                await self._owner.settle()
            self._closing.set()
            # The runner first: a reconnect in progress is cancelled, and whatever
            # link is installed once it has stopped is the one to close.
            await runner
            link = self.writer.link
            if link is not None:
                await self._close_link(link)
        finally:
            if self.writer.link is not None:  # close() itself was cancelled past its bounds
                self._on_lost(self.writer.link, None)
            self.writer.link = None
            self._owner.link_down(None, True)
            self.states.set(ConnectionState.DISCONNECTED)
            self.states.end_subscriptions()
            self._shutdown = None
