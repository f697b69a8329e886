"""The link: one ``asyncio.Protocol`` per port, and the only module that knows which
pyserial asyncio package is in use.

Why the write path is shaped this way
-------------------------------------
A robot that stops reading its UART (a hung MCU, a USB CDC device whose firmware
stalls) fills the kernel's output buffer. pyserial's ``Serial.write`` with
``write_timeout=0`` swallows ``EAGAIN`` and loops, so a transport that calls it with a
full buffer freezes the whole event loop; and a transport that buffers without bound
sends minutes-old velocity commands the moment the device reads again. So:

* a write **never blocks or spins**. For a serial port the link writes to its own
  duplicate of the descriptor with one non-blocking ``os.write`` and, when the kernel
  takes only part of a frame, keeps the rest and waits for the descriptor itself; the
  pyserial transports never see a write. (Besides the spin, pyserial-asyncio-fast 0.16
  leaves its writer callback registered after a blocked write drains, and it then
  raises ``AssertionError`` on every loop iteration.) ``Serial.write`` is replaced by a
  single ``os.write`` anyway, and ``Serial.flush`` (a blocking ``tcdrain``, which
  pyserial-asyncio calls on the loop while closing) by a no-op. Sockets use asyncio's
  own transport with a high-water mark of 0, so it pauses the link as soon as it holds
  a byte;
* while the port cannot take bytes the link holds frames under a discipline that knows
  what they are. A **velocity frame is state, not a queue**: only the newest waits (the
  one it replaces is discarded and counted), and one whose command has expired by the
  time the port can take it is dropped, so the first velocity frame after a stall is
  never stale. Other frames (requests, e-stops) wait in order, bounded. These
  decisions are `WriteQueue`'s (sans-IO);
* writes are **eager** (pyserial-asyncio would hold every frame until the loop's next
  writer callback, so a frame queued just before the application blocks the loop
  would leave a whole block later);
* `Link.aclose` drains with a bound. If the device is still not reading then,
  every stale frame is discarded (what the link holds, and the kernel's output queue,
  with ``tcflush``) **but the final zero is kept**: it goes out at once where the flush
  made room (a serial port), or waits in the background (a socket whose kernel buffer
  cannot be flushed, a serial line held by flow control) for at most ``linger``
  seconds after ``close()`` has returned. So the last frame a device ever gets, however
  late it reads again within that bound, is the zero; the descriptors are closed once
  it has left (the kernel's output queue is empty) or the bound has passed, and then
  whatever is still held is discarded (a socket is reset, so the kernel sends nothing
  stale either). The close is the link's `Linger`'s,
  in `chassis_sdk.core.linger` (with `wait_lingering`, re-exported here).

Opening is bounded and never blocks the loop: device paths are opened in a daemon
thread (pyserial's open, its advisory ``flock`` and termios set-up are blocking calls),
``socket://host:port`` with the loop's own non-blocking connect (pyserial's socket
handler connects with a blocking 5 s call, and its ``close()`` sleeps 0.3 s), each under
``connect_timeout``. Serial devices are opened exclusively: a second opener, in this
process or another, gets [`PortOpenError`][chassis_sdk.PortOpenError] naming who holds the port.

Three transports carry device paths, the first installed preferred: **serialx** (extra
``serialx``: opens off the loop, locks the port, reads with ``os.read`` straight from
the loop), **pyserial-asyncio-fast** (extra ``fast``) and **pyserial-asyncio**.
``CHASSIS_SDK_BACKEND`` forces one. With the pyserial ones the port is opened in a
thread through ``serial.serial_for_url`` and read with one ``os.read`` too: pyserial's
``Serial.read`` first calls ``select()``, which fails for descriptors numbered 1024 and
up, and its two abort pipes (closed here) would cost four descriptors per port. Under
every transport the link writes itself, to its own duplicate of the descriptor, as
described above; a port holds two descriptors. And once the transport has delivered
the first chunk, the link reads the port itself too (`Link._read_ready`: one
``os.read`` and the chunk straight to the decoder, without the transport's Python
around it); the transport still opens, locks and closes the port.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import functools
import importlib
import logging
import math
import os
import socket
import termios
import threading
import time
import urllib.parse
from collections.abc import Callable
from typing import Any, Generic, Protocol, TypeVar, cast

import anyio
import serial

from ..errors import PortOpenError, install_hint
from .linger import CLOSE_GRACE as CLOSE_GRACE
from .linger import CLOSE_WAIT as CLOSE_WAIT
from .linger import Linger, lingering, wait_lingering
from .ports import lock_holder, parse_usb_identity, resolve_port
from .writequeue import QUEUE_LIMIT, WriteQueue

#: In order of preference: the first installed is used.
_BACKENDS = {
    "serialx": "serialx",
    "pyserial-asyncio-fast": "serial_asyncio_fast",
    "pyserial-asyncio": "serial_asyncio",
}


class _Backend:
    """The serial backend, loaded at the first open of a device path (never at import,
    so the codecs, ``--help`` and ``socket://`` links work without it)."""

    module: Any = None
    name: str | None = None
    #: What opening a device path may raise (serialx's exceptions are not OSErrors).
    open_errors: tuple[type[BaseException], ...] = (OSError, ValueError, termios.error)


def _load_backend() -> type[_Backend]:
    """The first of serialx, pyserial-asyncio-fast and pyserial-asyncio installed.

    The environment variable ``CHASSIS_SDK_BACKEND`` (``serialx``,
    ``pyserial-asyncio-fast`` or ``pyserial-asyncio``) forces one, to compare them or
    to rule one out.

    Raises:
        PortOpenError: The forced one is unknown or not installed, or none is.
    """
    if _Backend.name is not None:
        return _Backend
    forced = os.environ.get("CHASSIS_SDK_BACKEND")
    if forced:
        if forced not in _BACKENDS:
            raise PortOpenError(
                f"CHASSIS_SDK_BACKEND={forced!r}: use one of {', '.join(sorted(_BACKENDS))}"
            )
        try:
            module, name = importlib.import_module(_BACKENDS[forced]), forced
        except ImportError:
            raise PortOpenError(
                f"CHASSIS_SDK_BACKEND={forced!r} is not installed: pip install {forced}"
            ) from None
    else:
        for candidate, module_name in _BACKENDS.items():
            try:
                module, name = importlib.import_module(module_name), candidate
                break
            except ImportError:  # pragma: no cover - depends on the installed extra
                continue
        else:
            raise PortOpenError(
                "no serial backend is installed: pip install pyserial-asyncio "
                f"(or the extra fast or serialx: {install_hint('fast')})"
            )
    _Backend.module, _Backend.name = module, name
    if name == "serialx":
        _Backend.open_errors += (module.SerialException,)
    return _Backend


def backend_name() -> str:
    """The serial backend in use (``serialx``, ``pyserial-asyncio-fast`` or
    ``pyserial-asyncio``), loading it if no port has been opened yet; ``"none"`` if
    it cannot be loaded."""
    try:
        return _load_backend().name or "none"
    except PortOpenError:
        return "none"


__all__ = ["QUEUE_LIMIT", "Link", "Tap", "backend_name", "open_link", "wait_lingering"]

M = TypeVar("M")

#: The most serialx reads per wake-up. Its default, 256 KiB, is past glibc's mmap
#: threshold (128 KiB): every read then maps, shrinks and unmaps a buffer, which costs
#: time on every read and every request round trip (figures: docs/figures.md,
#: benchmarks/read_size.py). 64 KiB is served from the heap and still drains more than
#: half a second of a 1 Mbaud line in one read.
READ_SIZE = 64 * 1024

#: The kernel send buffer of a ``socket://`` link, asked for (Linux doubles it, and
#: counts each small frame at several hundred bytes: some 14 frames in all), so what a
#: device that stops reading has not taken waits in the link, where velocity is state.
SOCKET_SNDBUF = 4096


class Decoder(Protocol[M]):
    """What the link needs of a decoder."""

    def feed(self, data: bytes, timestamp: float = 0.0) -> list[M]: ...

    def reset(self) -> None: ...


class Tap(Protocol):
    """Sees every byte of a link, both ways (a recorder): called synchronously, so it
    must be quick and must not raise."""

    def rx(self, data: bytes, now: float) -> None:
        """``data`` arrived at ``now`` (``time.monotonic()``)."""

    def tx(self, data: bytes, now: float) -> None:
        """The frame ``data`` began to leave at ``now``."""


class Link(asyncio.Protocol, Generic[M]):
    """Feeds received bytes to the decoder synchronously and hands each message on;
    writes frames without ever blocking, under the discipline described above.

    Args:
        decoder: The protocol's decoder (kept across reconnects for its stats).
        on_messages: Called once per received chunk that decoded into messages, with
            the messages in wire order and the ``time.monotonic()`` of their arrival
            (one call per chunk, not per message: the hot path stays flat).
        on_lost: Called once when the connection is lost, with the error if any.
        logger: Hex dumps go here at DEBUG.
    """

    def __init__(
        self,
        decoder: Decoder[M],
        on_messages: Callable[[list[M], float], None],
        on_lost: Callable[[Exception | None], None],
        logger: logging.Logger,
    ) -> None:
        self._decoder = decoder
        self._on_messages = on_messages
        self._on_lost = on_lost
        self._log = logger
        # What the logger knows of its levels (CPython's Logger._cache, emptied by every
        # change of level or disable()): a False there is what isEnabledFor would
        # answer, so a read asks it nothing when DEBUG is off (it is a Python call).
        self._levels: dict[int, bool] = getattr(logger, "_cache", {})
        self._loop = asyncio.get_running_loop()
        self.transport: asyncio.WriteTransport | None = None
        self.closed = self._loop.create_future()
        # For a serial port: our own duplicate of its descriptor, written to directly.
        # pyserial's transports never see a write (see the module docstring), and the
        # duplicate outlives their close of the original until we are done with it.
        self._wfd: int | None = None
        # For a serial port: the descriptor the transport reads, which the link reads
        # itself once the transport has delivered the first chunk (see `_read_ready`).
        self._rfd: int | None = None
        self._blocked = False  # the port cannot take bytes now
        self._partial = b""  # the unsent rest of a frame (serial ports)
        # What waits while the port cannot take bytes, and what is discarded.
        self._held = WriteQueue()
        self._lost = 0  # discarded outside it: part-sent frames, asyncio's buffer
        self._write_error: Exception | None = None
        self._read_error: Exception | None = None
        self._flushed: asyncio.Future[None] | None = None
        #: The ``time.monotonic()`` of the last chunk that decoded into messages.
        self.received_at: float | None = None
        self._intercept: Callable[[Link[M]], None] | None = None
        #: Set by the owner once it has counted this link's losses.
        self.accounted = False
        #: Sees every byte both ways (a recorder), or ``None``.
        self.tap: Tap | None = None
        #: The port's name (set by :func:`open_link`), for the lingering registry.
        self.url = ""
        #: The device node open (``/dev/ttyUSB1``; set by :func:`open_link`): the node a
        #: ``usb:`` port or a ``/dev/serial/by-id`` link reached; a socket's URL.
        self.node = ""
        self._finished = False  # closed, or half-closed (a socket), with nothing held
        # The close (bounded drain, stale frames discarded, the final zero kept and
        # lingering): it reads and changes the write state above.
        self._closing = Linger(self)

    # --- asyncio.Protocol ---------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if self.transport is not None:  # called again by the transport's call_soon
            return
        self.transport = cast(asyncio.WriteTransport, transport)
        fd = _serial_fd(transport.get_extra_info("serial"))
        if fd is not None:
            self._wfd = os.dup(fd)
            if hasattr(transport, "_read_ready"):  # all three; another reads itself
                self._rfd = fd
        else:
            # asyncio's socket transport: pause as soon as it holds a byte, so that
            # from then on the link holds frames itself.
            self.transport.set_write_buffer_limits(high=0, low=0)
            # It reads itself, always: its chunks go straight to the work.
            self.data_received = self._read_ready  # type: ignore[method-assign]

    def data_received(self, data: bytes) -> None:
        if self._rfd is not None:
            # The transport's reader delivered this: from now on the link reads itself.
            # (Its reader was registered by now; the pyserial transports register it
            # only after connection_made, so it may have replaced the link's.)
            self._read_here(self._rfd)
        self._read_ready(data)

    def _read_here(self, fd: int) -> None:
        """Make the link's `_read_ready` the port's read callback. It replaces the one
        registered, and cancels a call of it the loop had already queued."""
        self._loop.add_reader(fd, self._read_ready)

    def _read_ready(self, data: bytes | None = None) -> None:
        """The link's own read callback, in place of the transport's (called with no
        ``data``: one ``os.read``), and what `data_received` hands the transport's
        chunks to: the chunk to the tap and the decoder, its messages on.

        Every transport's read callback is Python of its own around the same
        ``os.read`` (serialx logs twice per read at DEBUG level, the pyserial ones go
        through ``Serial.read``), and at 50 Hz that is a good part of what a chassis
        costs beyond the read itself (docs/figures.md), as is every call on this path:
        one function serves both. Should a transport register its reader again
        (``resume_reading``; the SDK never pauses reading), it simply delivers through
        `data_received` again; the transport removes whichever reader is registered
        when it closes. A read that fails, or finds the device gone (readable, no
        data), ends the link once, with that error: the reader is removed, so there is
        no error per wake-up, and the transport is aborted. (The first chunk is the
        transport's read; for the pyserial transports that is `_fd_reader`, which meets
        the same conditions in the way they expect.)
        """
        if data is None:
            try:
                data = os.read(self._rfd, READ_SIZE)  # type: ignore[arg-type]  # (no cast() call)
            except (BlockingIOError, InterruptedError):
                return
            except Exception as exc:  # whatever it is, the port is lost, once
                self._lose_reading(exc)
                return
            if not data:  # what the kernel says of a tty hung up: the device has gone
                self._lose_reading(
                    OSError(errno.EIO, "the port reports data but has none: device disconnected?")
                )
                return
        now = time.monotonic()
        if self._levels.get(logging.DEBUG) is not False and self._log.isEnabledFor(logging.DEBUG):
            self._log.debug("rx %s", data.hex(" "))
        if self.tap is not None:
            self.tap.rx(data, now)
        messages = self._decoder.feed(data, now)
        if messages:
            self.received_at = now
            if self._intercept is not None:
                intercept, self._intercept = self._intercept, None
                intercept(self)
            self._on_messages(messages, now)

    def intercept(self, call: Callable[[Link[M]], None]) -> None:
        """Call ``call(link)`` once, before the messages of the next chunk that holds
        any are handed on (a stale link's first frame: see the supervisor)."""
        self._intercept = call

    def _lose_reading(self, exc: Exception) -> None:
        self._read_error = exc
        rfd, self._rfd = self._rfd, None
        transport = self.transport
        if rfd is not None and transport is not None:
            self._loop.remove_reader(rfd)
            transport.abort()

    def connection_lost(self, exc: Exception | None) -> None:
        self._rfd = None
        self.transport = None
        self.drop_held()
        self.release_write_fd()
        self._wake_flushed()
        if not self.closed.done():
            self.closed.set_result(None)
        if exc is None:  # an abort by the link: why it aborted
            exc = self._read_error or self._write_error
        self._on_lost(exc)

    def pause_writing(self) -> None:
        self._blocked = True

    def resume_writing(self) -> None:
        self._blocked = False
        self._send_held()

    def flush_input(self) -> None:
        """Discard what the port received before now (a serial port's kernel buffer and
        any part-frame the decoder holds), so the first frame handed on is fresh.

        A USB serial adapter keeps receiving while no program has the port open, and a
        device's frames pile up in the kernel; opening (and reopening after an outage)
        must not hand them to the application as if they were new. Both pyserial and
        serialx flush on open today, but this promise is the SDK's, so it is kept here
        whatever the transport does. A TCP connection is new: nothing in it is old.

        The link takes the port's reading over first: a read callback the loop had
        queued for bytes the flush then discards would find the port empty, which a
        tty reads as 0 bytes and every transport as a device unplugged.
        """
        if self._wfd is not None:
            if self._rfd is not None:
                self._read_here(self._rfd)
            with contextlib.suppress(OSError, termios.error):
                termios.tcflush(self._wfd, termios.TCIFLUSH)
            self._decoder.reset()

    # --- writing -----------------------------------------------------------------------

    @property
    def discarded(self) -> int:
        """Frames the link discarded: velocity frames replaced by newer ones or expired
        while the port could not take them, frames over the queue limit, and whatever
        was still held when the link was closed."""
        return self._held.discarded + self._lost

    @property
    def is_open(self) -> bool:
        """True while frames can be handed to the port."""
        transport = self.transport
        return transport is not None and not transport.is_closing() and not self._finished

    def write(self, frame: bytes) -> bool:
        """Write a frame that is not a velocity command (a request, an e-stop, ...).

        Frames keep their order. While the port cannot take bytes they wait, up to
        `QUEUE_LIMIT` bytes; past that the frame is discarded and counted.

        Returns:
            False if the link is not open or the frame had to be discarded.
        """
        if not self.is_open:
            return False
        held = self._held
        if self._blocked or held.holds:
            return held.push(frame)
        if not self._emit(frame):
            held.hold(frame)
        return True

    def write_velocity(self, frame: bytes, expires: float = math.inf) -> bool:
        """Write a velocity frame: state, not a queue.

        While the port cannot take bytes only the newest velocity frame waits (the one
        it replaces is discarded and counted), and it is dropped if ``expires``
        (``time.monotonic()``) has passed by the time the port can take it.

        Returns:
            False if the link is not open or velocity frames are closed off.
        """
        held = self._held
        if not self.is_open or held.velocity_closed:
            return False
        if self._blocked or held.waiting or not self._emit(frame):
            held.put_velocity(frame, expires)
        return True

    def close_velocity(self, zero: bytes) -> bool:
        """Write ``zero`` as the last velocity frame this link will ever carry.

        It replaces any velocity frame still waiting ("zero wins"), and every later
        `write_velocity` is refused, so nothing but zero can follow it.
        """
        sent = self.write_velocity(zero)
        self._held.close_velocity(zero)
        return sent

    def _emit(self, frame: bytes) -> bool:
        """Hand ``frame`` to the port now; False if the port took none of it (the
        caller holds it under its discipline). A frame partly taken is completed
        first, whatever comes after it, so the device never sees half a frame."""
        wfd = self._wfd
        if wfd is None:  # asyncio's own socket transport: never blocks, never spins
            cast(asyncio.WriteTransport, self.transport).write(frame)
            n = len(frame)
        else:
            # Eagerly, so that a frame never waits for a later loop iteration.
            n = self._write_fd(wfd, frame)
            if 0 <= n < len(frame):
                self._blocked = True
                self._partial = frame[n:] if n else b""
                self._loop.add_writer(wfd, self._writable)
        if n > 0:
            if self._log.isEnabledFor(logging.DEBUG):
                self._log.debug("tx %s", frame.hex(" "))
            if self.tap is not None:
                self.tap.tx(frame, time.monotonic())
        return n != 0

    def _write_fd(self, wfd: int, data: bytes) -> int:
        """One non-blocking write; -1 if the port failed (the link is then aborted)."""
        try:
            return os.write(wfd, data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError as exc:  # the device is gone; reading will notice it too
            self._write_error = exc
            self._partial = b""
            self.release_write_fd()
            if self.transport is not None:
                self.transport.abort()
            return -1

    def _writable(self) -> None:
        wfd = self._wfd
        if wfd is None:
            return
        if self._partial:
            n = self._write_fd(wfd, self._partial)
            if n < 0:
                return
            self._partial = self._partial[n:]
            if self._partial:
                return
        self._loop.remove_writer(wfd)
        self._blocked = False
        self._send_held()

    def _send_held(self) -> None:
        held = self._held
        while held.holds and not self._blocked and self.is_open:
            # An expired velocity frame is dropped here, never sent.
            frame = held.peek(time.monotonic())
            if frame is None or not self._emit(frame):
                break
            held.pop()
        if self.is_flushed():
            self._wake_flushed()

    # --- the close's hooks (`chassis_sdk.core.linger.Closable`) ------------------------

    @property
    def loop(self) -> asyncio.AbstractEventLoop:
        """The loop the link runs on."""
        return self._loop

    @property
    def log(self) -> logging.Logger:
        """The logger the link reports to."""
        return self._log

    @property
    def write_fd(self) -> int | None:
        """Our own descriptor of a serial port, written to directly; ``None`` for a
        socket (and once released)."""
        return self._wfd

    @property
    def finished(self) -> bool:
        """Closed, or half-closed (a socket), with nothing held."""
        return self._finished

    @property
    def holds_zero(self) -> bool:
        """The final zero is held, waiting for the port to take it."""
        return self._held.zero is not None

    def mark_finished(self) -> None:
        """Nothing more will be written (the close has begun to end the port)."""
        self._finished = True

    def stop_receiving(self) -> None:
        """Nobody listens any more: what arrives from now on is decoded for nothing,
        and the tap sees nothing more (a recording is closed once close() returns)."""
        self._on_messages = _ignore_messages
        self._intercept = None
        self.tap = None

    def discard_partial(self) -> None:
        """Drop the unsent rest of a part-sent frame (counted as lost)."""
        self._lost += bool(self._partial)
        self._partial = b""

    def keep_only_the_zero(self, flushed: bool) -> None:
        """Discard every frame held but the final zero, kept whole (``flushed``: the
        kernel's output queue was flushed too, which made room: write again now)."""
        wfd = self._wfd
        if flushed and self._blocked and wfd is not None:
            self._loop.remove_writer(wfd)
            self._blocked = False
        if self._held.discard_stale(flushed):
            self._send_held()

    def count_lost(self) -> None:
        """One frame lost outside the held ones (what asyncio's transport still held)."""
        self._lost += 1

    def drop_held(self) -> None:
        """Discard everything held, the zero too, and a part-sent frame's rest."""
        self._held.drop_all()
        self.discard_partial()

    def release_write_fd(self) -> None:
        """Close our own descriptor of a serial port (once the port is closed)."""
        wfd, self._wfd = self._wfd, None
        if wfd is not None:
            self._loop.remove_writer(wfd)
            os.close(wfd)

    # --- draining and closing ---------------------------------------------------------

    def is_flushed(self) -> bool:
        """Everything written has left the link (and asyncio's transport)."""
        transport = self.transport
        if transport is None:
            return True
        if self._blocked or self._held.holds:
            return False
        return self._wfd is not None or transport.get_write_buffer_size() == 0

    def _wake_flushed(self) -> None:
        waiter = self._flushed
        if waiter is not None and not waiter.done():
            waiter.set_result(None)

    async def drain(self, timeout: float) -> bool:
        """Wait (at most ``timeout`` s) until every written byte has left for the port.

        Returns:
            True if everything left; False if something is still held.
        """
        try:
            with anyio.fail_after(timeout):
                while not self.is_flushed():
                    self._flushed = waiter = self._loop.create_future()
                    try:
                        await waiter
                    finally:
                        self._flushed = None
        except TimeoutError:
            pass
        return self.is_flushed()

    async def aclose(self, timeout: float, linger: float = 0.0) -> None:
        """Close the port: at once if everything written has left, else see
        `chassis_sdk.core.linger` (stale frames discarded, the final zero kept).

        Args:
            timeout: The most this waits for the port to report closing.
            linger: Seconds the final zero may take to leave, in the background after
                this has returned, for a device that is not reading; 0: what has not
                left within a moment is discarded, the zero with it.
        """
        await self._closing.aclose(timeout, linger)

    async def lingered(self) -> None:
        """Wait until this link's background close (if any) is over; a cancellation
        stops the wait, not the close."""
        await self._closing.lingered()


def _ignore_messages(messages: list[Any], now: float) -> None:
    """The sink of a link that is closing."""


# --- opening ---------------------------------------------------------------------------


def _describe_open_error(url: str, exc: BaseException, node: str | None = None) -> str:
    """One line: why ``url`` did not open and what to do. ``node`` is the path that
    was opened (a ``usb:`` port's device node): the lock and the hints are its."""
    node = node or url
    if node != url:
        url = f"{url} ({node})"
    err = getattr(exc, "errno", None)
    text = str(exc)
    locked = "exclusively lock" in text or "already locked" in text  # pyserial, serialx
    if locked or err in (errno.EAGAIN, errno.EWOULDBLOCK, errno.EBUSY):
        holder = lock_holder(node)
        return f"could not open {url}: port busy, held by " + (
            holder or "another program (close it, or check `fuser -v " + node + "`)"
        )
    if (
        err == errno.ENOENT
        or "No such file" in text
        or ("could not open port" in text and ("[Errno 2]" in text))
    ):
        return f"could not open {url}: no such device (is it plugged in? check `ls /dev/tty*`)"
    if err == errno.EACCES or "[Errno 13]" in text or "Permission denied" in text:
        return (
            f"could not open {url}: permission denied (add yourself to the group that "
            "owns the device, usually `sudo usermod -aG dialout $USER`, then log in again)"
        )
    if err == errno.ECONNREFUSED or "Connection refused" in text or "[Errno 111]" in text:
        return f"could not open {url}: connection refused (is the server running?)"
    if err == errno.EISDIR or "Is a directory" in text:
        return f"could not open {url}: it is a directory, not a serial port"
    if err == errno.ENOTTY or "Inappropriate ioctl" in text:
        return f"could not open {url}: not a serial port (it takes no serial settings)"
    if isinstance(exc, socket.gaierror):
        host = urllib.parse.urlsplit(url).hostname
        return f"could not open {url}: cannot resolve the host {host!r}"
    return f"could not open {url}: {text}"


def _serial_fd(ser: object) -> int | None:
    """The descriptor of a serial port object of either library (``None`` if none)."""
    if isinstance(ser, serial.Serial):
        return ser.fd if ser.fd is not None else None
    fileno = getattr(ser, "fileno", None)
    if ser is not None and callable(fileno):
        with contextlib.suppress(Exception):
            fd = fileno()
            if isinstance(fd, int) and fd >= 0:
                return fd
    return None


def _open_serial(url: str, baudrate: int) -> serial.Serial:
    ser = serial.serial_for_url(
        url, baudrate=baudrate, bytesize=8, parity="N", stopbits=1, exclusive=True
    )
    fd = ser.fd
    os.set_blocking(fd, False)
    # One non-blocking os.write: EAGAIN surfaces as BlockingIOError, which the pyserial
    # transports handle by waiting; pyserial's own loop would spin on it.
    ser.write = lambda data: os.write(fd, bytes(data))
    ser.flush = lambda: None  # a blocking tcdrain; the link drains with a bound itself
    ser.read = _fd_reader(fd)
    # pyserial's two "abort" pipes (4 descriptors) serve only its blocking read and
    # write, which are replaced above: close them, and close the port without them.
    for name in (
        "pipe_abort_read_r",
        "pipe_abort_read_w",
        "pipe_abort_write_r",
        "pipe_abort_write_w",
    ):
        pipe_fd = getattr(ser, name, None)
        if pipe_fd is not None:
            os.close(pipe_fd)
            setattr(ser, name, None)
    ser.close = functools.partial(_close_serial, ser)
    return ser


def _fd_reader(fd: int) -> Callable[[int], bytes]:
    """The transports' read: one ``os.read`` of what is there.

    pyserial's ``Serial.read`` first calls ``select()``, which fails for every
    descriptor numbered 1024 or above (a process with some 200 ports open), and builds
    a ``Timeout`` object per wake-up. Whatever fails here is a ``SerialException``,
    which the pyserial transports turn into a lost link, once; anything else would
    escape their read callback and be logged on every wake-up, forever.
    """

    def read(size: int = 1) -> bytes:
        try:
            data = os.read(fd, size)
        except (BlockingIOError, InterruptedError):
            return b""  # a spurious wake-up
        except Exception as exc:
            raise serial.SerialException(f"read failed: {exc}") from exc
        if not data:  # readable but empty: the device is gone (as pyserial says it)
            raise serial.SerialException(
                "device reports readiness to read but returned no data "
                "(device disconnected or multiple access on port?)"
            )
        return data

    return read


def _close_serial(ser: serial.Serial) -> None:
    """pyserial's ``close`` without the abort pipes `_open_serial` closed."""
    if ser.is_open:
        if ser.fd is not None:
            os.close(ser.fd)
            ser.fd = None
        ser.is_open = False


async def _open_serial_in_thread(url: str, baudrate: int) -> serial.Serial:
    """Open in a daemon thread: a hung open can neither block the loop nor keep the
    interpreter from exiting; if nobody is waiting any more, the port is closed."""
    loop = asyncio.get_running_loop()
    fut: asyncio.Future[serial.Serial] = loop.create_future()

    def deliver(ser: serial.Serial | None, exc: BaseException | None) -> None:
        if fut.done():  # cancelled or timed out meanwhile
            if ser is not None:
                ser.close()
        elif exc is not None:
            fut.set_exception(exc)
        else:
            fut.set_result(cast(serial.Serial, ser))

    def work() -> None:
        ser: serial.Serial | None = None
        exc: BaseException | None = None
        try:
            ser = _open_serial(url, baudrate)
        except BaseException as e:
            exc = e
        try:
            loop.call_soon_threadsafe(deliver, ser, exc)
        except RuntimeError:  # the loop is closed: nobody will ever take it
            if ser is not None:
                ser.close()

    threading.Thread(target=work, name=f"chassis_sdk open {url}", daemon=True).start()
    return await fut


async def _open_device(
    loop: asyncio.AbstractEventLoop,
    link_factory: Callable[[], Link[Any]],
    path: str,
    baudrate: int,
) -> tuple[asyncio.BaseTransport, Any]:
    """Open the device path ``path`` (as given: a symlink is followed by the OS, at
    this open) through the serial backend."""
    backend = _load_backend()
    if backend.name == "serialx":
        # Opened off the loop, locked (flock), read with os.read from the loop.
        transport, protocol = await backend.module.create_serial_connection(
            loop, link_factory, path, baudrate, exclusive=True
        )
        if isinstance(getattr(transport, "max_size", None), int):
            setattr(transport, "max_size", READ_SIZE)  # noqa: B010 (not typed)
        return transport, protocol
    ser = await _open_serial_in_thread(path, baudrate)
    transport, protocol = await backend.module.connection_for_serial(loop, link_factory, ser)
    return transport, protocol


def _opened_node(link: Link[Any], path: str) -> str:
    """The device node the link has open: what its descriptor is (a symlink may have
    moved since the open), else where ``path`` points now."""
    fd = link._wfd
    if fd is not None:
        with contextlib.suppress(OSError):
            return os.readlink(f"/proc/self/fd/{fd}")
    return os.path.realpath(path)


async def _still_the_identity(url: str, path: str, transport: asyncio.BaseTransport) -> None:
    """After opening the node a ``usb:`` identity was found at, look it up again: if
    the adapter left and another took its node in between (a replug, two adapters),
    the node open now is not this robot's. Close it and say so (a ``PortOpenError``:
    a reconnecting device tries again).

    Raises:
        PortOpenError: The identity is no longer at ``path``.
    """
    try:
        now = await anyio.to_thread.run_sync(resolve_port, url, abandon_on_cancel=True)
    except PortOpenError:
        now = None
    if now != path:
        transport.close()
        where = f"at {now}" if now is not None else "gone"
        raise PortOpenError(f"could not open {url}: it moved while opening ({path}, now {where})")


async def open_link(
    url: str,
    baudrate: int,
    link_factory: Callable[[], Link[Any]],
    *,
    timeout: float = 2.0,
) -> Link[Any]:
    """Open ``url`` (device path, pty path, ``/dev/serial/by-id`` link,
    ``usb:VID:PID[:SERIAL]`` or ``socket://host:port``) at 8N1.

    A ``usb:`` port is looked up now (`resolve_port`, off
    the loop), so every open and every reconnect attempt finds the device wherever it
    is; a path is opened as given (the OS follows a symlink at each open). The node
    opened is the link's `Link.node`. Bounded by ``timeout`` and
    cancellation-safe: whatever was opened is closed again if the open does not
    complete.

    Raises:
        ValueError: A malformed ``usb:`` port (before anything is looked up).
        PortOpenError: The port cannot be opened; the message says why and what to do
            (`PortNotFoundError`: no such USB device is
            attached now, or several are).
    """
    loop = asyncio.get_running_loop()
    usb = parse_usb_identity(url) is not None
    parsed = urllib.parse.urlsplit(url)
    transport: asyncio.BaseTransport | None = None
    path = url  # what is opened: a usb: port's node once it is found
    earlier = lingering(loop, url)
    try:
        with anyio.fail_after(timeout):
            if earlier is not None:
                # The previous link's final zero still waits for the device: it must be
                # the last frame of that session, so this open waits for it (bounded).
                await earlier.lingered()
                earlier = None
            if parsed.scheme == "socket":
                try:
                    port = parsed.port
                except ValueError:  # not a number, or out of range
                    port = None
                if not parsed.hostname or port is None:
                    raise ValueError("a socket URL needs a host and a port: socket://HOST:PORT")
                transport, protocol = await loop.create_connection(
                    link_factory, parsed.hostname, port
                )
                sock = transport.get_extra_info("socket")
                if sock is not None:
                    # A small kernel send buffer: frames then wait in the link, where
                    # velocity is state, not in megabytes of kernel buffer the device
                    # would work through, seconds of stale commands, if it read again.
                    with contextlib.suppress(OSError):
                        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SOCKET_SNDBUF)
            elif "://" in url and not usb:
                raise ValueError(
                    f"unsupported URL scheme {parsed.scheme!r}: use a device path or "
                    "socket://host:port"
                )
            else:
                if usb:
                    # comports() reads sysfs: off the loop, under the same bound.
                    path = await anyio.to_thread.run_sync(resolve_port, url, abandon_on_cancel=True)
                transport, protocol = await _open_device(loop, link_factory, path, baudrate)
                if usb:
                    await _still_the_identity(url, path, transport)
    except TimeoutError:
        if earlier is not None:
            raise PortOpenError(
                f"could not open {url}: the previous connection's final stop still waits "
                f"for the device to read (close_linger), after {timeout:g} s"
            ) from None
        raise PortOpenError(
            f"could not open {url}: no answer within {timeout:g} s (connect_timeout)"
        ) from None
    except PortOpenError:
        raise
    except _Backend.open_errors as exc:
        # serial.SerialException is an OSError subclass; bad URLs raise ValueError.
        raise PortOpenError(_describe_open_error(url, exc, path)) from exc
    link: Link[Any] = protocol
    # pyserial's transports only schedule connection_made() (call_soon): the link can
    # write from now on.
    link.connection_made(transport)
    link.url = url
    link.node = url if parsed.scheme == "socket" else _opened_node(link, path)
    link.flush_input()
    return link
