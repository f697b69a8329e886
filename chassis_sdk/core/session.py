"""``Session``: a device's port side.

It owns the link (through `LinkSupervisor`: the
lifetime, the writes, the close fence, reconnect, link health), the requests in flight
(`Requester`), the streams
(`Streams`) and the session recording; what
observers may see of it (the raw traffic, every named stream, the connection states)
they see through [`Notifier`][chassis_sdk.core.notifier.Notifier].
[`Device`][chassis_sdk.core.device.Device] adds the robot side: motion, odometry, events
and reports.
"""

from __future__ import annotations

import abc
import logging
import os
from collections.abc import Callable, Coroutine, Hashable
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar, Generic, Protocol, Self, TypeVar, runtime_checkable

import anyio
import anyio.lowlevel

from ..errors import NotConnectedError, RequestTimeoutError, install_hint
from .dispatch import SLOW_CALLBACK, Broadcast, Listener, Streams, Subscription, first_match
from .framing import FrameDecoder
from .ports import parse_usb_identity
from .requests import Requester
from .supervisor import ConnectionState, LinkSupervisor
from .transport import Decoder, Tap, backend_name
from .validation import check_int, check_real

__all__ = ["RecordTarget", "Recorder", "Session", "set_recorder"]

M = TypeVar("M")
K = TypeVar("K", bound=Hashable)
T = TypeVar("T")

_POSITIVE: dict[str, Any] = {"low": 0, "low_open": True}


class Recorder(Protocol):
    """A session recording as a device holds it (the ``record`` option): it taps the
    device's traffic from before the port opens, and `close` ends it after the
    final zero."""

    def close(self) -> None:
        """End the recording (flush and close its file)."""


@runtime_checkable
class RecordTarget(Protocol):
    """A ``record`` option that names its own recorder: a file path (``os.fspath``
    gives it) that also opens the recording, with the options it was made with, so
    the core never knows the file's format. ``chassis_sdk.recording.ros2.rosbag(...)``
    is one (a rosbag2 MCAP file for ROS 2 tools)."""

    def __fspath__(self) -> str:
        """The file the recording goes to."""

    def open_recorder(self, device: Any) -> Recorder:
        """Start recording ``device`` (the device being connected) to the file."""


#: Opens the recording of the ``record`` option: ``opener(path, device)`` (the device
#: is the :class:`~chassis_sdk.core.device.Device` being connected). Set by
#: :mod:`chassis_sdk.recording` when it is imported (the core knows no file format).
_open_recorder: Callable[[Path, Any], Recorder] | None = None


def set_recorder(opener: Callable[[Path, Any], Recorder]) -> None:
    """Install what opens the ``record`` option's recordings (the recording package
    does, on import; ``chassis_sdk.Chassis`` and ``chassis_sdk.Board`` import it)."""
    global _open_recorder
    _open_recorder = opener


#: Where the recorders are declared (pyproject: ``chassis_sdk.recording``): found like
#: devices, by entry point, when ``record=`` is first used and none is installed yet.
RECORDER_GROUP = "chassis_sdk.recorders"


def _find_recorder() -> None:
    """Load the declared recorders (importing one installs it with `set_recorder`)."""
    from importlib import metadata

    for ep in metadata.entry_points(group=RECORDER_GROUP):
        try:
            ep.load()
        except Exception as exc:  # a broken plugin must not break a device
            logging.getLogger("chassis_sdk").warning(
                "recorder entry point %s = %s failed to load: %r", ep.name, ep.value, exc
            )
        if _open_recorder is not None:
            return


