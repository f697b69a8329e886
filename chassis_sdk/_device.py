"""What both devices share: lifetime, link supervision, reconnect, requests, streams,
the velocity watchdog and stats. ``Chassis`` and ``Board`` add only their protocol.

Lifetime
--------
``connect()`` opens the port, then starts a runner task that owns an anyio task group
with the background tasks (the watchdog, the link supervisor and the link-health
monitor). Running the group in its own task, rather than in the caller's, keeps the
caller's cancel scopes out of it, so ``connect()`` and ``close()`` may be called from
different tasks, and a failure in the background never cancels application code in the
middle of a request.

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
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import random
import time
from collections.abc import Callable, Hashable
from dataclasses import dataclass, fields
from types import TracebackType
from typing import Any, Generic, Self, TypeVar

import anyio
import anyio.lowlevel

from ._dispatch import Broadcast, Reply, RequestTable, Subscription
from ._transport import BACKEND, QUEUE_LIMIT, Link, open_link
from ._watchdog import Axes, FrameBuilder, MotionLimits, VelocityWatchdog
from .errors import (
    ChassisError,
    ConnectionLostError,
    NotConnectedError,
    PortOpenError,
    RequestTimeoutError,
)
from .events import BatteryMonitor, EventKind, RobotEvent
from .odometry import Odometry, OdometryIntegrator
from .protocol import DecoderStats
from .protocol._scale import check_duration, check_real

__all__ = ["ConnectionState", "LinkStats"]

M = TypeVar("M")
K = TypeVar("K", bound=Hashable)

#: Reconnect backoff: first delay, growth factor, cap (seconds).
_BACKOFF_START = 0.1
_BACKOFF_FACTOR = 2.0
_BACKOFF_CAP = 2.0
#: How long close() waits for the zero frame to leave, and for the port to close.
_DRAIN_TIMEOUT = 0.25
_CLOSE_TIMEOUT = 1.0


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


_OPEN = frozenset({ConnectionState.CONNECTED, ConnectionState.STALE})


@dataclass(frozen=True, slots=True)
class LinkStats:
    """A snapshot of a device's link counters (cumulative over reconnects).

    Attributes:
        bytes_received: Bytes read from the port.
        bytes_sent: Bytes written to the port.
        frames: Frames decoded.
        frames_sent: Frames written.
        bytes_dropped: Received bytes skipped as noise.
        checksum_errors: Received candidate frames with a bad check.
        malformed_frames: Frames that checked out but carried invalid content.
        length_mismatches: Frames accepted despite a wrong length byte.
        misaligned_frames: Frames that passed the check but were refused because the
            bytes after them showed them shifted by line noise (protocol B).
        unmatched_replies: Replies nobody was waiting for.
        late_replies: Replies to requests that had already timed out: dropped, never
            given to a later call (see "Requests" in the README).
        frames_discarded: Frames not sent because the device was not reading: velocity
            frames replaced by newer ones or expired while they waited, frames over the
            bound of what may wait, and what was still waiting at close.
        queue_drops: Messages dropped because a subscriber fell behind.
        sequence_gaps: Breaks in the device's frame numbers (protocol A), whether it
            keeps one counter for every frame or one per frame id (detected; see
            ``Chassis.sequence_scheme``). Counted within each connection: the break
            a reconnect makes is not a gap.
        reconnects: Successful reconnects.
        resends: Velocity frames re-sent by the watchdog.
        command_expiries: Velocity commands zeroed by the deadman or ``duration``.
    """

    bytes_received: int = 0
    bytes_sent: int = 0
    frames: int = 0
    frames_sent: int = 0
    bytes_dropped: int = 0
    checksum_errors: int = 0
    malformed_frames: int = 0
    length_mismatches: int = 0
    misaligned_frames: int = 0
    unmatched_replies: int = 0
    late_replies: int = 0
    frames_discarded: int = 0
    queue_drops: int = 0
    sequence_gaps: int = 0
    reconnects: int = 0
    resends: int = 0
    command_expiries: int = 0

    def as_dict(self) -> dict[str, int]:
        """Return the counters as a plain ``dict``."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


def _check_positive(name: str, value: float, *, allow_none: bool = False) -> None:
    if value is None and allow_none:
        return
    check_real(value, name, low=0, low_open=True)


