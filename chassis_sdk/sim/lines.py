"""The lines a simulator serves its device on: a pseudo-terminal behind a stable path,
or TCP clients on ``127.0.0.1:PORT``. Each delivers what the host sends to
``received(data)`` and takes what the device sends with `send`; neither knows
the firmware or the line faults."""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import tty
from collections import deque
from collections.abc import Callable

__all__ = ["PtyLine", "TcpLine"]

_log = logging.getLogger("chassis_sdk.sim")
#: Bytes the device holds while the host does not read: a firmware's transmit ring.
#: A real device cannot keep more (its UART sends on, and what the host's kernel cannot
#: take is lost); a simulator that held 64 KiB fed a host that opened the port late
#: seconds of old frames after the open had flushed the kernel's buffer.
MAX_BACKLOG = 256


class PtyLine:
    """A pseudo-terminal in raw mode, reached through the symlink ``path`` (like
    ``socat``'s ``link=``), so a re-plugged device appears at the same path, as a USB
    adapter does under its udev name.

    Args:
        path: The symlink to make (replaced atomically on every `open`).
        received: Called with each chunk the host writes.
    """

    def __init__(self, path: str, received: Callable[[bytes], None]) -> None:
        self.path = path
        self._received = received
        self._master: int | None = None
        self._slave: int | None = None
        self._backlog: deque[bytes] = deque()
        self._backlog_size = 0
        self._writer_registered = False
        #: Bytes written towards the host.
        self.bytes_sent = 0
        #: Bytes dropped because the host did not read (past :data:`MAX_BACKLOG`).
        self.bytes_discarded = 0

    @property
    def is_open(self) -> bool:
        return self._master is not None

    def open(self) -> None:
        """Make a new pty behind `path`."""
        master, slave = os.openpty()
        # Raw mode before anything else: no echo, no line discipline, 8-bit clean.
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        tmp = self.path + ".new"
        os.symlink(os.ttyname(slave), tmp)
        os.replace(tmp, self.path)  # atomic: the path is never half-made
        asyncio.get_running_loop().add_reader(master, self._readable)

    def close(self) -> None:
        """Close the pty and remove its path (the host's reads fail and reopening finds
        no device, as when a USB adapter is pulled)."""
        loop = asyncio.get_running_loop()
        if self._master is not None:
            loop.remove_reader(self._master)
            if self._writer_registered:
                loop.remove_writer(self._master)
                self._writer_registered = False
            os.close(self._master)
            self._master = None
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.path)
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None
        self._backlog.clear()
        self._backlog_size = 0

    def send(self, data: bytes) -> None:
        """Write towards the host; what the kernel cannot take waits in a bounded
        backlog (the oldest is lost past `MAX_BACKLOG`)."""
        assert self._master is not None
        if not self._backlog:
            try:
                n = os.write(self._master, data)
            except BlockingIOError:
                n = 0
            except OSError as exc:
                self._error(exc)
                return
            self.bytes_sent += n
            data = data[n:]
            if not data:
                return
        self._backlog.append(data)
        self._backlog_size += len(data)
        while self._backlog_size > MAX_BACKLOG:
            dropped = self._backlog.popleft()
            self._backlog_size -= len(dropped)
            self.bytes_discarded += len(dropped)
        if not self._writer_registered:
            asyncio.get_running_loop().add_writer(self._master, self._writable)
            self._writer_registered = True

    def _writable(self) -> None:
        assert self._master is not None
        while self._backlog:
            chunk = self._backlog[0]
            try:
                n = os.write(self._master, chunk)
            except BlockingIOError:
                return
            except OSError as exc:
                self._error(exc)
                return
            self.bytes_sent += n
            self._backlog_size -= n
            if n < len(chunk):
                self._backlog[0] = chunk[n:]
                return
            self._backlog.popleft()
        asyncio.get_running_loop().remove_writer(self._master)
        self._writer_registered = False

    def _readable(self) -> None:
        assert self._master is not None
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            self._error(exc)
            return
        if data:
            self._received(data)

    def _error(self, exc: OSError) -> None:
        if exc.errno == errno.EIO:  # nobody has the other end open; not an error
            return
        _log.warning("simulator pty error: %s", exc)


class TcpLine:
    """A TCP server on ``host:port`` (0 picks a free port, kept across re-plugs); every
    client gets what the device sends.

    Args:
        host: Interface to listen on.
        port: The port (0: any).
        received: Called with each chunk a client writes.
        connected: Called when a client connects (the firmware's clock starts).
    """

    def __init__(
        self,
        host: str,
        port: int,
        received: Callable[[bytes], None],
        connected: Callable[[], None],
    ) -> None:
        self.host = host
        self.port = port
        self._received = received
        self._connected = connected
        self._server: asyncio.Server | None = None
        self._clients: set[asyncio.StreamWriter] = set()
        self._client_tasks: set[asyncio.Task[None]] = set()
        #: Bytes written towards the host.
        self.bytes_sent = 0
        #: Bytes dropped because no client was connected.
        self.bytes_discarded = 0

    @property
    def is_open(self) -> bool:
        return self._server is not None

    @property
    def clients(self) -> int:
        """Clients connected now."""
        return len(self._clients)

    async def open(self) -> None:
        """Listen (again, on the same port)."""
        self._server = await asyncio.start_server(self._serve, self.host, self.port)
        self.port = self._server.sockets[0].getsockname()[1]

    def close(self) -> asyncio.Server | None:
        """Stop listening and drop every client; returns the server to wait for."""
        server, self._server = self._server, None
        if server is not None:
            server.close()
        for w in self._clients:
            w.close()
        self._clients.clear()  # their reader tasks end on their own (discard is a no-op)
        return server

    def cancel_clients(self) -> None:
        for task in list(self._client_tasks):
            task.cancel()

    def send(self, data: bytes) -> None:
        # A closed client stays in the set until its reader task runs; uvloop raises
        # on a write to a closed transport (asyncio ignores it), so skip those.
        if open_clients := [w for w in self._clients if not w.transport.is_closing()]:
            for w in open_clients:
                w.write(data)
            self.bytes_sent += len(data)
        else:
            self.bytes_discarded += len(data)

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._server is None:  # connected before the cable was pulled, served after
            writer.close()
            return
        task = asyncio.current_task()
        assert task is not None
        self._client_tasks.add(task)
        self._clients.add(writer)
        self._connected()
        try:
            while data := await reader.read(4096):
                self._received(data)
        except ConnectionError:
            pass
        except asyncio.CancelledError:
            # The server is stopping (cancel_clients). Ending quietly, not cancelled:
            # Python 3.11's start_server callback calls task.exception() on its client
            # task, which raises for a cancelled one ("Exception in callback ...").
            pass
        finally:
            self._clients.discard(writer)
            self._client_tasks.discard(task)
            writer.close()