def _recording(
    record: str | os.PathLike[str] | None,
) -> tuple[Path, Callable[[Any], Recorder]] | None:
    """The ``record`` option checked: ``None``; a `RecordTarget` (it opens its own
    recording); or a file path, opened by the installed recorder (``.mcap``: MCAP, which
    needs foxglove-sdk; any other name: a JSON-lines capture). Returns the file and what
    opens the recording given the device."""
    if record is None:
        return None
    if isinstance(record, RecordTarget):
        path = Path(os.fspath(record))
        if path.is_dir():
            raise ValueError(f"record must be a file path, got the directory {str(path)!r}")
        return path, record.open_recorder
    if not isinstance(record, str | os.PathLike) or not str(record):
        raise ValueError(
            "record must be a file path (or a recording with options, such as "
            f"chassis_sdk.recording.ros2.rosbag(...)), got {record!r}"
        )
    path = Path(record)
    if path.is_dir():
        raise ValueError(f"record must be a file path, got the directory {str(path)!r}")
    if path.suffix.lower() == ".mcap":
        import importlib.util

        if importlib.util.find_spec("foxglove") is None:
            raise ValueError(f"record='*.mcap' needs foxglove-sdk: {install_hint('foxglove')}")
    if _open_recorder is None:
        _find_recorder()
        if _open_recorder is None:
            raise ValueError(
                "record= found no recorder: install chassis-sdk (it declares one in the "
                f"entry-point group {RECORDER_GROUP!r}) or import chassis_sdk.recording"
            )
    opener = _open_recorder
    return path, lambda device: opener(path, device)


class _LinkHooks(Generic[M]):
    """What the link supervisor needs of a session (`Supervised`),
    kept off the session's public surface."""

    __slots__ = ("_session",)

    def __init__(self, session: Session[M, Any]) -> None:
        self._session = session

    def link_opening(self) -> tuple[Decoder[M], Callable[[list[M], float], None]]:
        session = self._session
        session._decoder.reset()
        session._on_link_up()
        return session._decoder, session._received

    def closing_frame(self) -> bytes | None:
        return self._session._closing_frame()

    def fenced(self) -> None:
        self._session._on_fenced()

    def state_changed(self, old: ConnectionState, new: ConnectionState) -> None:
        self._session._on_state(old, new)

    def link_down(self, error: BaseException | None, final: bool) -> None:
        session = self._session
        session._on_fenced()  # never resume motion after an outage
        session._requests.fail_all(error)
        if final:
            session._streams.fail(error)

    async def settle(self) -> None:
        await self._session._settle()


