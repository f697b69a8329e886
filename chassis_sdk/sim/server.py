"""Expose a sans-IO firmware model on a pseudo-terminal (default) or a TCP port.

The model is driven by two calls: ``receive(data, now)`` for bytes from the host (it
returns any immediate reply) and ``poll(now)`` for what is due at ``now`` (periodic
telemetry). ``next_deadline()`` says when ``poll`` next has something to do.

The server is also where the line's faults live (:class:`LineFaults`: noise, bit
flips, lost bytes, late or lost replies) and where the cable is pulled
(:meth:`SimulatorServer.unplug`) and put back (:meth:`SimulatorServer.replug`). The
pty is reached through a symlink that the server owns, like ``socat``'s ``link=``, so
a re-plugged device appears at the same path, as a USB adapter does under its udev
name.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import random
import shutil
import tempfile
import time
import tty
from collections import deque
from dataclasses import dataclass, field
from types import TracebackType
from typing import Self

from ..core.alarm import Alarm
from ..core.firmware import Firmware
from ..core.validation import check_probability, check_real

__all__ = ["FaultCounts", "LineFaults", "SimulatorServer", "damage"]

_log = logging.getLogger("chassis_sdk.sim")
#: Bytes the device holds while the host does not read: a firmware's transmit ring.
#: A real device cannot keep more (its UART sends on, and what the host's kernel cannot
#: take is lost); a simulator that held 64 KiB fed a host that opened the port late
#: seconds of old frames after the open had flushed the kernel's buffer.
_MAX_BACKLOG = 256


@dataclass(slots=True)
class LineFaults:
    """Damage done to what the simulated device sends, as a noisy line would.

    Rates are probabilities per byte sent (``noise_rate=0.01``: about one junk byte per
    hundred); change them at any time on a running server (``sim.faults.drop_rate =
    0.001``). Host-to-device bytes are not damaged.

    Attributes:
        noise_rate: Chance that a random byte is inserted before each byte.
        bit_flip_rate: Chance that one random bit of a byte is flipped.
        drop_rate: Chance that a byte is lost.
        reply_delay: Seconds each reply to a request is held back.
        reply_loss: Chance that a reply to a request is not sent at all.
        seed: Seed of the fault generator, for repeatable runs.
    """

    noise_rate: float = 0.0
    bit_flip_rate: float = 0.0
    drop_rate: float = 0.0
    reply_delay: float = 0.0
    reply_loss: float = 0.0
    seed: int | None = None
    _rng: random.Random = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("noise_rate", "bit_flip_rate", "drop_rate", "reply_loss"):
            check_probability(getattr(self, name), name)
        check_real(self.reply_delay, "reply_delay", low=0, unit="s")
        self._rng = random.Random(self.seed)

    @property
    def damages_bytes(self) -> bool:
        """True if any per-byte fault is switched on."""
        return bool(self.noise_rate or self.bit_flip_rate or self.drop_rate)


@dataclass(slots=True)
class FaultCounts:
    """What the server's fault injection actually did (for tests to check against)."""

    noise_bytes: int = 0
    flipped_bytes: int = 0
    dropped_bytes: int = 0
    delayed_replies: int = 0
    lost_replies: int = 0


def damage(data: bytes, faults: LineFaults, counts: FaultCounts) -> bytes:
    """Apply ``faults``'s per-byte damage to ``data``, counting it in ``counts``."""
    rng = faults._rng
    rand = rng.random
    noise, flip, drop = faults.noise_rate, faults.bit_flip_rate, faults.drop_rate
    out = bytearray()
    for byte in data:
        if noise and rand() < noise:
            out.append(rng.randrange(256))
            counts.noise_bytes += 1
        if drop and rand() < drop:
            counts.dropped_bytes += 1
            continue
        if flip and rand() < flip:
            byte ^= 1 << rng.randrange(8)
            counts.flipped_bytes += 1
        out.append(byte)
    return bytes(out)


