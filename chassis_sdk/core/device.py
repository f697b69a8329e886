"""``Device``: what every device shares, composed of small collaborators.

A device is its protocol plus these, each in its own module and testable alone:

* :class:`~chassis_sdk.core.supervisor.LinkSupervisor`: lifetime, the link and its
  writes, the close fence, reconnect with backoff, link health;
* :class:`~chassis_sdk.core.requests.Requester`: requests in flight, retries, and
  which reply answers which call;
* :class:`~chassis_sdk.core.dispatch.Streams`: every stream with its latest value;
* :class:`~chassis_sdk.core.watchdog.VelocityWatchdog`: the active velocity command,
  its resends, deadman, limits and ramps;
* :class:`~chassis_sdk.core.odometry.OdometryIntegrator`, and the events of
  :mod:`~chassis_sdk.core.events`.

A device package subclasses :class:`Device` and implements its abstract methods (the
"hooks" below); everything else is here, once.
"""

from __future__ import annotations

import abc
import logging
import os
import time
from collections.abc import Callable, Hashable
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, ClassVar, Generic, Protocol, Self, TypeVar

import anyio
import anyio.lowlevel

from ..errors import NotConnectedError, RequestTimeoutError
from .dispatch import Broadcast, Listener, Streams, Subscription
from .events import BatteryMonitor, EventKind, RobotEvent
from .framing import FrameDecoder
from .motion import Motion
from .observation import Observation
from .odometry import Odometry, OdometryIntegrator
from .requests import Requester
from .stats import LinkStats
from .supervisor import ConnectionState, LinkSupervisor
from .transport import Decoder, backend_name
from .validation import check_int, check_optional, check_real
from .watchdog import MotionLimits, VelocityWatchdog

if TYPE_CHECKING:
    from .transport import Tap

__all__ = ["ConnectionState", "Device", "LinkStats", "Recorder", "set_recorder"]

M = TypeVar("M")
K = TypeVar("K", bound=Hashable)

_POSITIVE: dict[str, Any] = {"low": 0, "low_open": True}
_CONNECTING = ConnectionState.CONNECTING
#: State -> the event entering it makes (CONNECTED only when coming back).
_LINK_EVENTS = {
    ConnectionState.STALE: EventKind.LINK_STALE,
    ConnectionState.RECONNECTING: EventKind.LINK_LOST,
    ConnectionState.LOST: EventKind.LINK_LOST,
    ConnectionState.CONNECTED: EventKind.LINK_RESTORED,
}


class Recorder(Protocol):
    """A session recording as a device holds it (the ``record`` option): it taps the
    device's traffic from before the port opens, and :meth:`close` ends it after the
    final zero."""

    def close(self) -> None:
        """End the recording (flush and close its file)."""


#: Opens the recording of the ``record`` option: ``opener(path, device)``. Set by
#: :mod:`chassis_sdk.recording` when it is imported (the core knows no file format).
_open_recorder: Callable[[Path, Device[Any, Any]], Recorder] | None = None


def set_recorder(opener: Callable[[Path, Device[Any, Any]], Recorder]) -> None:
    """Install what opens the ``record`` option's recordings (the recording package
    does, on import; ``chassis_sdk.Chassis`` and ``chassis_sdk.Board`` import it)."""
    global _open_recorder
    _open_recorder = opener


def _recording_path(record: str | os.PathLike[str] | None) -> Path | None:
    """The ``record`` option checked: ``None``, or a file path (``.mcap``: MCAP, which
    needs foxglove-sdk; any other name: a JSON-lines capture)."""
    if record is None:
        return None
    if _open_recorder is None:
        raise ValueError(
            "record= needs the recorders: import chassis_sdk.recording first "
            "(chassis_sdk.Chassis and chassis_sdk.Board do)"
        )
    if not isinstance(record, str | os.PathLike) or not str(record):
        raise ValueError(f"record must be a file path, got {record!r}")
    path = Path(record)
    if path.is_dir():
        raise ValueError(f"record must be a file path, got the directory {str(path)!r}")
    if path.suffix.lower() == ".mcap":
        import importlib.util

        if importlib.util.find_spec("foxglove") is None:
            raise ValueError(
                "record='*.mcap' needs foxglove-sdk: pip install 'chassis-sdk[foxglove]'"
            )
    return path