class Session(abc.ABC, Generic[M, K]):
    """A device's port side: see the module. The options are the device's (see
    [`Chassis`][chassis_sdk.Chassis]); ``background`` are the tasks that run while the
    port is open, by name.

    A subclass implements `_make_decoder` and `_zero_frame`; it may
    override `_on_link_up`, `_make_command_decoder`, `_reply_quarantine`,
    `_on_fenced` and `_on_state`.
    """

    #: The device's profile name, as ``Diagnosis.device`` and the CLI say it.
    device_name: ClassVar[str] = "device"

    def __init__(
        self,
        port: str,
        *,
        baudrate: int,
        request_timeout: float,
        retries: int,
        reconnect: bool,
        queue_size: int,
        link_timeout: float | None,
        connect_timeout: float,
        close_linger: float,
        logger: logging.Logger,
        record: str | os.PathLike[str] | None,
        background: list[tuple[str, Callable[[], Coroutine[Any, Any, None]]]],
        read_only: bool = False,
    ) -> None:
        if any("kind" in vars(c) for c in type(self).__mro__):  # the old name: not "device"
            raise TypeError(f"{type(self).__name__}: `kind` is now `device_name`")
        parse_usb_identity(port)  # a malformed usb: port is the caller's error, now
        self.port = port
        self._log = logger
        chosen = _recording(record)
        self._record_path = chosen[0] if chosen is not None else None
        self._record_opener = chosen[1] if chosen is not None else None
        self._recording: Recorder | None = None
        self._decoder = self._make_decoder()
        self._streams = Streams(queue_size)
        self._observers: set[object] = set()  # kept until closed (core.notifier)
        self._link: LinkSupervisor[M] = LinkSupervisor(
            _LinkHooks(self),
            port,
            baudrate=baudrate,
            connect_timeout=connect_timeout,
            close_linger=close_linger,
            link_timeout=link_timeout,
            reconnect=bool(reconnect),
            queue_size=queue_size,
            log=logger,
            background=background,
        )
        if not isinstance(read_only, bool):
            raise TypeError(f"read_only must be True or False, got {read_only!r}")
        self._link.writer.read_only = read_only
        self._requests: Requester[K] = Requester(
            port,
            self._link.writer.write,
            self._link.writer.ensure_open,
            timeout=request_timeout,
            retries=retries,
            log=logger,
        )
        #: Message type -> what to do with it (set up by the device); called
        #: synchronously from the link's ``data_received``, in wire order.
        self._handlers: dict[type, Callable[[Any], None]] = {}

    # --- the hooks ----------------------------------------------------------------------------

    @abc.abstractmethod
    def _make_decoder(self) -> FrameDecoder[M]:
        """The device's incremental decoder (one per device, reset per connection)."""

    def _closing_frame(self) -> bytes | None:
        """The last velocity frame at close: zero (a device may owe none)."""
        return self._zero_frame()

    @abc.abstractmethod
    def _zero_frame(self) -> bytes:
        """A zero-velocity frame: the last velocity frame on every path."""

    def _on_link_up(self) -> None:
        """Reset per-connection state (called on connect and each reconnect)."""

    def _on_fenced(self) -> None:
        """Writes are fenced off, or the link dropped: forget any active command."""

    def _on_state(self, old: ConnectionState, new: ConnectionState) -> None:
        """The connection went from ``old`` to ``new`` (before anyone hears of it)."""

    def _make_command_decoder(self) -> FrameDecoder[Any] | None:
        """A decoder of what the *host* writes (``None``: recordings keep raw bytes)."""
        return None

    async def _settle(self) -> None:
        """Closing, the final zero gone and the port still open: wait (bounded) for
        what should be read before it closes. Nothing here; a device that knows its
        motion keeps a recording going until the robot is still."""

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

    # --- the connection -------------------------------------------------------------------------

    @property
    def connection_state(self) -> ConnectionState:
        """The current [`ConnectionState`][chassis_sdk.ConnectionState]."""
        return self._link.state

    @property
    def read_only(self) -> bool:
        """True for a viewer (``read_only=True``): nothing is ever written to the
        device, not even the zero at close; commands and requests raise
        [`ChassisError`][chassis_sdk.ChassisError]."""
        return self._link.writer.read_only

    @property
    def is_connected(self) -> bool:
        """True while the port is open (``CONNECTED`` or ``STALE``)."""
        return self._link.is_open

    @property
    def port_node(self) -> str | None:
        """The device node open now (``/dev/ttyUSB1``), or ``None`` while the port is
        not open.

        `port` stays what was given. A ``usb:VID:PID[:SERIAL]`` port is looked up
        in ``serial.tools.list_ports`` at every open and every reconnect attempt, and a
        ``/dev/serial/by-id`` link is followed by the OS at each open, so after a
        replug that renumbered the adapter (``ttyUSB0`` -> ``ttyUSB1``) this names the
        new node (and the ``chassis_sdk`` logger says so at INFO). For a plain path it
        is that path's node; for ``socket://`` the URL.
        """
        return self._link.node

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
    def retries(self) -> int:
        """Extra attempts of a read-only request after a timeout (may be changed)."""
        return self._requests.retries

    @retries.setter
    def retries(self, value: int) -> None:
        self._requests.retries = check_int(value, "retries", low=0)

    def connection_states(self) -> Subscription[ConnectionState]:
        """An async iterator of `ConnectionState` changes, from the next one on.

        It ends after ``DISCONNECTED`` when the device is closed, for example:

        ```python
        async for state in robot.connection_states():
            print("link is", state.value)
        ```
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

    # --- lifetime ---------------------------------------------------------------------------------

    async def connect(self) -> None:
        """Open the port and start the background tasks.

        Raises:
            PortOpenError: The port cannot be opened (the message says why).
            ChassisError: Already connected.
        """

        def connecting() -> None:
            self._requests.table.quarantine = self._reply_quarantine()
            self._streams.reopen()

        if self._record_opener is not None and self._recording is None:
            self._recording = self._record_opener(self)
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
        [`chassis_sdk.run`][chassis_sdk.run] the program ends only once it has left. Safe to call
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
        ``None``. Connecting again after `close` starts the file anew."""
        return self._record_path

    def _stop_recording(self) -> None:
        recording, self._recording = self._recording, None
        if recording is not None:
            recording.close()

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

    # --- observing it (recorders, bridges, live views; see core.notifier) --------------------

    @property
    def stream_names(self) -> tuple[str, ...]:
        """The names of the device's streams: the methods that subscribe to them
        (``"telemetry"``, ``"odometry"``, ``"events"``, ...)."""
        return tuple(self._streams.named)

    def listen(
        self, stream: str, callback: Callable[[Any], None], *, slow: float = SLOW_CALLBACK
    ) -> Listener[Any]:
        """Call ``callback(message)`` for every message of the stream named ``stream``,
        inside the read path, until the returned handle is closed or dropped (see
        [`Notifier.listen`][chassis_sdk.core.notifier.Notifier.listen], which keeps it).

        Raises:
            ValueError: No stream of that name, or ``slow`` is not a finite number > 0.
        """
        named = self._streams.named
        found = named.get(stream)
        if found is None:
            raise ValueError(
                f"{self.device_name} has no stream {stream!r}; it has: {', '.join(named)}"
            )
        return found.listen(callback, slow=slow, stream=stream)

    def listen_states(
        self, callback: Callable[[ConnectionState], None], *, slow: float = SLOW_CALLBACK
    ) -> Listener[ConnectionState]:
        """Call ``callback(state)`` on every `ConnectionState` change (a stream named
        ``"connection_states"`` in the log and the stats), as `listen`."""
        return self._link.states.listen(callback, slow=slow, stream="connection_states")

    def add_tap(self, tap: Tap) -> None:
        """Let ``tap`` see every byte of the link, both ways (see
        [`Notifier.add_tap`][chassis_sdk.core.notifier.Notifier.add_tap])."""
        self._link.add_tap(tap)

    def remove_tap(self, tap: Tap) -> None:
        """Stop ``tap`` seeing the link's bytes (nothing if it does not)."""
        self._link.remove_tap(tap)

    def keep_observer(self, observer: object) -> None:
        """Hold ``observer`` (a `Notifier`) as long as the device lives or until
        `drop_observer`: its callbacks go on without the caller keeping it."""
        self._observers.add(observer)

    def drop_observer(self, observer: object) -> None:
        """Stop holding ``observer``."""
        self._observers.discard(observer)

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

    # --- for the device: writing, requests, streams -----------------------------------------------

    def _ensure_connected(self) -> None:
        self._link.writer.ensure_open()

    async def _send(self, frame: bytes) -> None:
        """Write a command that has no reply; return once it is handed to the port."""
        self._link.writer.write(frame)
        await anyio.lowlevel.checkpoint()

    async def _request(
        self, build: Callable[[], tuple[bytes, K]], *, read_only: bool, name: str
    ) -> Any:
        """Write a request and wait for its reply (see `Requester.call`).

        A timeout on a port where bytes arrive but no frame of this protocol does says
        so: that is another device, or the wrong baud rate, not a slow one.
        """
        try:
            return await self._requests.call(build, read_only=read_only, name=name)
        except RequestTimeoutError as exc:
            d = self._decoder.stats
            if d.bytes_received and not d.frames:
                raise RequestTimeoutError(
                    f"{exc}; {d.bytes_received} bytes arrived but none is a {self.device_name} "
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

    async def _first_match(
        self, stream: Broadcast[T], predicate: Callable[[T], bool], timeout: float, what: str
    ) -> T:
        """The latest message of ``stream`` if it satisfies ``predicate``, else the next
        one that does (a device's ``wait_for``; see `first_match`)."""
        return await first_match(stream, self._subscribe, predicate, timeout, what, self.port)

    def __repr__(self) -> str:
        return f"<{type(self).__name__} {self.port!r} {self._link.state.value}>"