class Device(Generic[M, K]):
    """Base of :class:`~chassis_sdk.Chassis` and :class:`~chassis_sdk.Board`.

    Not for direct use; see those classes for the arguments.
    """

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 115200,
        request_timeout: float = 1.0,
        retries: int = 2,
        resend_interval: float = 0.05,
        command_timeout: float | None = 0.5,
        reconnect: bool = False,
        queue_size: int = 64,
        link_timeout: float | None = 1.0,
        limits: MotionLimits | None = None,
        battery_low: float | None = None,
        connect_timeout: float = 2.0,
        logger: logging.Logger | None = None,
    ) -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a device path or URL string, got {port!r}")
        if isinstance(baudrate, bool) or not isinstance(baudrate, int) or baudrate <= 0:
            raise ValueError(f"baudrate must be a positive integer, got {baudrate!r}")
        _check_positive("request_timeout", request_timeout)
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
        _check_positive("resend_interval", resend_interval)
        _check_positive("command_timeout", command_timeout, allow_none=True)  # type: ignore[arg-type]
        if isinstance(queue_size, bool) or not isinstance(queue_size, int) or queue_size < 1:
            raise ValueError(f"queue_size must be an integer >= 1, got {queue_size!r}")
        _check_positive("link_timeout", link_timeout, allow_none=True)  # type: ignore[arg-type]
        _check_positive("connect_timeout", connect_timeout)
        self.port = port
        self.baudrate = baudrate
        self.request_timeout = float(request_timeout)
        self.retries = retries
        self.reconnect = bool(reconnect)
        self.queue_size = queue_size
        self.link_timeout = None if link_timeout is None else float(link_timeout)
        self.connect_timeout = float(connect_timeout)
        self._log = logger if logger is not None else logging.getLogger("chassis_sdk")
        self._decoder = self._make_decoder()
        self._requests: RequestTable[K, Any] = RequestTable(quarantine=self.request_timeout)
        self._streams: list[Broadcast[Any]] = []
        self._state = ConnectionState.DISCONNECTED
        self._states: Broadcast[ConnectionState] = Broadcast(queue_size)
        # Events bind to the loop that first waits on them, so they are made anew by
        # every connect(): the device works in any event loop it is connected in.
        # _state_changed is also replaced on every change, so each waiter sees the
        # change it waited on.
        self._state_changed = asyncio.Event()
        self._lost = asyncio.Event()
        self._closing = asyncio.Event()
        self._link: Link[M] | None = None
        self._opened_at = 0.0
        self._last_frame_time: float | None = None
        self._lost_exc: Exception | None = None
        self._runner: asyncio.Task[None] | None = None
        self._shutdown: asyncio.Future[None] | None = None
        # Set the moment close() starts (and by a failed runner): from then on nothing
        # is written but the zero frame, and every call gets NotConnectedError.
        self._fenced = False
        # Set while connect() opens the port; a close() meanwhile waits for it.
        self._connecting: asyncio.Future[None] | None = None
        self._watchdog = VelocityWatchdog(
            self._write_velocity,
            interval=float(resend_interval),
            command_timeout=None if command_timeout is None else float(command_timeout),
            logger=self._log,
        )
        self.limits = limits
        self._bytes_sent = 0
        self._frames_sent = 0
        self._unmatched = 0
        self._late_replies = 0
        self._discarded = 0  # by links already closed
        self._reconnects = 0
        #: Message type -> what to do with it (set up by ``_init_protocol``); called
        #: synchronously from ``data_received``, in wire order.
        self._handlers: dict[type, Callable[[Any], None]] = {}
        self._odometer = OdometryIntegrator()
        self._odometry: Broadcast[Odometry] = self._stream()
        self._latest_odometry: Odometry | None = None
        self._events: Broadcast[RobotEvent] = self._stream()
        self._battery_monitor = BatteryMonitor(battery_low)
        self._init_protocol()

    # --- hooks for the subclasses ---------------------------------------------------------

    def _init_protocol(self) -> None:
        """Set up the encoder, streams and message routing (end of ``__init__``)."""
        raise NotImplementedError

    def _make_decoder(self) -> Any:
        raise NotImplementedError

    def _zero_frame(self) -> bytes:
        """Build a zero-velocity frame."""
        raise NotImplementedError

    def _velocity_builder(self, linear: float, angular: float) -> FrameBuilder:
        """Check ``(linear, angular)`` (raises ``ValueError``) and return a builder of
        velocity frames for any values between zero and them."""
        raise NotImplementedError

    def _sequence_gaps(self) -> int:
        """Breaks in the device's frame numbers (protocols that number frames)."""
        return 0

    def _on_link_up(self) -> None:
        """Reset per-connection state (called on connect and each reconnect)."""

    # --- lifetime -------------------------------------------------------------------------

    @property
    def connection_state(self) -> ConnectionState:
        """The current :class:`ConnectionState`."""
        return self._state

    @property
    def is_connected(self) -> bool:
        """True while the port is open (``CONNECTED`` or ``STALE``)."""
        return self._state in _OPEN

    @property
    def transport_backend(self) -> str:
        """Which pyserial asyncio package carries the link."""
        return BACKEND

    def connection_states(self) -> Subscription[ConnectionState]:
        """An async iterator of :class:`ConnectionState` changes, from the next one on.

        It ends after ``DISCONNECTED`` when the device is closed. Example::

            async for state in robot.connection_states():
                print("link is", state.value)
        """
        return self._states.subscribe()

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Wait until the port is open (``CONNECTED`` or ``STALE``), e.g. after a
        reconnect. Returns at once if it already is.

        Raises:
            TimeoutError: ``timeout`` elapsed first.
            NotConnectedError: The device is closed or lost and will not reconnect.
        """
        with anyio.fail_after(timeout):
            while self._state not in _OPEN:
                if self._state in (ConnectionState.DISCONNECTED, ConnectionState.LOST):
                    raise NotConnectedError(f"{self.port} is {self._state.value}")
                await self._state_changed.wait()

    def _set_state(self, state: ConnectionState) -> None:
        old = self._state
        if state is old:
            return
        self._log.info("%s: %s -> %s", self.port, old.value, state.value)
        self._state = state
        kind = None
        if state is ConnectionState.STALE:
            kind = EventKind.LINK_STALE
        elif state in (ConnectionState.RECONNECTING, ConnectionState.LOST):
            kind = EventKind.LINK_LOST
        elif state is ConnectionState.CONNECTED and old is not ConnectionState.CONNECTING:
            kind = EventKind.LINK_RESTORED
        if kind is not None:
            self._emit(RobotEvent(kind, "", time.monotonic()))
        self._states.publish(state)
        changed, self._state_changed = self._state_changed, asyncio.Event()
        changed.set()

    async def connect(self) -> None:
        """Open the port and start the background tasks.

        Raises:
            PortOpenError: The port cannot be opened (the message says why).
            ChassisError: Already connected.
        """
        if self._shutdown is not None:  # a close() in progress: let it finish
            await asyncio.shield(self._shutdown)
        if self._runner is not None or self._connecting is not None:
            raise ChassisError(f"{self.port} is already connected; close() it first")
        connecting = self._connecting = asyncio.get_running_loop().create_future()
        self._fenced = False
        self._state_changed = asyncio.Event()
        self._lost = asyncio.Event()
        self._closing = asyncio.Event()
        self._requests.quarantine = self._reply_quarantine()
        self._set_state(ConnectionState.CONNECTING)
        for stream in self._streams:
            stream.reopen()
        try:
            await self._open()
            if self._link is None:  # close() was called while the port was opening
                raise NotConnectedError(f"{self.port} was closed while connecting")
        except BaseException:
            self._set_state(ConnectionState.DISCONNECTED)
            raise
        finally:
            self._connecting = None
            connecting.set_result(None)
        self._runner = asyncio.create_task(self._run(), name=f"chassis_sdk:{self.port}")
        self._set_state(ConnectionState.CONNECTED)

    def _reply_quarantine(self) -> float:
        """How long a key whose reply is overdue stays out of use (see RequestTable):
        one more ``request_timeout``, so a reply up to twice that late is still
        recognised as late; a later one is taken as lost."""
        return self.request_timeout

    async def _open(self) -> None:
        self._lost.clear()
        self._lost_exc = None
        self._decoder.reset()
        self._on_link_up()

        def make_link() -> Link[M]:
            link: Link[M] = Link(
                self._decoder, self._received, lambda exc: self._on_lost(link, exc), self._log
            )
            return link

        link = await open_link(self.port, self.baudrate, make_link, timeout=self.connect_timeout)
        if self._fenced:  # close() started while the port was opening: never use it
            await self._close_link(link)
            return
        self._link = link
        self._opened_at = time.monotonic()
        self._log.info("%s: opened at %d baud via %s", self.port, self.baudrate, BACKEND)

    def _received(self, messages: list[M], now: float) -> None:
        """Called by the link, synchronously, for each chunk that held frames."""
        self._last_frame_time = now
        if self._state is ConnectionState.STALE:
            self._log.warning("%s: frames arrive again; link restored", self.port)
            self._set_state(ConnectionState.CONNECTED)
        handlers = self._handlers
        for msg in messages:
            try:
                handlers[type(msg)](msg)
            except Exception:  # a bug must not stop the frames after it, nor the link
                self._log.exception("%s: error handling %r", self.port, msg)

    async def _monitor_link(self, timeout: float) -> None:
        """Mark the link ``STALE`` when no valid frame has come for ``timeout`` s."""
        while True:
            changed = self._state_changed
            if self._state is not ConnectionState.CONNECTED:
                await changed.wait()
                continue
            last = self._opened_at
            if self._last_frame_time is not None and self._last_frame_time > last:
                last = self._last_frame_time
            wait = last + timeout - time.monotonic()
            if wait > 0:
                await anyio.sleep(wait)
                continue
            self._log.warning(
                "%s: no valid frame for %.1f s; link stale (is the device on and sending?)",
                self.port,
                timeout,
            )
            self._set_state(ConnectionState.STALE)

    def _on_lost(self, link: Link[M], exc: Exception | None) -> None:
        if link.accounted:
            return
        link.accounted = True
        self._discarded += link.discarded
        if link is not self._link:  # one that close() kept from being installed
            return
        self._link = None
        self._lost_exc = exc
        self._lost.set()

    async def _close_link(self, link: Link[M]) -> None:
        await link.aclose(_CLOSE_TIMEOUT)
        self._on_lost(link, None)  # in case connection_lost did not come in time

    async def _run(self) -> None:
        try:
            async with anyio.create_task_group() as tg:
                tg.start_soon(self._watchdog.run, name=f"watchdog:{self.port}")
                tg.start_soon(self._supervise, name=f"supervisor:{self.port}")
                if self.link_timeout is not None:
                    tg.start_soon(
                        self._monitor_link, self.link_timeout, name=f"link health:{self.port}"
                    )
                await self._closing.wait()
                tg.cancel_scope.cancel()
        except Exception as exc:  # a bug in a background task: fail loudly, stop safely
            self._log.exception("%s: background task failed", self.port)
            error = ChassisError(f"background task failed: {exc!r}")
            # Nothing will resend or expire a command from here on: zero goes out first.
            self._fence()
            self._requests.fail_all(error)
            for stream in self._streams:
                stream.fail(error)
            self._set_state(ConnectionState.LOST)

    async def _supervise(self) -> None:
        while True:
            await self._lost.wait()
            if self._closing.is_set():
                return
            # Never resume motion after an outage: forget the command before anything.
            self._watchdog.clear()
            cause = self._lost_exc
            error = ConnectionLostError(
                f"lost connection to {self.port}" + (f": {cause}" if cause else "")
            )
            self._log.warning("%s", error)
            self._requests.fail_all(error)
            if not self.reconnect:
                self._set_state(ConnectionState.LOST)  # first, so LINK_LOST reaches events()
                for stream in self._streams:
                    stream.fail(error)
                return
            self._set_state(ConnectionState.RECONNECTING)
            await self._reopen()

    async def _reopen(self) -> None:
        delay = _BACKOFF_START
        while not self._closing.is_set():
            # Full jitter keeps a fleet of clients from retrying in lockstep.
            await anyio.sleep(delay * random.uniform(0.5, 1.0))
            try:
                await self._open()
            except PortOpenError as exc:
                self._log.debug("%s: reconnect failed: %s", self.port, exc)
                delay = min(delay * _BACKOFF_FACTOR, _BACKOFF_CAP)
                continue
            if self._link is None:  # closing
                return
            self._reconnects += 1
            self._set_state(ConnectionState.CONNECTED)
            return

    async def close(self) -> None:
        """Stop the robot, close the port and stop the background tasks.

        A zero-velocity frame is written and given a bounded time to leave before the
        port closes. Safe to call more than once, and from any task; a second call
        waits for the first to finish. Cancelling it does not interrupt it: the port is
        closed (within about a second) before the cancellation goes on.
        """
        shutdown = self._shutdown
        if shutdown is None:
            # First, synchronously, before anything that can be interrupted.
            self._fence()
            runner = self._runner
            if runner is None:
                connecting = self._connecting
                if connecting is not None:
                    # connect() sees the fence once the port is open and closes it
                    # again; return only then (bounded by connect_timeout).
                    await asyncio.shield(connecting)
                return
            self._runner = None
            shutdown = self._shutdown = asyncio.ensure_future(self._shut_down(self._link, runner))
        try:
            await asyncio.shield(shutdown)
        except asyncio.CancelledError:
            # An open port and live background tasks must not outlive a cancelled
            # close(); finishing is bounded by the drain and close timeouts.
            while not shutdown.done():
                with contextlib.suppress(asyncio.CancelledError):
                    await asyncio.shield(shutdown)
            raise

    def _fence(self) -> None:
        """Fence off every writer: from here on every call that would write gets
        NotConnectedError, the active command is forgotten, and the link takes one
        last velocity frame, zero, and refuses any after it, so zero is the last one
        on the wire (a racing set_velocity() included)."""
        self._fenced = True
        self._watchdog.clear()
        link = self._link
        if link is not None:
            zero = self._zero_frame()
            if link.close_velocity(zero):
                self._count_sent(len(zero))

    async def _shut_down(self, link: Link[M] | None, runner: asyncio.Task[None]) -> None:
        try:
            if link is not None:
                await link.drain(_DRAIN_TIMEOUT)
            self._closing.set()
            # The runner first: a reconnect in progress is cancelled, and whatever
            # link is installed once it has stopped is the one to close.
            await runner
            link = self._link
            if link is not None:
                await self._close_link(link)
        finally:
            if self._link is not None:  # close() itself was cancelled past its bounds
                self._on_lost(self._link, None)
            self._link = None
            closed = NotConnectedError(f"{self.port} was closed")
            self._requests.fail_all(closed)
            for stream in self._streams:
                stream.fail(None)
            self._set_state(ConnectionState.DISCONNECTED)
            # End the state iterators after DISCONNECTED; new ones may subscribe again.
            self._states.fail(None)
            self._states.reopen()
            self._shutdown = None

    async def __aenter__(self) -> Self:
        await self.connect()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    # --- writing, requests, streams ---------------------------------------------------------

    def _count_sent(self, n_bytes: int) -> None:
        self._bytes_sent += n_bytes
        self._frames_sent += 1

    def _not_connected(self) -> NotConnectedError:
        state = "closing" if self._fenced else self._state.value
        return NotConnectedError(f"{self.port} is {state}, not connected")

    def _write(self, frame: bytes) -> None:
        """Write a frame that is not a velocity command."""
        link = self._link
        if link is None or self._fenced:
            raise self._not_connected()
        if not link.write(frame):
            if link.is_open:
                raise ChassisError(
                    f"{self.port}: the device is not reading; {QUEUE_LIMIT} bytes already "
                    "wait to be sent, so this frame was discarded"
                )
            raise self._not_connected()
        self._count_sent(len(frame))

    def _write_velocity(self, frame: bytes, expires: float) -> None:
        """Write a velocity frame (the watchdog's writer): state, not a queue."""
        link = self._link
        if link is None or self._fenced or not link.write_velocity(frame, expires):
            raise self._not_connected()
        self._count_sent(len(frame))

    def _ensure_connected(self) -> None:
        if self._link is None or self._fenced or self._state not in _OPEN:
            raise self._not_connected()

    async def _send(self, frame: bytes) -> None:
        """Write a command that has no reply; return once it is handed to the port."""
        self._write(frame)
        await anyio.lowlevel.checkpoint()

    async def _request(
        self, build: Callable[[], tuple[bytes, K]], *, read_only: bool, what: str
    ) -> Any:
        """Write a request and wait for its reply, retrying read-only requests.

        Args:
            build: Returns ``(frame, reply key)``; called per attempt, so each attempt
                gets a fresh sequence number or request id.
            read_only: Retry up to ``retries`` times on timeout.
            what: Names the request in errors.
        """
        attempts = self.retries + 1 if read_only else 1
        table = self._requests
        key: K | None = None
        call: asyncio.Future[Any] | None = None
        try:
            for attempt in range(1, attempts + 1):
                self._ensure_connected()
                frame, new_key = build()
                if call is None or new_key != key:
                    # A new key (protocol B allocates one per attempt) gives up the
                    # old; the same key (protocol A) keeps the call, so a reply to an
                    # earlier attempt answers it.
                    if key is not None:
                        table.release(key)
                        key = None
                    call = await table.acquire(new_key)
                    key = new_key
                    self._ensure_connected()
                self._write(frame)
                table.sent(key)
                # asyncio.wait, unlike a cancel scope, leaves the call's future intact
                # for the next attempt.
                done, _ = await asyncio.wait((call,), timeout=self.request_timeout)
                if done:
                    return call.result()
                self._log.debug("%s: %s attempt %d timed out", self.port, what, attempt)
        finally:
            if key is not None:
                table.release(key)
        raise RequestTimeoutError(
            f"no reply to {what} from {self.port} within {self.request_timeout:g} s "
            f"({attempts} attempt{'s' if attempts > 1 else ''})"
        )

    def _resolve(self, key: K, msg: Any) -> None:
        outcome = self._requests.resolve(key, msg)
        if outcome is Reply.LATE:
            self._late_replies += 1
            self._log.info("%s: late reply %r dropped (its request had timed out)", self.port, msg)
        elif outcome is Reply.UNMATCHED:
            self._unmatched += 1
            self._log.info("%s: unmatched reply %r", self.port, msg)

    def _stream(self) -> Broadcast[Any]:
        stream: Broadcast[Any] = Broadcast(self.queue_size)
        self._streams.append(stream)
        return stream

    def _subscribe(self, stream: Broadcast[Any]) -> Subscription[Any]:
        if self._state is ConnectionState.DISCONNECTED:
            raise NotConnectedError(f"{self.port} is not connected; use `async with` first")
        return stream.subscribe()

    # --- motion -----------------------------------------------------------------------------

    async def set_velocity(
        self, linear: float, angular: float, *, duration: float | None = None
    ) -> None:
        """Drive with a linear (m/s) and angular (rad/s) velocity.

        The frame is written at once and re-sent every ``resend_interval``. Without
        ``duration`` it stays active until ``command_timeout`` after the *last* call
        (keep calling, as with ROS ``cmd_vel``); with ``duration`` it holds exactly that
        long. Then one zero frame is written. With :attr:`limits`, what is written is
        clamped and ramped towards the command; stopping is always immediate.

        Raises:
            ValueError: NaN, infinity, a value that overflows the wire field, or a bad
                ``duration``; nothing is written.
            NotConnectedError: The port is not open.
        """
        build = self._velocity_builder(linear, angular)
        duration = check_duration(duration)
        self._drive((linear, angular), build, duration, f"({linear}, {angular})", "velocity")
        await anyio.lowlevel.checkpoint()

    def _drive(
        self,
        target: tuple[float, float],
        build: FrameBuilder,
        duration: float | None,
        description: str,
        axes: Axes,
    ) -> None:
        self._ensure_connected()
        self._watchdog.command(target, build, self._zero_frame, duration, description, axes)

    @property
    def limits(self) -> MotionLimits:
        """The :class:`MotionLimits` applied to what is written; assign to change them
        (the next write uses the new ones)."""
        return self._watchdog.limits

    @limits.setter
    def limits(self, limits: MotionLimits | None) -> None:
        if limits is not None and not isinstance(limits, MotionLimits):
            raise ValueError(f"limits must be a MotionLimits or None, got {limits!r}")
        self._watchdog.limits = limits if limits is not None else MotionLimits()

    @property
    def commanded_velocity(self) -> tuple[float, float] | None:
        """The active command as asked: ``(linear, angular)`` (``(left, right)`` in
        wheel mode), or ``None`` when no command is active."""
        active = self._watchdog.active
        return None if active is None else active.target

    @property
    def written_velocity(self) -> tuple[float, float]:
        """What was last written for the active command, after limits and ramps
        (zeros when none is active)."""
        return self._watchdog.written

    async def stop(self) -> None:
        """Write zero velocity now and end the active command.

        Raises:
            NotConnectedError: The port is not open (the command is ended anyway).
        """
        self._watchdog.clear()
        self._ensure_connected()
        self._watchdog.stop(self._zero_frame)
        await anyio.lowlevel.checkpoint()

    # --- events -----------------------------------------------------------------------------------

    def _emit(self, event: RobotEvent) -> None:
        self._log.info("%s: %s", self.port, event)
        self._events.publish(event)

    def _battery(self, voltage: float, timestamp: float) -> None:
        event = self._battery_monitor.update(voltage, timestamp)
        if event is not None:
            self._emit(event)

    def events(self) -> Subscription[RobotEvent]:
        """Subscribe to :class:`~chassis_sdk.RobotEvent` edges: e-stops, bumpers, driver
        faults, docking changes (chassis), battery low/ok (with ``battery_low``), and
        the link going stale, lost and restored. Each edge is reported once.
        """
        return self._subscribe(self._events)

    @property
    def battery_low(self) -> float | None:
        """Voltage below which ``BATTERY_LOW`` is reported (``None``: not watched)."""
        return self._battery_monitor.threshold

    def _link_findings(self) -> tuple[list[str], list[str]]:
        """(faults, notes) about the link and battery, for ``diagnose()``."""
        faults: list[str] = []
        notes: list[str] = []
        if self._state is not ConnectionState.CONNECTED:
            faults.append(f"link {self._state.value}")
        age = self.last_frame_age
        if age is None:
            faults.append("no valid frame received yet")
        else:
            notes.append(f"last frame {age:.2f} s ago, via {BACKEND}")
        if self._battery_monitor.low:
            faults.append(f"battery below {self._battery_monitor.threshold:g} V")
        return faults, notes

    # --- odometry ---------------------------------------------------------------------------------

    def _integrate(
        self, linear: float, angular: float, timestamp: float, heading: float | None = None
    ) -> None:
        odometry = self._odometer.update(linear, angular, timestamp, heading)
        self._latest_odometry = odometry
        self._odometry.publish(odometry)

    def odometry(self) -> Subscription[Odometry]:
        """Subscribe to the pose dead-reckoned from the device's reported velocities:
        an async iterator of :class:`~chassis_sdk.Odometry`, one per velocity sample.

        Integration runs all the time, subscribed or not, using the samples'
        timestamps, so irregular intervals and dropped frames do not bias it; a gap
        longer than half a second (an outage) is not integrated. See
        :meth:`configure_odometry` for the sources.
        """
        return self._subscribe(self._odometry)

    @property
    def latest_odometry(self) -> Odometry | None:
        """The most recent :class:`~chassis_sdk.Odometry`, or ``None``."""
        return self._latest_odometry

    def reset_odometry(self, x: float = 0.0, y: float = 0.0, heading: float = 0.0) -> None:
        """Set the current pose (default: the origin, heading 0) and integrate from it.

        Raises:
            ValueError: A value is not finite.
        """
        x = check_real(x, "x")
        y = check_real(y, "y")
        heading = check_real(heading, "heading")
        self._odometer.reset(x, y, heading)
        self._on_odometry_reset(heading)

    def _on_odometry_reset(self, heading: float) -> None:
        """Hook: a device with its own heading source resets it too."""

    # --- observability ------------------------------------------------------------------------

    def _link_stats(self, **extra: int) -> LinkStats:
        d: DecoderStats = self._decoder.stats
        return LinkStats(
            bytes_received=d.bytes_received,
            bytes_sent=self._bytes_sent,
            frames=d.frames,
            frames_sent=self._frames_sent,
            bytes_dropped=d.bytes_dropped,
            checksum_errors=d.checksum_errors,
            malformed_frames=d.malformed_frames,
            length_mismatches=d.length_mismatches,
            misaligned_frames=d.misaligned_frames,
            unmatched_replies=self._unmatched,
            late_replies=self._late_replies,
            frames_discarded=self._discarded
            + (self._link.discarded if self._link is not None else 0),
            queue_drops=sum(s.dropped for s in self._streams),
            sequence_gaps=self._sequence_gaps(),
            reconnects=self._reconnects,
            resends=self._watchdog.resends,
            command_expiries=self._watchdog.expiries,
            **extra,
        )

    @property
    def stats(self) -> LinkStats:
        """A snapshot of the link counters (see :class:`LinkStats`)."""
        return self._link_stats()

    @property
    def last_frame_age(self) -> float | None:
        """Seconds since the last valid frame of any kind arrived (across reconnects),
        or ``None`` if none has."""
        last = self._last_frame_time
        return None if last is None else time.monotonic() - last

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.port!r} {self._state.value}>"
