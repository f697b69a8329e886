"""Captures: record a port's raw bytes with timestamps, decode them later, detect the
protocol on a port.

A capture is a JSON-lines file: a header line ``{"capture": 1, "port": ..., "started":
...}``, then one line per chunk read, ``{"t": seconds since the start, "data": hex}``.
Plain text, so captures can be diffed, trimmed and attached to bug reports.
"""

from __future__ import annotations

import asyncio
import datetime
import json
import logging
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .core.transport import Link, open_link
from .devices import profile, profiles

__all__ = ["Capture", "decode_capture", "detect_protocol", "read_capture", "record"]

_log = logging.getLogger("chassis_sdk.capture")


class _RawDecoder:
    """A 'decoder' that hands every chunk through unchanged (for recording)."""

    def feed(self, data: bytes, timestamp: float = 0.0) -> list[tuple[float, bytes]]:
        return [(timestamp, bytes(data))]

    def reset(self) -> None:
        pass


@dataclass(frozen=True, slots=True)
class Capture:
    """Summary of a finished recording."""

    path: Path
    chunks: int
    bytes: int
    seconds: float


async def _open_raw(
    port: str, baudrate: int, on_chunk: Callable[[tuple[float, bytes]], None]
) -> Link[Any]:
    def on_chunks(chunks: list[tuple[float, bytes]], now: float) -> None:
        for chunk in chunks:
            on_chunk(chunk)

    return await open_link(
        port, baudrate, lambda: Link(_RawDecoder(), on_chunks, lambda exc: None, _log)
    )


async def record(
    port: str,
    path: str | Path,
    *,
    seconds: float,
    baudrate: int = 115200,
    progress: Callable[[int, float], None] | None = None,
) -> Capture:
    """Record what the device sends for ``seconds`` into a capture file.

    Args:
        port: Device path, pty path or ``socket://host:port``.
        path: The capture file to write.
        seconds: How long to listen.
        baudrate: Serial speed.
        progress: Called about twice a second with (bytes so far, seconds so far).

    Raises:
        PortOpenError: The port cannot be opened.
    """
    path = Path(path)
    start = time.monotonic()
    total = 0
    chunks = 0
    # Local file writes are small and buffered; a thread per chunk would cost more.
    with path.open("w", encoding="utf-8") as f:  # noqa: ASYNC230
        f.write(
            json.dumps(
                {
                    "capture": 1,
                    "port": port,
                    "baudrate": baudrate,
                    "started": datetime.datetime.now(datetime.UTC).isoformat(),
                }
            )
            + "\n"
        )

        def on_chunk(item: tuple[float, bytes]) -> None:
            nonlocal total, chunks
            t, data = item
            total += len(data)
            chunks += 1
            f.write(json.dumps({"t": round(t - start, 6), "data": data.hex()}) + "\n")

        link = await _open_raw(port, baudrate, on_chunk)
        try:
            end = start + seconds
            while (now := time.monotonic()) < end:
                if progress is not None:
                    progress(total, now - start)
                await asyncio.sleep(min(0.5, end - now))
        finally:
            await link.aclose(1.0)
    return Capture(path, chunks, total, time.monotonic() - start)


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
                yield float(item["t"]), bytes.fromhex(item["data"])
            except (ValueError, KeyError, TypeError):
                raise ValueError(f"{path}:{n}: not a capture line") from None


def decode_capture(path: str | Path, protocol: str) -> Iterator[tuple[float, object]]:
    """Decode a capture: yield ``(seconds since start, message)`` in order.

    Args:
        path: The capture file.
        protocol: The device's name (see :func:`chassis_sdk.devices.profiles`).

    Raises:
        ValueError: An unknown device, or a file that is not a capture.
    """
    decoder = profile(protocol).decoder()
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