class _LinkHooks(Generic[M]):
    """What the link supervisor needs of a device (:class:`~.supervisor.Supervised`),
    kept off the device's public surface."""

    __slots__ = ("_device",)

    def __init__(self, device: Device[M, Any]) -> None:
        self._device = device

    def link_opening(self) -> tuple[Decoder[M], Callable[[list[M], float], None]]:
        device = self._device
        device._decoder.reset()
        device._on_link_up()
        return device._decoder, device._received

    def zero_frame(self) -> bytes:
        return self._device._zero_frame()

    def fenced(self) -> None:
        self._device._watchdog.clear()

    def state_changed(self, old: ConnectionState, new: ConnectionState) -> None:
        kind = _LINK_EVENTS.get(new)
        if kind is not None and (new is not ConnectionState.CONNECTED or old is not _CONNECTING):
            self._device._emit(RobotEvent(kind, "", time.monotonic()))

    def link_down(self, error: BaseException | None, final: bool) -> None:
        device = self._device
        device._watchdog.clear()  # never resume motion after an outage
        device._requests.fail_all(error)
        if final:
            device._streams.fail(error)


class Device(Motion, Observation, Generic[M, K]):
    """Base of every device (:class:`~chassis_sdk.Chassis`, :class:`~chassis_sdk.Board`,
    and any a device package adds). See those classes for the arguments.

    ``M`` is the device's message type, ``K`` the key a reply is matched by.

    A subclass implements the hooks: :meth:`_make_decoder`, :meth:`_init_protocol`
    (its encoder, streams and :attr:`_handlers`), :meth:`_zero_frame` and
    :meth:`_velocity_builder`; it may override :meth:`_on_link_up`,
    :meth:`_sequence_gaps`, :meth:`_reply_quarantine` and :meth:`_on_odometry_reset`.
    From the base it uses :meth:`_stream`, :meth:`_send`, :meth:`_request`,
    :meth:`_reply`, :meth:`_drive`, :meth:`_emit`, :meth:`_battery`, :meth:`_integrate`
    and :meth:`_findings`.
    """

    #: The device's profile name, as ``Diagnosis.device`` and the CLI say it.
    kind: ClassVar[str] = "device"

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
        close_linger: float = 5.0,
        logger: logging.Logger | None = None,
        record: str | os.PathLike[str] | None = None,
    ) -> None:
        if not isinstance(port, str) or not port:
            raise ValueError(f"port must be a device path or URL string, got {port!r}")
        check_int(baudrate, "baudrate", low=1)
        request_timeout = check_real(request_timeout, "request_timeout", **_POSITIVE)
        check_int(retries, "retries", low=0)
        resend_interval = check_real(resend_interval, "resend_interval", **_POSITIVE)
        command_timeout = check_optional(command_timeout, "command_timeout", **_POSITIVE)
        self.queue_size = check_int(queue_size, "queue_size", low=1)
        link_timeout = check_optional(link_timeout, "link_timeout", **_POSITIVE)
        connect_timeout = check_real(connect_timeout, "connect_timeout", **_POSITIVE)
        close_linger = check_real(close_linger, "close_linger", low=0, unit="s")
        self._record_path = _recording_path(record)
        self._recording: Recorder | None = None
        self.port = port
        self._log = logger if logger is not None else logging.getLogger("chassis_sdk")
        self._decoder = self._make_decoder()
        self._streams = Streams(queue_size)
        self._listeners: set[Listener[Any]] = set()
        self._watchdog = VelocityWatchdog(
            self._write_velocity,
            interval=resend_interval,
            command_timeout=command_timeout,
            logger=self._log,
        )
        self._link: LinkSupervisor[M] = LinkSupervisor(
            _LinkHooks(self),
            port,
            baudrate=baudrate,
            connect_timeout=connect_timeout,
            close_linger=close_linger,
            link_timeout=link_timeout,
            reconnect=bool(reconnect),
            queue_size=queue_size,
            log=self._log,
            background=[("watchdog", self._watchdog.run)],
        )
        self._requests: Requester[K] = Requester(
            port,
            self._link.writer.write,
            self._link.writer.ensure_open,
            timeout=request_timeout,
            retries=retries,
            log=self._log,
        )
        self.limits = limits
        #: Message type -> what to do with it (set up by ``_init_protocol``); called
        #: synchronously from the link's ``data_received``, in wire order.
        self._handlers: dict[type, Callable[[Any], None]] = {}
        self._pose = OdometryIntegrator()
        self._odometry: Broadcast[Odometry] = self._stream("odometry")
        self._events: Broadcast[RobotEvent] = self._stream("events")
        self._battery_monitor = BatteryMonitor(battery_low)
        self._init_protocol()

    # --- the hooks a device implements -----------------------------------------------------

    @abc.abstractmethod
    def _make_decoder(self) -> FrameDecoder[M]:
        """The device's incremental decoder (one per device, reset per connection)."""

    @abc.abstractmethod
    def _init_protocol(self) -> None:
        """Set up the encoder, streams and :attr:`_handlers` (end of ``__init__``)."""

    def _on_link_up(self) -> None:
        """Reset per-connection state (called on connect and each reconnect)."""

    def _make_command_decoder(self) -> FrameDecoder[Any] | None:
        """A decoder of what the *host* writes, so recordings show the commands
        decoded (``None``: they hold the raw bytes only)."""
        return None

    def _reply_quarantine(self) -> float:
        """The least time a key whose reply is overdue stays out of use (see
        RequestTable, which keeps it out longer on a device that has shown itself
        slower): one more ``request_timeout``."""
        return self.request_timeout

    def _received(self, messages: list[M], now: float) -> None:
        handlers = self._handlers
        for msg in messages:
            try:
                handlers[type(msg)](msg)
            except Exception:  # a bug must not stop the frames after it, nor the link
                self._log.exception("%s: error handling %r", self.port, msg)

    # --- lifetime -------------------------------------------------------------------------

    @property
    def connection_state(self) -> ConnectionState:
        """The current :class:`ConnectionState`."""
        return self._link.state

    @property
    def is_connected(self) -> bool:
        """True while the port is open (``CONNECTED`` or ``STALE``)."""
        return self._link.is_open

    @property
    def transport_backend(self) -> str:
        """Which pyserial asyncio package carries the link."""
        return backend_name()

    @property
    def baudrate(self) -> int:
        """The serial speed."""
        return self._link.baudrate

    @property
    def reconnect(self) -> bool:
        """Whether the port is reopened when the link drops."""
        return self._link.reconnect

    @property
    def request_timeout(self) -> float:
        """Seconds each attempt of a request waits for its reply (may be changed)."""
        return self._requests.timeout

    @request_timeout.setter
    def request_timeout(self, value: float) -> None:
        self._requests.timeout = check_real(value, "request_timeout", **_POSITIVE)

    @property
    def command_timeout(self) -> float | None:
        """The deadman (s): a velocity command without ``duration`` expires this long
        after the last call; ``None``: it holds until :meth:`stop`."""
        return self._watchdog.command_timeout

    @property
    def retries(self) -> int:
        """Extra attempts of a read-only request after a timeout (may be changed)."""
        return self._requests.retries

    @retries.setter
    def retries(self, value: int) -> None:
        self._requests.retries = check_int(value, "retries", low=0)

    def connection_states(self) -> Subscription[ConnectionState]:
        """An async iterator of :class:`ConnectionState` changes, from the next one on.

        It ends after ``DISCONNECTED`` when the device is closed. Example::

            async for state in robot.connection_states():
                print("link is", state.value)
        """
        return self._link.states.subscribe()

    async def wait_connected(self, timeout: float | None = None) -> None:
        """Wait until the port is open (``CONNECTED`` or ``STALE``), e.g. after a
        reconnect. Returns at once if it already is.

        Raises:
            TimeoutError: ``timeout`` elapsed first.
            NotConnectedError: The device is closed or lost and will not reconnect.
        """
        await self._link.states.wait_open(timeout)

    async def connect(self) -> None:
        """Open the port and start the background tasks.

        Raises:
            PortOpenError: The port cannot be opened (the message says why).
            ChassisError: Already connected.
        """

        def connecting() -> None:
            self._requests.table.quarantine = self._reply_quarantine()
            self._streams.reopen()

        if self._record_path is not None and self._recording is None:
            assert _open_recorder is not None  # checked with the option
            self._recording = _open_recorder(self._record_path, self)
        try:
            await self._link.connect(connecting)
        except BaseException:
            self._stop_recording()
            raise

    async def close(self) -> None:
        """Stop the robot, close the port and stop the background tasks.

        A zero-velocity frame is written and given a bounded time to leave before the
        port closes. If the device is not reading, every stale frame is discarded but
        the zero, which may go on waiting for it in the background for up to
        ``close_linger`` seconds after this returns (see the safety model); under
        :func:`chassis_sdk.run` the program ends only once it has left. Safe to call
        more than once, and from any task; a second call waits for the first to
        finish. Cancelling it does not interrupt it: it returns (within about a second)
        before the cancellation goes on.
        With ``record``, the recording ends after the zero frame, which it holds unless
        the zero had to wait for a device that was not reading.
        """
        try:
            await self._link.close()
        finally:
            self._stop_recording()

    @property
    def recording(self) -> Path | None:
        """The file this session is being recorded to (the ``record`` option), or
        ``None``. Connecting again after :meth:`close` starts the file anew."""
        return self._record_path

    def _stop_recording(self) -> None:
        recording, self._recording = self._recording, None
        if recording is not None:
            recording.close()

    # --- observing the device (recorders, bridges, live views) -----------------------------

    def add_tap(self, tap: Tap) -> Callable[[], None]:
        """Let ``tap`` see every byte of this device's link, both ways, across
        reconnects: ``tap.rx(data, now)`` for each chunk received, ``tap.tx(frame,
        now)`` for each frame as it begins to leave (``now`` is ``time.monotonic()``).
        Called synchronously on the event loop: it must be quick and must not raise.

        Returns:
            The function that removes it.
        """
        self._link.add_tap(tap)
        return lambda: self._link.remove_tap(tap)

    @property
    def stream_names(self) -> tuple[str, ...]:
        """The names of this device's streams: the methods that subscribe to them
        (``"telemetry"``, ``"odometry"``, ``"events"``, ...)."""
        return tuple(self._streams.named)

    def listen(self, stream: str, callback: Callable[[Any], None]) -> Callable[[], None]:
        """Call ``callback(message)`` synchronously for every message of the stream
        named ``stream`` (see :attr:`stream_names`), in wire order, from now on: for
        recorders and bridges that must see every message and cost nothing when
        absent. It must be quick and must not raise.

        Returns:
            The function that stops it.

        Raises:
            ValueError: No stream of that name.
        """
        found = self._streams.named.get(stream)
        if found is None:
            raise ValueError(
                f"{self.kind} has no stream {stream!r}; it has: {', '.join(self._streams.named)}"
            )
        return self._held(found.listen(callback))

    def listen_states(self, callback: Callable[[ConnectionState], None]) -> Callable[[], None]:
        """Call ``callback(state)`` synchronously on every :class:`ConnectionState`
        change, from now on. Returns the function that stops it."""
        return self._held(self._link.states.listen(callback))

    def _held(self, listener: Listener[Any]) -> Callable[[], None]:
        """Keep ``listener`` (streams hold theirs weakly) until the returned call."""
        self._listeners.add(listener)

        def stop() -> None:
            self._listeners.discard(listener)
            listener.close()

        return stop

    def command_decoder(self) -> FrameDecoder[Any] | None:
        """A new decoder of what the *host* writes to this device, so recordings show
        the commands decoded (``None``: the device has none; they keep the raw bytes)."""
        return self._make_command_decoder()

    def feed(self, data: bytes, now: float) -> None:
        """Take bytes that reached this device other than through its own link (a
        capture being replayed, a passive recorder, a conversion): tapped, decoded and
        handled as if they had come through it (streams, odometry, events)."""
        tap = self._link.tap
        if tap is not None:
            tap.rx(data, now)
        messages = self._decoder.feed(data, now)
        if messages:
            self._received(messages, now)

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

    # --- for the subclasses: writing, requests, streams ---------------------------------------

    def _ensure_connected(self) -> None:
        self._link.writer.ensure_open()

    async def _send(self, frame: bytes) -> None:
        """Write a command that has no reply; return once it is handed to the port."""
        self._link.writer.write(frame)
        await anyio.lowlevel.checkpoint()

    async def _request(
        self, build: Callable[[], tuple[bytes, K]], *, read_only: bool, name: str
    ) -> Any:
        """Write a request and wait for its reply (see :meth:`Requester.call`).

        A timeout on a port where bytes arrive but no frame of this protocol does says
        so: that is another device, or the wrong baud rate, not a slow one.
        """
        try:
            return await self._requests.call(build, read_only=read_only, name=name)
        except RequestTimeoutError as exc:
            d = self._decoder.stats
            if d.bytes_received and not d.frames:
                raise RequestTimeoutError(
                    f"{exc}; {d.bytes_received} bytes arrived but none is a {self.kind} "
                    "frame (another device on the port, or the wrong baud rate?)"
                ) from None
            raise

    def _reply(self, key: K, msg: Any) -> None:
        """A reply arrived for ``key``: answer its call, or count it late or unmatched."""
        self._requests.reply(key, msg)

    def _stream(self, name: str | None = None) -> Broadcast[Any]:
        """A new stream (with its latest value) of this device; ``name``, the name of
        the method that subscribes to it, makes it a topic of recordings and live
        views."""
        return self._streams.new(name)

    def _subscribe(self, stream: Broadcast[Any]) -> Subscription[Any]:
        if self._link.state is ConnectionState.DISCONNECTED:
            raise NotConnectedError(f"{self.port} is not connected; use `async with` first")
        return stream.subscribe()

    def _write_velocity(self, frame: bytes, expires: float) -> None:
        self._link.writer.write_velocity(frame, expires)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.port!r} {self._link.state.value}>"
