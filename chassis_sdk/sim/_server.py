"""Expose a sans-IO firmware model on a pseudo-terminal (default) or a TCP port.

The model is driven by two calls: ``receive(data, now)`` for bytes from the host (it
returns any immediate reply) and ``poll(now)`` for what is due at ``now`` (periodic
telemetry). ``next_deadline()`` says when ``poll`` next has something to do.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import time
import tty
from collections import deque
from types import TracebackType
from typing import Protocol, Self

from .._alarm import Alarm

__all__ = ["Firmware", "SimulatorServer", "next_slot"]

_log = logging.getLogger("chassis_sdk.sim")
_MAX_BACKLOG = 64 * 1024  # bytes held for a reader that does not read, like a full UART


def next_slot(previous: float, period: float, now: float) -> float:
    """The next boundary of the schedule ``previous + k * period`` after ``now``.

    A firmware that fell behind (a busy loop) skips the missed slots rather than sending
    a burst, as a real timer interrupt would.
    """
    nxt = previous + period
    return nxt if nxt > now else now + period


class Firmware(Protocol):
    """What the server needs of a firmware model."""

    def receive(self, data: bytes, now: float) -> bytes: ...

    def poll(self, now: float) -> bytes: ...

    def next_deadline(self) -> float: ...

    def on_connect(self, now: float) -> None: ...


class SimulatorServer:
    """Serves one firmware model on a pty or on ``127.0.0.1:PORT``.

    Args:
        firmware: The model.
        tcp_port: ``None`` for a pseudo-terminal; a port number (0 picks a free one) for
            TCP.
        host: Interface to listen on for TCP.
    """

    def __init__(self, firmware: Firmware, *, tcp_port: int | None = None, host: str = "127.0.0.1"):
        self.firmware = firmware
        self._tcp_port = tcp_port
        self._host = host
        self._master: int | None = None
        self._slave: int | None = None
        self._pty_path: str | None = None
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.StreamWriter] = set()
        self._client_tasks: set[asyncio.Task[None]] = set()
        self._ticker: asyncio.Task[None] | None = None
        self._backlog: deque[bytes] = deque()
        self._backlog_size = 0
        self._writer_registered = False
        self._alarm = Alarm()
        #: Bytes written towards the host.
        self.bytes_sent = 0
        #: Bytes dropped because nobody was reading.
        self.bytes_discarded = 0

    # --- lifetime -------------------------------------------------------------------------

    @property
    def port(self) -> str:
        """What to pass to ``Chassis``/``Board``: the pty path or a ``socket://`` URL."""
        if self._pty_path is not None:
            return self._pty_path
        if self._server is not None:
            host, port = self._server.sockets[0].getsockname()[:2]
            return f"socket://{host}:{port}"
        raise RuntimeError("the simulator is not running; use `async with` or start()")

    async def start(self) -> None:
        """Open the pty or start listening, and start the firmware's clock."""
        loop = asyncio.get_running_loop()
        self.firmware.on_connect(time.monotonic())
        if self._tcp_port is None:
            master, slave = os.openpty()
            # Raw mode before anything else: no echo, no line discipline, 8-bit clean.
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self._pty_path = os.ttyname(slave)
            loop.add_reader(master, self._pty_readable)
        else:
            self._server = await asyncio.start_server(
                self._serve_client, self._host, self._tcp_port
            )
        self._ticker = asyncio.create_task(self._tick(), name="simulator clock")
        _log.info("simulator listening on %s", self.port)

    async def stop(self) -> None:
        """Stop the clock and close the pty or the server (the host sees an unplug)."""
        if self._ticker is not None:
            self._ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._ticker
            self._ticker = None
        self.unplug()
        if self._server is not None:
            self._server.close()
            for w in list(self._clients):
                w.close()
            for t in list(self._client_tasks):
                t.cancel()
            await self._server.wait_closed()
            self._server = None

    def unplug(self) -> None:
        """Close the pty (the host's reads fail, as when a USB adapter is pulled) or
        drop every TCP client."""
        loop = asyncio.get_event_loop()
        if self._master is not None:
            loop.remove_reader(self._master)
            if self._writer_registered:
                loop.remove_writer(self._master)
                self._writer_registered = False
            os.close(self._master)
            self._master = None
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None
        for w in list(self._clients):
            w.close()
        self._backlog.clear()
        self._backlog_size = 0

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.stop()

    # --- the firmware's clock ---------------------------------------------------------------

    async def _tick(self) -> None:
        fw = self.firmware
        while True:
            now = time.monotonic()
            out = fw.poll(now)
            if out:
                self.send(out)
            delay = fw.next_deadline() - time.monotonic()
            if delay > 0:
                await self._alarm.sleep(min(delay, 0.1))

    def _received(self, data: bytes) -> None:
        out = self.firmware.receive(data, time.monotonic())
        if out:
            self.send(out)
        self._alarm.wake()  # a command may have changed what is due next

    # --- output ---------------------------------------------------------------------------------

    def send(self, data: bytes) -> None:
        """Write ``data`` towards the host (dropped if nobody is connected)."""
        if self._master is not None:
            self._pty_write(data)
        elif self._clients:
            for w in self._clients:
                w.write(data)
            self.bytes_sent += len(data)
        else:
            self.bytes_discarded += len(data)

    def _pty_write(self, data: bytes) -> None:
        assert self._master is not None
        if not self._backlog:
            try:
                n = os.write(self._master, data)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                self._pty_error(exc)
                return
            self.bytes_sent += n
            data = data[n:]
            if not data:
                return
        self._backlog.append(data)
        self._backlog_size += len(data)
        while self._backlog_size > _MAX_BACKLOG:
            dropped = self._backlog.popleft()
            self._backlog_size -= len(dropped)
            self.bytes_discarded += len(dropped)
        if not self._writer_registered:
            asyncio.get_event_loop().add_writer(self._master, self._pty_writable)
            self._writer_registered = True

    def _pty_writable(self) -> None:
        assert self._master is not None
        while self._backlog:
            chunk = self._backlog[0]
            try:
                n = os.write(self._master, chunk)
            except BlockingIOError:
                return
            except OSError as exc:
                self._pty_error(exc)
                return
            self.bytes_sent += n
            self._backlog_size -= n
            if n < len(chunk):
                self._backlog[0] = chunk[n:]
                return
            self._backlog.popleft()
        asyncio.get_event_loop().remove_writer(self._master)
        self._writer_registered = False

    def _pty_readable(self) -> None:
        assert self._master is not None
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            self._pty_error(exc)
            return
        if data:
            self._received(data)

    def _pty_error(self, exc: OSError) -> None:
        if exc.errno == errno.EIO:  # nobody has the other end open; not an error
            return
        _log.warning("simulator pty error: %s", exc)

    # --- TCP ------------------------------------------------------------------------------------

    async def _serve_client(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._client_tasks.add(task)
        self._clients.add(writer)
        self.firmware.on_connect(time.monotonic())
        try:
            while data := await reader.read(4096):
                self._received(data)
        except ConnectionError:
            pass
        finally:
            self._clients.discard(writer)
            self._client_tasks.discard(task)
            writer.close()
