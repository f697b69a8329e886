"""Captures: record a port's raw bytes with timestamps, decode them later, detect the
protocol on a port.

A capture is a JSON-lines file: a header line ``{"capture": 1, "port": ..., "started":
...}``, then one line per chunk read, ``{"t": seconds since the start, "data": hex}``,
and a line ``{"t": ..., "event": "disconnected"}`` (or ``"reconnected"``) where the link
dropped or came back.
Plain text, so captures can be diffed, trimmed and attached to bug reports.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime
import json
import logging
import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .core.backoff import Backoff
from .core.transport import Link, open_link
from .core.validation import check_real
from .devices import profile, profiles
from .errors import PortOpenError

__all__ = [
    "Capture",
    "CaptureDevice",
    "Progress",
    "decode_capture",
    "detect_in",
    "detect_protocol",
    "read_capture",
    "record",
]

_log = logging.getLogger("chassis_sdk.capture")
#: Reopening after a drop while recording: first delay, cap (seconds).
_REOPEN_START = 0.1
_REOPEN_CAP = 1.0


class _RawDecoder:
    """A 'decoder' that hands every chunk through unchanged (for recording)."""

    def feed(self, data: bytes, timestamp: float = 0.0) -> list[tuple[float, bytes]]:
        return [(timestamp, bytes(data))]

    def reset(self) -> None:
        pass


@dataclass(frozen=True, slots=True)
class Capture:
    """Summary of a finished recording.

    Attributes:
        path: The capture file.
        chunks: Chunks recorded (one line each).
        bytes: Bytes recorded.
        seconds: How long the recording ran.
        disconnects: Times the link dropped during the recording (each is a line
            ``{"t": ..., "event": "disconnected"}`` in the file, and a reopen that
            worked is ``"reconnected"``).
        connected: Whether the link was up when the recording ended.
    """

    path: Path
    chunks: int
    bytes: int
    seconds: float
    disconnects: int = 0
    connected: bool = True


#: What a recording's progress callback gets: (bytes so far, seconds so far, link up).
Progress = Callable[[int, float, bool], None]


async def _open_raw(
    port: str,
    baudrate: int,
    on_chunk: Callable[[tuple[float, bytes]], None],
    on_lost: Callable[[Exception | None], None] = lambda exc: None,
) -> Link[Any]:
    def on_chunks(chunks: list[tuple[float, bytes]], now: float) -> None:
        for chunk in chunks:
            on_chunk(chunk)

    return await open_link(port, baudrate, lambda: Link(_RawDecoder(), on_chunks, on_lost, _log))


def _setter(event: asyncio.Event) -> Callable[[Exception | None], None]:
    return lambda exc: event.set()


async def record(
    port: str,
    path: str | Path,
    *,
    seconds: float,
    baudrate: int = 115200,
    progress: Progress | None = None,
) -> Capture:
    """Record what the device sends for ``seconds`` into a capture file.

    If the link drops (the cable is pulled), the recording goes on: the drop is written
    to the file, the port is reopened with backoff until ``seconds`` are up, and a
    reopen is written too; :attr:`Capture.connected` says how it ended.

    Args:
        port: Device path, pty path or ``socket://host:port``.
        path: The capture file to write.
        seconds: How long to listen.
        baudrate: Serial speed.
        progress: Called about twice a second, and at once when the link drops or
            comes back, with (bytes so far, seconds so far, link up).

    Raises:
        PortOpenError: The port cannot be opened at the start.
    """
    path = Path(path)
    start = time.monotonic()
    end = start + seconds
    total = chunks = disconnects = 0
    lost = asyncio.Event()
    # Local file writes are small and buffered; a thread per chunk would cost more.
    with path.open("w", encoding="utf-8") as f:  # noqa: ASYNC230

        def line(item: dict[str, object]) -> None:
            f.write(json.dumps(item) + "\n")

        line(
            {
                "capture": 1,
                "port": port,
                "baudrate": baudrate,
                "started": datetime.datetime.now(datetime.UTC).isoformat(),
            }
        )

        def on_chunk(item: tuple[float, bytes]) -> None:
            nonlocal total, chunks
            t, data = item
            total += len(data)
            chunks += 1
            line({"t": round(t - start, 6), "data": data.hex()})

        def report() -> None:
            if progress is not None:
                progress(total, time.monotonic() - start, link is not None)

        link: Link[Any] | None = await _open_raw(port, baudrate, on_chunk, _setter(lost))
        try:
            backoff = Backoff(_REOPEN_START, _REOPEN_CAP)
            while (now := time.monotonic()) < end:
                report()
                if link is not None:
                    with contextlib.suppress(TimeoutError):
                        await asyncio.wait_for(lost.wait(), min(0.5, end - now))
                    if lost.is_set():
                        disconnects += 1
                        line({"t": round(time.monotonic() - start, 6), "event": "disconnected"})
                        await link.aclose(0.0)
                        link = None
                        backoff.reset()
                    continue
                await asyncio.sleep(min(backoff.next(), end - now))
                try:
                    # A fresh event per link: a late word from the old one cannot count.
                    lost = asyncio.Event()
                    link = await _open_raw(port, baudrate, on_chunk, _setter(lost))
                except PortOpenError:
                    continue
                line({"t": round(time.monotonic() - start, 6), "event": "reconnected"})
        finally:
            if link is not None:
                await link.aclose(1.0)
        report()
    return Capture(
        path, chunks, total, time.monotonic() - start, disconnects, connected=link is not None
    )


def read_capture(path: str | Path) -> Iterator[tuple[float, bytes]]:
    """Yield ``(seconds since start, bytes)`` for each chunk of a capture file.

    Raises:
        ValueError: The file is not a capture.
    """
    with Path(path).open(encoding="utf-8") as f:
        header = f.readline()
        try:
            if json.loads(header).get("capture") != 1:
                raise ValueError
        except (ValueError, AttributeError):
            raise ValueError(f"{path} is not a chassis-sdk capture file") from None
        for n, line in enumerate(f, start=2):
            if not line.strip():
                continue
            try:
                item = json.loads(line)
                if "event" in item:  # the link dropped or came back: no bytes
                    continue
                yield float(item["t"]), bytes.fromhex(item["data"])
            except (ValueError, KeyError, TypeError):
                raise ValueError(f"{path}:{n}: not a capture line") from None


def decode_capture(
    path: str | Path, protocol: str, *, commands: bool = False
) -> Iterator[tuple[float, object]]:
    """Decode a capture: yield ``(seconds since start, message)`` in order.

    Args:
        path: The capture file.
        protocol: The device's name (see :func:`chassis_sdk.devices.profiles`).
        commands: Decode what the *host* sent instead (a capture taken on a tap that
            sees both directions holds both; one from ``record`` holds none).

    Raises:
        ValueError: An unknown device, or a file that is not a capture.
    """
    device = profile(protocol)
    decoder = device.command_decoder() if commands else device.decoder()
    for t, data in read_capture(path):
        for msg in decoder.feed(data, t):
            yield t, msg


def detect_in(data: bytes) -> str | None:
    """Which device's protocol ``data`` is in: the one whose decoder finds the most
    frames in it (the first registered wins a tie), or ``None`` if none finds any."""
    best, most = None, 0
    for name, device in profiles().items():
        decoder = device.decoder()
        decoder.feed(data)
        if decoder.stats.frames > most:
            best, most = name, decoder.stats.frames
    return best


async def detect_protocol(port: str, *, seconds: float = 1.0, baudrate: int = 115200) -> str | None:
    """Listen to ``port`` for ``seconds`` and say which device's protocol it speaks
    (a name from :func:`chassis_sdk.devices.profiles`).

    Devices send telemetry unprompted (the chassis 0x81 at 50 Hz, the board its IMU
    at 100 Hz), so a second of listening is plenty. Returns ``None`` if nothing
    recognisable arrived.
    """
    received = bytearray()
    done = asyncio.get_running_loop().create_future()

    def on_chunk(item: tuple[float, bytes]) -> None:
        received.extend(item[1])
        if not done.done() and detect_in(bytes(received)) is not None and len(received) > 200:
            done.set_result(None)

    link = await _open_raw(port, baudrate, on_chunk)
    try:
        await asyncio.wait_for(asyncio.shield(done), seconds)
    except TimeoutError:
        pass
    finally:
        await link.aclose(1.0)
    return detect_in(bytes(received))


class CaptureDevice:
    """A capture played back as a device: the firmware model of a
    :class:`~chassis_sdk.core.simulator.SimulatorServer` that sends the recorded bytes
    at the recorded times (``speed`` times faster), so an unmodified application runs
    against what a real robot sent. What the application writes is counted and decoded
    (``commands``), never acted on.

    Timing starts with :meth:`on_connect`: when the server starts (a pty, after
    ``start_after`` seconds, so the application has time to open it) or when a TCP
    client connects.

    Args:
        path: The capture file.
        protocol: The device's name, to decode what the application writes.
        speed: Playback speed (2: twice as fast).
        start_after: Seconds between :meth:`on_connect` and the first chunk.
        on_done: Called once the last chunk has been played.
    """

    def __init__(
        self,
        path: str | Path,
        protocol: str,
        *,
        speed: float = 1.0,
        start_after: float = 0.0,
        on_done: Callable[[], None] | None = None,
    ) -> None:
        self.speed = check_real(speed, "speed", low=0, low_open=True)
        self.chunks = list(read_capture(path))
        self.start_after = float(start_after)
        self._decoder = profile(protocol).command_decoder()
        #: What the application wrote, decoded, in order.
        self.commands: list[object] = []
        #: Bytes the application wrote; bytes and chunks played so far.
        self.bytes_written = 0
        self.bytes_played = 0
        self._next = 0
        self._t0: float | None = None
        self._on_done = on_done

    @property
    def done(self) -> bool:
        """True once every recorded chunk has been played."""
        return self._next >= len(self.chunks)

    def on_connect(self, now: float) -> None:
        self._t0 = now + self.start_after
        self._next = 0

    def receive(self, data: bytes, now: float) -> bytes:
        self.bytes_written += len(data)
        self.commands += self._decoder.feed(data, now)
        return b""

    def _due(self, index: int) -> float:
        assert self._t0 is not None
        return self._t0 + self.chunks[index][0] / self.speed

    def poll(self, now: float) -> bytes:
        if self._t0 is None:
            return b""
        out = bytearray()
        while self._next < len(self.chunks) and self._due(self._next) <= now:
            out += self.chunks[self._next][1]
            self._next += 1
        self.bytes_played += len(out)
        if out and self.done and self._on_done is not None:
            self._on_done()
        return bytes(out)

    def next_deadline(self) -> float:
        if self._t0 is None or self.done:
            return math.inf
        return self._due(self._next)

    def reset(self, now: float, downtime: float = 0.5) -> None:
        self.on_connect(now + downtime)
