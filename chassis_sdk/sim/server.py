"""Serve a sans-IO firmware model on a pseudo-terminal (default) or a TCP port.

The model is driven by two calls: ``receive(data, now)`` for bytes from the host (it
returns any immediate reply) and ``poll(now)`` for what is due at ``now`` (periodic
telemetry). ``next_deadline()`` says when ``poll`` next has something to do.

The server runs the model's clock, passes what it sends through the line faults
(`.faults`) to the line (`.lines`: a pty behind a stable path, or TCP), and
is where the cable is pulled (`SimulatorServer.unplug`) and put back
([`SimulatorServer.replug`][chassis_sdk.sim.server.SimulatorServer.replug]).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import os
import shutil
import tempfile
import time
from types import TracebackType
from typing import Self

from ..core.alarm import Alarm
from ..core.firmware import Firmware
from .control import apply
from .faults import FaultCounts, LineFaults, damage
from .lines import PtyLine, TcpLine

__all__ = ["FaultCounts", "LineFaults", "SimulatorServer", "damage"]

_log = logging.getLogger("chassis_sdk.sim")


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
        self._link_dir: str | None = None
        self._line: PtyLine | TcpLine | None = None
        self._delayed: set[asyncio.TimerHandle] = set()
        self._ticker: asyncio.Task[None] | None = None
        self._alarm = Alarm()
        self._unsent = 0  # sent while unplugged
        self._sent_before = self._discarded_before = 0  # by lines of earlier runs

    # --- lifetime -------------------------------------------------------------------------

    @property
    def port(self) -> str:
        """What to pass to ``Chassis``/``Board``: the pty's stable path (a symlink the
        server owns) or a ``socket://127.0.0.1:PORT`` URL. It stays the same across
        [`unplug`][chassis_sdk.sim.server.SimulatorServer.unplug] and `replug`."""
        line = self._line
        if isinstance(line, PtyLine):
            return line.path
        if isinstance(line, TcpLine):
            return f"socket://{line.host}:{line.port}"
        raise RuntimeError("the simulator is not running; use `async with` or start()")

    @property
    def plugged(self) -> bool:
        """True while the pty is open or the TCP port is listening."""
        return self._line is not None and self._line.is_open

    @property
    def clients(self) -> int:
        """TCP clients connected now (0 on a pty)."""
        return self._line.clients if isinstance(self._line, TcpLine) else 0

    @property
    def bytes_sent(self) -> int:
        """Bytes written towards the host."""
        return self._sent_before + (0 if self._line is None else self._line.bytes_sent)

    @property
    def bytes_discarded(self) -> int:
        """Bytes dropped because nobody was reading (or the cable was out)."""
        line = self._line
        return self._unsent + self._discarded_before + (0 if line is None else line.bytes_discarded)

    async def start(self) -> None:
        """Open the pty or start listening, and start the firmware's clock."""
        self.firmware.on_connect(time.monotonic())
        if self._tcp_port is None:
            self._link_dir = tempfile.mkdtemp(prefix="chassis-sim-")
            self._line = PtyLine(os.path.join(self._link_dir, "tty"), self._received)
        else:
            self._line = TcpLine(self._host, self._tcp_port, self._received, self._connected)
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
        server = self._unplug_line()
        if server is not None:
            await server.wait_closed()
        if isinstance(self._line, TcpLine):
            self._line.cancel_clients()
        if self._link_dir is not None:
            shutil.rmtree(self._link_dir, ignore_errors=True)
            self._link_dir = None
        if self._line is not None:  # its counts stay the server's
            self._sent_before += self._line.bytes_sent
            self._discarded_before += self._line.bytes_discarded
        self._line = None

    async def replug(self) -> None:
        """Plug the device (back) in: a new pty behind the same path, or listen on the
        same TCP port again. Does nothing if it is plugged in."""
        line = self._line
        if line is None or line.is_open:
            return
        if isinstance(line, PtyLine):
            line.open()
        else:
            await line.open()

    def unplug(self) -> None:
        """Pull the cable: close the pty and remove its path (the host's reads fail and
        reopening finds no device, as when a USB adapter is pulled), or stop listening
        and drop every TCP client. The firmware keeps running; `replug` puts the
        device back."""
        self._unplug_line()

    def _unplug_line(self) -> asyncio.Server | None:
        server = None
        if isinstance(self._line, PtyLine):
            self._line.close()
        elif isinstance(self._line, TcpLine):
            server = self._line.close()
        for handle in self._delayed:
            handle.cancel()
        self._delayed.clear()
        return server

    def command(self, line: str) -> str:
        """Carry out one runtime command on the firmware now (``"bumper front"``,
        ``"stall 2"``, ``"help"``...: see `chassis_sdk.sim.control`) and return its
        one-line answer (``ok: ...`` or ``error: ...``; empty for a blank line). Never
        raises for a bad line."""
        answer = apply(self.firmware, line, time.monotonic())
        self._alarm.wake()  # what is due next may have changed (a reset)
        return answer

    def reset_firmware(self, downtime: float = 0.5) -> None:
        """Reboot the firmware now (see the model's ``reset``); the line stays up."""
        self.firmware.reset(time.monotonic(), downtime)
        self._alarm.wake()

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

    def _connected(self) -> None:
        self.firmware.on_connect(time.monotonic())

    # --- output ---------------------------------------------------------------------------------

    def send(self, data: bytes) -> None:
        """Write ``data`` towards the host, through the line faults (dropped if nobody
        is connected)."""
        if self.faults.damages_bytes:
            data = damage(data, self.faults, self.fault_counts)
        if self._line is not None and self._line.is_open:
            self._line.send(data)
        else:
            self._unsent += len(data)
