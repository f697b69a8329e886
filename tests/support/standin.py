"""Independent firmware stand-ins for the integration tests.

They share no code with ``chassis_sdk``: frames are packed and parsed here by hand,
straight from the protocol tables (docs/protocols.md), so an error in the SDK's codec cannot cancel out
against the same error in the test double. Each stand-in serves a real pseudo-terminal
(raw mode, set before anything else) or, with ``tcp=True``, a TCP port on 127.0.0.1,
that the SDK opens through its real transport; it puts noise on the line between
frames, and records every frame the host writes with its arrival time so tests can
wait on them as events. ``unplug()`` drops the line; over TCP, ``replug()`` listens on
the same port again. ``stop_reading()`` plays a device whose firmware stopped reading
its UART (``fill_line()`` fills the kernel's buffer at once, as minutes of that
would); ``release_line()`` lets the host's close reach the stand-in as ``eof``.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
import select
import socket
import struct
import time
import tty
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, cast

# A noise mix: random bytes, and false heads of both protocols that must be skipped.
_NOISE = [b"\x00", b"\xff\x13\x37", b"\xed", b"\xed\xde\x05", b"\xfe", b"\xfe\xce\x11", b"\xab"]


@dataclass
class Received:
    """One frame from the host, parsed by the stand-in."""

    time: float
    kind: int
    payload: bytes
    seq: int | None = None
    raw: bytes = b""


@dataclass
class PtyPeer:
    """The pty plumbing and the event log shared by both stand-ins."""

    noise: bool = True
    seed: int = 1
    tcp: bool = False
    #: When False, the periodic output (telemetry) pauses; replies still go out.
    streaming: bool = True
    #: (TCP) The receive buffer of the device's socket, bytes (``None``: the system's).
    tcp_rcvbuf: int | None = None
    frames: list[Received] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)
        self._buf = bytearray()
        self._cond: asyncio.Condition | None = None
        self._master = -1
        self._slave = -1
        self.port = ""
        self._tasks: list[asyncio.Task[None]] = []
        self.noise_bytes = 0
        self._server: asyncio.Server | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._tcp_port = 0
        #: TCP connections accepted so far.
        self.connections = 0
        #: ``time.monotonic()`` of the last unplug().
        self.unplugged_at: float | None = None
        #: TCP connections open now.
        self.live_connections = 0
        #: Set when a TCP connection is accepted (clear it to wait for the next).
        self.accepted = asyncio.Event()
        #: Set when the host has closed the line and every byte it sent was read.
        self.eof = asyncio.Event()
        self._reading = True
        self._resumed = asyncio.Event()
        self._resumed.set()

    async def __aenter__(self) -> Any:
        self._cond = asyncio.Condition()
        if self.tcp:
            await self.replug()
            self.port = f"socket://127.0.0.1:{self._tcp_port}"
        else:
            master, slave = os.openpty()
            tty.setraw(slave)
            os.set_blocking(master, False)
            self._master, self._slave = master, slave
            self.port = os.ttyname(slave)
            asyncio.get_running_loop().add_reader(master, self._readable)
        self._tasks.append(asyncio.create_task(self.run()))
        return self

    async def __aexit__(self, *exc: object) -> None:
        for t in self._tasks:
            t.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)
        self._read_what_is_left()
        self.unplug()

    def _read_what_is_left(self) -> None:
        """Take in what the host wrote before it closed and the loop had not yet
        handed over (a device reads its line to the end before it is unplugged). The
        kernel hands a pty's bytes across a moment after the write, so this waits
        until the line has been quiet for 10 ms."""
        if self._master < 0 or not self._reading:
            return
        while True:
            if not select.select([self._master], [], [], 0.01)[0]:
                return
            try:
                data = os.read(self._master, 4096)
            except OSError:  # BlockingIOError: nothing more; EIO: all was read
                return
            if not data:
                return
            self._on_bytes(data)

    def stop_reading(self) -> None:
        """Stop reading what the host sends, like a hung MCU. Over TCP the kernel's
        buffers take some 20 KiB more first (with ``tcp_rcvbuf`` small)."""
        self._reading = False
        if self.tcp:
            self._resumed.clear()
            if self._writer is not None:  # the stream's own buffer would take 128 KiB
                cast(asyncio.ReadTransport, self._writer.transport).pause_reading()
        else:
            asyncio.get_running_loop().remove_reader(self._master)

    def resume_reading(self) -> None:
        self._reading = True
        if self.tcp:
            self._resumed.set()
            if self._writer is not None:
                cast(asyncio.ReadTransport, self._writer.transport).resume_reading()
        else:
            asyncio.get_running_loop().add_reader(self._master, self._readable)

    def fill_line(self) -> int:
        """Fill the kernel's buffers between host and device with zero bytes (what a
        device that stopped reading minutes ago leaves); return how many. Over TCP the
        host's own socket is filled (found among this process's descriptors by its
        address: the host runs in the test's process), after ``stop_reading()``."""
        if self.tcp:
            return self._fill_tcp()
        fd = os.open(self.port, os.O_WRONLY | os.O_NONBLOCK | os.O_NOCTTY)
        try:
            return _fill(lambda data: os.write(fd, data))
        finally:
            os.close(fd)

    def _fill_tcp(self) -> int:
        assert self._writer is not None, "no host is connected"
        host = self._writer.get_extra_info("peername")
        for name in os.listdir("/proc/self/fd"):
            try:
                sock = socket.socket(fileno=os.dup(int(name)))
            except OSError:  # not a socket (or gone since the listing)
                continue
            with sock:
                try:
                    if sock.family != socket.AF_INET or sock.getsockname() != host:
                        continue
                except OSError:
                    continue

                def send(data: bytes, sock: socket.socket = sock) -> int:
                    return sock.send(data, socket.MSG_DONTWAIT)

                return _fill(send)
        raise LookupError(f"the host's socket {host} is not in this process")

    def release_line(self) -> None:
        """Close the stand-in's own hold on the pty, so that once the host closes the
        port the master reads end of file (and ``eof`` is set)."""
        if self._slave >= 0:
            os.close(self._slave)
            self._slave = -1

    def unplug(self) -> None:
        """Close the pty, or stop listening and drop the TCP client: the host sees
        the device disappear."""
        self.unplugged_at = time.monotonic()
        if self._master >= 0:
            asyncio.get_running_loop().remove_reader(self._master)
            os.close(self._master)
            if self._slave >= 0:
                os.close(self._slave)
            self._master = self._slave = -1
        if self._server is not None:
            self._server.close()
            self._server = None
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    async def replug(self) -> None:
        """(TCP) Listen on the same port again."""
        assert self.tcp, "a pty cannot be re-plugged at the same path"
        sock = socket.socket()
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if self.tcp_rcvbuf is not None:  # before listen(): accepted sockets inherit it
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, self.tcp_rcvbuf)
        sock.bind(("127.0.0.1", self._tcp_port))
        self._server = await asyncio.start_server(self._serve, sock=sock)
        self._tcp_port = self._server.sockets[0].getsockname()[1]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self._writer is not None:  # one host at a time, like a serial line
            writer.close()
            return
        self._writer = writer
        self._buf.clear()  # a partial frame does not survive a new connection
        self.connections += 1
        self.live_connections += 1
        self.accepted.set()
        self.eof.clear()
        try:
            while True:
                await self._resumed.wait()
                data = await reader.read(4096)
                if not data:
                    break
                self._on_bytes(data)
        except ConnectionError:
            pass
        finally:
            self.live_connections -= 1
            self.eof.set()
            if self._writer is writer:
                self._writer = None
            writer.close()
            asyncio.get_running_loop().create_task(self._notify())

    async def run(self) -> None:
        """Periodic output; overridden."""

    def send(self, frame: bytes) -> None:
        """Write a frame, with some noise before it when noise is on."""
        if self._master < 0 and self._writer is None:
            return
        data = frame
        if self.noise and self._rng.random() < 0.5:
            junk = self._rng.choice(_NOISE)
            self.noise_bytes += len(junk)
            data = junk + frame
        if self._writer is not None:
            self._writer.write(data)
            return
        with contextlib.suppress(BlockingIOError):
            os.write(self._master, data)

    def _readable(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError:  # EIO: every slave descriptor is closed and all was read
            asyncio.get_running_loop().remove_reader(self._master)
            self.eof.set()
            asyncio.get_running_loop().create_task(self._notify())
            return
        self._on_bytes(data)

    def _on_bytes(self, data: bytes) -> None:
        self._buf += data
        now = time.monotonic()
        for rec in self.parse(self._buf, now):
            self.frames.append(rec)
            self.on_frame(rec)
        if self._cond is not None:
            asyncio.get_running_loop().create_task(self._notify())

    async def _notify(self) -> None:
        assert self._cond is not None
        async with self._cond:
            self._cond.notify_all()

    def parse(self, buf: bytearray, now: float) -> list[Received]:
        raise NotImplementedError

    def on_frame(self, rec: Received) -> None:
        """React to a host frame; overridden."""

    async def wait_for(
        self, predicate: Callable[[list[Received]], bool], timeout: float = 5.0
    ) -> None:
        """Wait until ``predicate(frames)`` holds (an event, not a sleep)."""
        assert self._cond is not None
        async with asyncio.timeout(timeout), self._cond:
            await self._cond.wait_for(lambda: predicate(self.frames))

    def of_kind(self, kind: int) -> list[Received]:
        return [f for f in self.frames if f.kind == kind]


# --- protocol A ---------------------------------------------------------------------------------


def frame_a(fid: int, payload: bytes, seq: int, length: int | None = None) -> bytes:
    total = len(payload) + 10
    body = b"\xed\xde" + struct.pack("<HBB", seq, fid, total if length is None else length)
    body += payload
    return body + struct.pack("<H", sum(body) & 0xFFFF) + b"\xbd\xbc"


#: The vendor document's 0x89 example, verbatim, with its wrong length byte.
DOC_CHASSIS_INFO = bytes.fromhex("ED DE 00 00 89 12 D5 02 F4 01 AA 00 1E 00 E8 03 E5 05 BD BC")
#: The vendor document's 0x8A example, verbatim.
DOC_SHIP_DATE = bytes.fromhex("ED DE 00 00 8A 0D 18 01 02 7D 02 BD BC")


@dataclass
class ChassisStandIn(PtyPeer):
    """Protocol A firmware stand-in: telemetry at 50 Hz, replies, e-stop bit."""

    telemetry_period: float = 0.02
    firmware_version: int = 0x0103
    hardware: bytes = b"ZKWL-brush-motor-chassis"
    silent_ids: set[int] = field(default_factory=set)
    reply_delay: float = 0.0
    status: int = 0
    seq: int = 0
    #: Number frames with one counter per frame id instead of one for all frames.
    per_id_seq: bool = False
    _seqs: dict[int, int] = field(default_factory=dict)

    def parse(self, buf: bytearray, now: float) -> list[Received]:
        out: list[Received] = []
        while True:
            i = buf.find(b"\xed\xde")
            if i < 0:
                del buf[: max(0, len(buf) - 1)]
                return out
            del buf[:i]
            if len(buf) < 6:
                return out
            n = buf[5]
            if n < 10 or n > 64:
                del buf[:1]
                continue
            if len(buf) < n:
                return out
            raw = bytes(buf[:n])
            ok = (
                raw[-2:] == b"\xbd\xbc"
                and struct.unpack_from("<H", raw, n - 4)[0] == sum(raw[: n - 4]) & 0xFFFF
            )
            if not ok:
                del buf[:1]
                continue
            del buf[:n]
            seq = struct.unpack_from("<H", raw, 2)[0]
            out.append(Received(now, raw[4], raw[6 : n - 4], seq, raw))

    def next_seq(self, frame_id: int = 0x81) -> int:
        if self.per_id_seq and frame_id != 0x81:
            s = self._seqs.get(frame_id, 0)
            self._seqs[frame_id] = (s + 1) & 0xFFFF
            return s
        s = self.seq
        self.seq = (s + 1) & 0xFFFF
        return s

    def on_frame(self, rec: Received) -> None:
        kind = rec.kind
        if kind == 0x03:
            estop = struct.unpack("<H", rec.payload)[0]
            self.status = (self.status | 4) if estop else (self.status & ~4)
            return
        if kind in self.silent_ids:
            return
        reply: bytes | None = None
        if kind == 0x07:
            reply = frame_a(0x87, struct.pack("<H", self.firmware_version), self.next_seq(0x87))
        elif kind == 0x08:
            reply = frame_a(0x88, self.hardware, self.next_seq(0x88))
        elif kind == 0x09:
            reply = DOC_CHASSIS_INFO
        elif kind == 0x0A:
            reply = DOC_SHIP_DATE
        elif kind == 0xB0:
            payload = struct.pack(
                "<4H4H4h4H2H2H",
                0x0008, 0, 0, 0x4000,  # FL over-current; RR second over-temperature bit
                0x0003, 0x0004, 0x0004, 0x2000,
                15, -15, 0, 0,
                30, 30, 0, 0,
                355, 341, 240, 239,
            )  # fmt: skip
            reply = frame_a(0xB0, payload, self.next_seq(0xB0))
        if reply is not None:
            if self.reply_delay:
                asyncio.get_running_loop().call_later(self.reply_delay, self.send, reply)
            else:
                self.send(reply)

    def telemetry_frame(self) -> bytes:
        # 24.6 V, status, docked, 0.3 m/s, -0.25 rad/s, wheels 0.1 -0.2 0.3 -0.4 m/s
        payload = struct.pack("<HHHhhhhhh", 246, self.status, 4, 300, -250, 100, -200, 300, -400)
        return frame_a(0x81, payload, self.next_seq())

    async def run(self) -> None:
        while True:
            if self.streaming:
                self.send(self.telemetry_frame())
            await asyncio.sleep(self.telemetry_period)


def drive_frames(frames: list[Received]) -> list[Received]:
    return [f for f in frames if f.kind == 0x02]


def last_drive_is_zero(frames: list[Received]) -> bool:
    """True once a drive frame has arrived and the latest one is zero."""
    drives = drive_frames(frames)
    return bool(drives) and is_zero_drive(drives[-1])


def is_zero_drive(rec: Received) -> bool:
    mode = struct.unpack_from("<H", rec.payload)[0]
    if mode == 0:
        _, vx, wz = struct.unpack("<Hhf", rec.payload)
        return bool(vx == 0 and wz == 0.0)
    _, left, right, _ = struct.unpack("<HhhH", rec.payload)
    return bool(left == 0 and right == 0)


# --- protocol B ---------------------------------------------------------------------------------


def frame_b(head: bytes, kind: int, data: bytes) -> bytes:
    n = len(data) + 1
    return head + bytes((kind, n)) + data + bytes(((kind + n + sum(data)) & 0xFF,))


_B_LENGTHS = {0x01: 3, 0x02: 3, 0x21: 4, 0x22: 5, 0x31: 4}


@dataclass
class BoardStandIn(PtyPeer):
    """Protocol B firmware stand-in: IMU, velocity, battery, logs and LED/buzzer replies.

    With ``hold_replies = N``, switch requests are held until N have arrived and then
    answered in reverse order.
    """

    imu_period: float = 0.01
    hold_replies: int = 0
    silent: bool = False
    led: bool = False
    buzzer: bool = False
    _held: list[bytes] = field(default_factory=list)

    def parse(self, buf: bytearray, now: float) -> list[Received]:
        out: list[Received] = []
        while True:
            i = buf.find(b"\xab\xbc")
            if i < 0:
                del buf[: max(0, len(buf) - 1)]
                return out
            del buf[:i]
            if len(buf) < 4:
                return out
            kind, n = buf[2], buf[3]
            if _B_LENGTHS.get(kind) != n:
                del buf[:1]
                continue
            if len(buf) < 4 + n:
                return out
            raw = bytes(buf[: 4 + n])
            if (kind + n + sum(raw[4:-1])) & 0xFF != raw[-1]:
                del buf[:1]
                continue
            del buf[: 4 + n]
            out.append(Received(now, kind, raw[4:-1], None, raw))

    def on_frame(self, rec: Received) -> None:
        if rec.kind in (0x01, 0x02) and not self.silent:
            # The state is applied and captured on arrival, whenever the reply goes out.
            reply = self._apply(rec)
            if self.hold_replies:
                self._held.append(reply)
                if len(self._held) >= self.hold_replies:
                    held, self._held = self._held, []
                    for frame in reversed(held):
                        self.send(frame)
            else:
                self.send(reply)
        elif rec.kind == 0x31:
            servo, angle = struct.unpack("<Bh", rec.payload)
            self.send(frame_b(b"\xfe\xce", 0xF1, f"servo {servo} at {angle / 10:.1f}".encode()))

    def _apply(self, rec: Received) -> bytes:
        command, rid = rec.payload
        if rec.kind == 0x01:
            if command < 2:
                self.led = bool(command)
            state = self.led
        else:
            if command < 2:
                self.buzzer = bool(command)
            state = self.buzzer
        return frame_b(b"\xfe\xce", rec.kind, bytes((rid, int(state))))

    async def run(self) -> None:
        n = 0
        while True:
            if not self.streaming:
                await asyncio.sleep(self.imu_period)
                continue
            # accel (164, -82, 164*1) raw -> (1.0, -0.5, 1.0) g; gyro 164 raw -> 10 deg/s
            imu = struct.pack("<9h", 164, -82, 164, 0, -164, 164, 300, -300, -420)
            self.send(frame_b(b"\xfe\xce", 0x11, imu))
            if n % 5 == 0:
                self.send(frame_b(b"\xfe\xce", 0x12, struct.pack("<hh", 250, -500)))
            if n % 20 == 0:
                self.send(frame_b(b"\xfe\xce", 0x13, struct.pack("<h", 1234)))
            n += 1
            await asyncio.sleep(self.imu_period)


def _fill(write: Callable[[bytes], int]) -> int:
    """Write zero bytes with ``write`` (non-blocking) until the kernel takes no more."""
    total = 0
    # The kernel moves bytes on between its buffers a moment after a write, so room
    # comes back: fill until a pause adds nothing, down to the last byte.
    while True:
        before = total
        for size in (4096, 256, 16, 1):
            with contextlib.suppress(BlockingIOError):
                while True:
                    total += write(bytes(size))
        if total == before:
            return total
        time.sleep(0.02)