class SimulatorServer:
    """Serves one firmware model on a pty or on ``127.0.0.1:PORT``.

    Args:
        firmware: The model.
        tcp_port: ``None`` for a pseudo-terminal; a TCP port (0 picks a free one).
        host: Interface to listen on for TCP.
        faults: Line faults to start with (``faults`` can be changed while it runs).
    """

    def __init__(
        self,
        firmware: Firmware,
        *,
        tcp_port: int | None = None,
        host: str = "127.0.0.1",
        faults: LineFaults | None = None,
    ):
        self.firmware = firmware
        self.faults = faults if faults is not None else LineFaults()  # applied to all sent
        self.fault_counts = FaultCounts()  # what injection did
        self._tcp_port = tcp_port
        self._host = host
        self._master: int | None = None
        self._slave: int | None = None
        self._link_dir: str | None = None
        self._link_path: str | None = None
        self._server: asyncio.Server | None = None
        self._delayed: set[asyncio.TimerHandle] = set()
        self._started = False
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
        """What to pass to ``Chassis``/``Board``: the pty's stable path (a symlink the
        server owns) or a ``socket://127.0.0.1:PORT`` URL. It stays the same across
        :meth:`unplug` and :meth:`replug`."""
        if self._link_path is not None:
            return self._link_path
        if self._tcp_port is not None and self._started:
            return f"socket://{self._host}:{self._tcp_port}"
        raise RuntimeError("the simulator is not running; use `async with` or start()")

    @property
    def plugged(self) -> bool:
        """True while the pty is open or the TCP port is listening."""
        return self._master is not None or self._server is not None

    async def start(self) -> None:
        """Open the pty or start listening, and start the firmware's clock."""
        self.firmware.on_connect(time.monotonic())
        if self._tcp_port is None:
            self._link_dir = tempfile.mkdtemp(prefix="chassis-sim-")
            self._link_path = os.path.join(self._link_dir, "tty")
        self._started = True
        await self.replug()
        self._ticker = asyncio.create_task(self._tick(), name="simulator clock")
        _log.info("simulator listening on %s", self.port)

    async def stop(self) -> None:
        """Stop the clock and close the pty or the server (the host sees an unplug)."""
        if self._ticker is not None:
            self._ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._ticker
            self._ticker = None
        await self._unplug()
        for t in list(self._client_tasks):
            t.cancel()
        if self._link_dir is not None:
            shutil.rmtree(self._link_dir, ignore_errors=True)
            self._link_dir = None
            self._link_path = None
        self._started = False

    async def replug(self) -> None:
        """Plug the device (back) in: a new pty behind the same path, or listen on the
        same TCP port again. Does nothing if it is plugged in."""
        if self.plugged:
            return
        if self._tcp_port is None:
            assert self._link_path is not None
            master, slave = os.openpty()
            # Raw mode before anything else: no echo, no line discipline, 8-bit clean.
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            tmp = self._link_path + ".new"
            os.symlink(os.ttyname(slave), tmp)
            os.replace(tmp, self._link_path)  # atomic: the path is never half-made
            asyncio.get_running_loop().add_reader(master, self._pty_readable)
        else:
            self._server = await asyncio.start_server(
                self._serve_client, self._host, self._tcp_port
            )
            self._tcp_port = self._server.sockets[0].getsockname()[1]

    def unplug(self) -> None:
        """Pull the cable: close the pty and remove its path (the host's reads fail and
        reopening finds no device, as when a USB adapter is pulled), or stop listening
        and drop every TCP client. The firmware keeps running; :meth:`replug` puts the
        device back."""
        loop = asyncio.get_running_loop()
        if self._master is not None:
            loop.remove_reader(self._master)
            if self._writer_registered:
                loop.remove_writer(self._master)
                self._writer_registered = False
            os.close(self._master)
            self._master = None
            if self._link_path is not None:
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(self._link_path)
        if self._slave is not None:
            os.close(self._slave)
            self._slave = None
        if self._server is not None:
            self._server.close()
            self._server = None
        for w in self._clients:
            w.close()
        self._clients.clear()  # their reader tasks end on their own (discard is a no-op)
        for handle in self._delayed:
            handle.cancel()
        self._delayed.clear()
        self._backlog.clear()
        self._backlog_size = 0

    def reset_firmware(self, downtime: float = 0.5) -> None:
        """Reboot the firmware now (see the model's ``reset``); the line stays up."""
        self.firmware.reset(time.monotonic(), downtime)
        self._alarm.wake()

    async def _unplug(self) -> None:
        server = self._server
        self.unplug()
        if server is not None:
            await server.wait_closed()

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
            self._reply(out)
        self._alarm.wake()  # a command may have changed what is due next

    def _reply(self, out: bytes) -> None:
        faults = self.faults
        if faults.reply_loss and faults._rng.random() < faults.reply_loss:
            self.fault_counts.lost_replies += 1
            return
        if faults.reply_delay > 0:
            self.fault_counts.delayed_replies += 1
            self._send_at(time.monotonic() + faults.reply_delay, out)
            return
        self.send(out)

    def _send_at(self, due: float, out: bytes) -> None:
        """Send ``out`` once ``time.monotonic()`` reaches ``due``, never before: uvloop's
        timers fire up to a millisecond early (MagicStack/uvloop#739), so an early
        one is re-armed for what is left."""
        left = due - time.monotonic()
        if left <= 0:
            self.send(out)
            return

        def later() -> None:
            self._delayed.discard(handle)
            self._send_at(due, out)

        handle = asyncio.get_running_loop().call_later(left, later)
        self._delayed.add(handle)

    # --- output ---------------------------------------------------------------------------------

    def send(self, data: bytes) -> None:
        """Write ``data`` towards the host, through the line faults (dropped if nobody
        is connected)."""
        if self.faults.damages_bytes:
            data = damage(data, self.faults, self.fault_counts)
        if self._master is not None:
            self._pty_write(data)
        elif open_clients := [w for w in self._clients if not w.transport.is_closing()]:
            # A closed client stays in the set until its reader task runs; uvloop raises
            # on a write to a closed transport (asyncio ignores it), so skip those.
            for w in open_clients:
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
            asyncio.get_running_loop().add_writer(self._master, self._pty_writable)
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
        asyncio.get_running_loop().remove_writer(self._master)
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
        if self._server is None:  # connected before the cable was pulled, served after
            writer.close()
            return
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
