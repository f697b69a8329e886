"""Captures: record a port's raw bytes with timestamps, decode them later, detect the
protocol on a port.

A capture is a JSON-lines file (the format: `chassis_sdk.recording.jsonl`) or an
MCAP recording (`chassis_sdk.recording.mcap`); every reader here takes both.
"""

from __future__ import annotations

import base64
import itertools
import json
import logging
import math
import os
import struct
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import anyio

from ..core.backoff import Backoff
from ..core.session import RecordTarget
from ..core.supervisor import reopen
from ..core.transport import Link, open_link
from ..core.validation import check_real
from ..devices import profile, profiles
from ..errors import ChassisError, install_hint
from . import Recording
from .jsonl import JsonlRecording, read_jsonl
from .mcap import McapRecording

if TYPE_CHECKING:
    from .columns import Columns

__all__ = [
    "SILENCE_WARNING",
    "Capture",
    "CaptureFirmware",
    "Progress",
    "capture_columns",
    "decode_capture",
    "detect_device",
    "detect_in",
    "is_mcap",
    "mcap_metadata",
    "read_capture",
    "record",
]

_log = logging.getLogger("chassis_sdk.recording.capture")
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
        device: The device whose frames the recording holds: the one named, once a
            frame of it arrived, else the one heard; ``None`` when no frame of it (or,
            with none named, of any known device) arrived: a wrong ``--device``, a
            silent port, the wrong baud rate.
    """

    path: Path
    chunks: int
    bytes: int
    seconds: float
    disconnects: int = 0
    connected: bool = True
    device: str | None = None


#: What a recording's progress callback gets: (bytes so far, seconds so far, link up).
Progress = Callable[[int, float, bool], None]
#: Seconds into a recording after which no frame of its device is warned about.
SILENCE_WARNING = 3.0


class _FrameWatch:
    """Whether a frame of ``device`` (of any known device when ``None``) has arrived:
    the bytes are decoded only until the first frame, and the first 64 KiB kept to
    say what else they look like."""

    _KEEP = 1 << 16

    def __init__(self, device: str | None) -> None:
        self.wanted = device
        names = [device] if device is not None else list(profiles())
        self._decoders = [(name, profile(name).codec.decoder()) for name in names]
        self._head = bytearray()
        #: The device a frame arrived of, once one did.
        self.heard: str | None = None

    def feed(self, data: bytes) -> None:
        if self.heard is not None:
            return
        if len(self._head) < self._KEEP:
            self._head += data[: self._KEEP - len(self._head)]
        for name, decoder in self._decoders:
            decoder.feed(data)
            if decoder.stats.frames:
                self.heard = name
                return

    def why(self, port: str, total: int) -> str:
        """What arrived instead of a frame, for a warning or an error."""
        what = f"{self.wanted} frame" if self.wanted else "frame of any known device"
        if not total:
            return f"no {what} from {port}: nothing arrived"
        other = detect_in(bytes(self._head)) if self.wanted else None
        if other is not None and other != self.wanted:
            return (
                f"no {what} in {total:,} bytes from {port}: they look like a {other}; "
                f"try --device {other}"
            )
        return f"no {what} in {total:,} bytes from {port} (the wrong baud rate?)"


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


def _setter(event: anyio.Event) -> Callable[[Exception | None], None]:
    return lambda exc: event.set()


async def record(
    port: str,
    path: str | os.PathLike[str],
    *,
    seconds: float | None,
    baudrate: int = 115200,
    progress: Progress | None = None,
    device: str | None = None,
) -> Capture:
    """Record what the device sends for ``seconds`` (``None``: until cancelled) into a
    capture file; it never writes to the port.

    The format is the file's suffix: ``.mcap`` (raw bytes with receive times, every
    stream decoded, odometry and events; see `chassis_sdk.recording.sink`; needs
    the ``foxglove`` extra and the device's protocol, heard on the port if not given),
    or a JSON-lines capture (raw bytes with receive times) for any other name. A
    recording chosen with its options, such as
    `chassis_sdk.recording.ros2.rosbag` (a rosbag2 file for ROS 2 tools), is
    made as it says, from the same decoded streams:
    ``record(port, rosbag("run.mcap", namespace="robot1"), seconds=60)``.

    If the link drops (the cable is pulled), the recording goes on: the drop is written
    to the file, the port is reopened with backoff until ``seconds`` are up, and a
    reopen is written too; `Capture.connected` says how it ended.

    If no frame of ``device`` (of any known device, when none is named) has arrived
    `SILENCE_WARNING` seconds in, a warning is logged (``chassis_sdk.recording.capture``)
    naming what came instead, and the recording goes on; `Capture.device` is
    ``None`` for a recording that never got one.

    Args:
        port: Device path, pty path or ``socket://host:port``.
        path: The capture file to write (``.mcap``, else JSON lines), or a
            `RecordTarget` (``rosbag(...)``).
        seconds: How long to listen; ``None``: until the call is cancelled (Ctrl-C),
            when the file is closed whole (cancelling it with a number works too).
            A JSON-lines capture reaches the disk at least once a second either way.
        baudrate: Serial speed.
        progress: Called about twice a second, and at once when the link drops or
            comes back, with (bytes so far, seconds so far, link up).
        device: The device's name, for ``.mcap`` and a target (heard on the port if
            not given).

    Raises:
        PortOpenError: The port cannot be opened at the start.
        ChassisError: ``.mcap`` without a device named, and none heard on the port.
        ValueError: An unknown device.
    """
    target = path if isinstance(path, RecordTarget) else None
    path = Path(path)
    decoding: Any = None
    if target is not None or path.suffix.lower() == ".mcap":
        if device is None:
            device = await detect_device(port, seconds=2.0, baudrate=baudrate)
            if device is None:
                raise ChassisError(
                    f"no frames of a known device on {port} within 2 s; "
                    "name it (--device) to record MCAP"
                )
        # The device, never connected: it decodes, integrates and raises events from
        # the bytes this recorder hands it, and its recording holds them all.
        decoding = profile(device).device(port, baudrate=baudrate)
    start = time.monotonic()
    end = math.inf if seconds is None else start + seconds
    total = chunks = disconnects = 0
    watch = _FrameWatch(device)
    warned = False
    lost = anyio.Event()
    writer: Recording
    if decoding is not None:
        writer = McapRecording(path, decoding) if target is None else _opened(target, decoding)
        feed: Callable[[bytes, float], None] = decoding.feed
    else:
        writer = JsonlRecording(path, port, baudrate)
        feed = writer.rx
    try:

        def on_chunk(item: tuple[float, bytes]) -> None:
            nonlocal total, chunks
            t, data = item
            total += len(data)
            chunks += 1
            feed(data, t)
            watch.feed(data)

        def report() -> None:
            if progress is not None:
                progress(total, time.monotonic() - start, link is not None)

        link: Link[Any] | None = await _open_raw(port, baudrate, on_chunk, _setter(lost))
        writer.link_state("connected", time.monotonic())
        try:
            backoff = Backoff(_REOPEN_START, _REOPEN_CAP)

            async def open_again() -> Link[Any]:
                nonlocal lost
                lost = anyio.Event()  # a fresh one per link: a late word from the old cannot count
                return await _open_raw(port, baudrate, on_chunk, _setter(lost))

            while (now := time.monotonic()) < end:
                report()
                if isinstance(writer, JsonlRecording):  # a quiet port: its last lines too
                    writer.flush()
                if not warned and watch.heard is None and now - start >= SILENCE_WARNING:
                    warned = True
                    _log.warning("after %g s, %s", SILENCE_WARNING, watch.why(port, total))
                if link is not None:
                    with anyio.move_on_after(min(0.5, end - now)):
                        await lost.wait()
                    if lost.is_set():
                        disconnects += 1
                        writer.link_state("lost", time.monotonic())
                        await link.aclose(0.0)
                        link = None
                        backoff.reset()
                    continue
                with anyio.move_on_after(end - now):
                    link = await reopen(
                        open_again, backoff, until=lambda: time.monotonic() >= end, each=report
                    )
                if link is not None:
                    writer.link_state("connected", time.monotonic())
        finally:
            if link is not None:
                await link.aclose(1.0)
        report()
    finally:
        writer.close()
    return Capture(
        path,
        chunks,
        total,
        time.monotonic() - start,
        disconnects,
        connected=link is not None,
        device=watch.heard,
    )


def _opened(target: RecordTarget, device: Any) -> Recording:
    """The target's recording of ``device``, which must take the link's states too."""
    recording = target.open_recorder(device)
    if not callable(getattr(recording, "link_state", None)):
        recording.close()
        raise TypeError(f"{type(recording).__name__} cannot record a port: no link_state()")
    return cast("Recording", recording)


MCAP_MAGIC = b"\x89MCAP0\r\n"


def is_mcap(path: str | Path) -> bool:
    """Whether ``path`` is an MCAP file (by its first bytes, whatever its name).

    Raises:
        FileNotFoundError: ``no such file: PATH``.
        IsADirectoryError: ``not a file but a directory: PATH``.
    """
    try:
        with Path(path).open("rb") as f:
            return f.read(len(MCAP_MAGIC)) == MCAP_MAGIC
    except FileNotFoundError:
        raise FileNotFoundError(f"no such file: {path}") from None
    except IsADirectoryError:
        raise IsADirectoryError(f"not a file but a directory: {path}") from None


def read_capture(path: str | Path, *, sent: bool = False) -> Iterator[tuple[float, bytes]]:
    """Yield ``(seconds since start, bytes)`` for each chunk of a capture: a JSON-lines
    capture or an MCAP recording (its ``/{device}/raw/rx`` topic).

    Args:
        path: The file.
        sent: The frames the host wrote instead (``{"t", "tx"}`` lines, the MCAP's
            ``raw/tx`` topic), where the recording has them.

    Raises:
        ValueError: The file is neither.
    """
    if is_mcap(path):
        yield from _read_mcap_bytes(Path(path), "/raw/tx" if sent else "/raw/rx")
        return
    yield from read_jsonl(path, sent=sent)


def _read_mcap_bytes(path: Path, suffix: str) -> Iterator[tuple[float, bytes]]:
    """The raw bytes of one direction of an MCAP recording, in file order; a file cut
    off by a hard kill is read up to where it stops (with a warning)."""
    _need_mcap()
    from mcap.exceptions import McapError
    from mcap.records import Channel as McapChannel
    from mcap.records import Message
    from mcap.stream_reader import StreamReader

    wanted: dict[int, Callable[[bytes], bytes]] = {}
    t0: int | None = None
    with path.open("rb") as f:
        records = StreamReader(f, record_size_limit=1 << 30).records
        try:
            for record in records:
                if isinstance(record, Message):
                    if t0 is None:
                        t0 = record.log_time
                    unpack = wanted.get(record.channel_id)
                    if unpack is not None:
                        yield (record.log_time - t0) / 1e9, unpack(record.data)
                elif isinstance(record, McapChannel) and record.topic.endswith(suffix):
                    wanted[record.id] = _raw_bytes(record.message_encoding)
        except (McapError, struct.error, EOFError) as exc:  # a torn record: struct.error
            if path.resolve() not in _CUT:  # once per file, however often it is read
                _CUT.add(path.resolve())
                _log.warning(
                    "%s ends early (%s): read up to there (cut by a hard kill? "
                    "`mcap recover` rewrites it whole)",
                    path,
                    str(exc) or type(exc).__name__,
                )


#: Files found cut short, warned about once.
_CUT: set[Path] = set()


def _from_json(data: bytes) -> bytes:
    return base64.b64decode(json.loads(data)["data"])


def _raw_bytes(encoding: str) -> Callable[[bytes], bytes]:
    """How to get the bytes out of a raw-bytes message: JSON with base64 (the Foxglove
    recording), or CDR of ``std_msgs/msg/UInt8MultiArray`` (the rosbag2 one,
    `chassis_sdk.recording.ros2`)."""
    return uint8_multiarray_data if encoding == "cdr" else _from_json


def uint8_multiarray_data(data: bytes) -> bytes:
    """The ``data`` of a CDR-serialised ``std_msgs/msg/UInt8MultiArray`` (after its
    4-byte encapsulation header, either byte order). Parsed here with ``struct``, so
    that reading a rosbag2 recording back (``replay``, ``export``, ``plot``) needs no
    cyclonedds: the layout is fixed (``tests/test_ros2_types.py`` checks it against
    rosbags' serialiser).

    Raises:
        ValueError: Not such a message (short, a bad header, lengths past the end).
    """
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise ValueError("not a CDR message (bad encapsulation header)")
    order = "<" if data[1] == 1 else ">"
    body = memoryview(data)[4:]
    pos = 0

    def uint32() -> int:
        nonlocal pos
        pos = (pos + 3) & ~3  # CDR aligns a uint32 to 4, from after the header
        if pos + 4 > len(body):
            raise ValueError("a UInt8MultiArray cut short")
        (value,) = struct.unpack_from(order + "I", body, pos)
        pos += 4
        return int(value)

    def skip(n: int) -> None:
        nonlocal pos
        if pos + n > len(body):
            raise ValueError("a UInt8MultiArray cut short")
        pos += n

    for _ in range(uint32()):  # layout.dim: label (string), size, stride
        skip(uint32())
        uint32()
        uint32()
    uint32()  # layout.data_offset
    n = uint32()
    start = pos
    skip(n)
    return bytes(body[start : start + n])


def _need_mcap() -> None:
    import importlib.util

    if importlib.util.find_spec("mcap") is None:
        raise ImportError(f"reading MCAP needs the mcap package: {install_hint('foxglove')}")


def mcap_metadata(path: str | Path) -> dict[str, str]:
    """The ``chassis_sdk`` metadata of an MCAP recording (device, port, baud rate,
    versions; see `chassis_sdk.recording.sink.session_metadata`), or ``{}``."""
    _need_mcap()
    from mcap.exceptions import McapError
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    with Path(path).open("rb") as f:
        try:
            for record in StreamReader(f, record_size_limit=1 << 30).records:
                if isinstance(record, Metadata) and record.name == "chassis_sdk":
                    return dict(record.metadata)
        except (McapError, struct.error, EOFError):
            pass
    return {}


def decode_capture(
    path: str | Path, device: str, *, commands: bool = False
) -> Iterator[tuple[float, object]]:
    """Decode a capture: yield ``(seconds since start, message)`` in order.

    Args:
        path: The capture (JSON lines or MCAP).
        device: The device's name (see `chassis_sdk.devices.profiles`).
        commands: Decode what the *host* sent instead: the frames written where the
            recording holds them (an application's ``record=``), else the received
            bytes (a capture taken on a tap that sees both directions).

    Raises:
        ValueError: An unknown device, or a file that is not a capture.
    """
    spec = profile(device)
    decoder = spec.codec.command_decoder() if commands else spec.codec.decoder()
    chunks = _chunks(path, commands)
    for t, data in chunks:
        for msg in decoder.feed(data, t):
            yield t, msg


def _chunks(path: str | Path, commands: bool) -> Iterator[tuple[float, bytes]]:
    """The chunks to decode: received, or with ``commands`` the frames the host wrote
    where the recording holds them (else the received bytes: a tap seeing both)."""
    if commands:
        sent = read_capture(path, sent=True)
        first = next(sent, None)
        if first is not None:
            return itertools.chain([first], sent)
    return read_capture(path)


def capture_columns(path: str | Path, device: str, *, commands: bool = False) -> Columns:
    """Decode a whole capture into arrays (numpy): a column per field, in SI units.

    The frames `decode_capture` finds, decoded 10-27 times faster (reading the
    file then takes most of the time). The high-rate types (telemetry, power; IMU,
    velocity, battery) come out as a table of columns each, ``t`` (seconds since the
    start) first; every other frame is in ``messages`` as an object:

    ```python
    cols = capture_columns("drive.jsonl", "chassis")
    telemetry = cols["Telemetry"]
    print(telemetry["t"][-1], telemetry["linear"].max(), telemetry["wheels.front_left"])
    ```

    Args:
        path: The capture (JSON lines or MCAP).
        device: The device's name (see `chassis_sdk.devices.profiles`).
        commands: What the host sent instead (see `decode_capture`).

    Raises:
        ValueError: An unknown device, a file that is not a capture, or numpy missing.
    """
    try:
        from .columns import decode_joined
    except ImportError:
        raise ValueError(f"capture_columns needs numpy: {install_hint('plot')}") from None
    spec = profile(device)
    decoder = spec.codec.command_decoder() if commands else spec.codec.decoder()
    joined = _joined(path, sent=True) if commands else None
    if joined is None or not joined[0]:
        joined = _joined(path, sent=False)
    return decode_joined(joined[2], joined[0], joined[1], decoder)


def _joined(path: str | Path, *, sent: bool) -> tuple[list[float], list[int], bytes]:
    """``(times, sizes, bytes)`` of one direction of a capture, every chunk's bytes
    joined (what `chassis_sdk.recording.columns.decode_joined` takes)."""
    times, parts = [], []
    for t, chunk in read_capture(path, sent=sent):
        if chunk:
            times.append(t)
            parts.append(chunk)
    return times, [len(p) for p in parts], b"".join(parts)


def detect_in(data: bytes) -> str | None:
    """Which device ``data`` is from: the one whose decoder finds the most
    frames in it (the first registered wins a tie), or ``None`` if none finds any."""
    best, most = None, 0
    for name, device in profiles().items():
        decoder = device.codec.decoder()
        decoder.feed(data)
        if decoder.stats.frames > most:
            best, most = name, decoder.stats.frames
    return best


async def detect_device(port: str, *, seconds: float = 1.0, baudrate: int = 115200) -> str | None:
    """Listen to ``port`` for ``seconds`` and say which device's protocol it speaks
    (a name from [`chassis_sdk.devices.profiles`][chassis_sdk.devices.profiles]).

    Devices send telemetry unprompted (the chassis 0x81 at 50 Hz, the board its IMU
    at 100 Hz), so a second of listening is plenty. Returns ``None`` if nothing
    recognisable arrived.
    """
    received = bytearray()
    heard = anyio.Event()

    def on_chunk(item: tuple[float, bytes]) -> None:
        received.extend(item[1])
        if not heard.is_set() and detect_in(bytes(received)) is not None and len(received) > 200:
            heard.set()

    link = await _open_raw(port, baudrate, on_chunk)
    try:
        with anyio.move_on_after(seconds):
            await heard.wait()
    finally:
        await link.aclose(1.0)
    return detect_in(bytes(received))


class CaptureFirmware:
    """A capture played back as a device: the firmware model of a
    [`SimulatorServer`][chassis_sdk.sim.server.SimulatorServer] that sends the recorded bytes
    at the recorded times (``speed`` times faster), so an unmodified application runs
    against what a real robot sent. What the application writes is counted and decoded
    (``commands``), never acted on.

    Timing starts with `on_connect`: when the server starts (a pty, after
    ``start_after`` seconds, so the application has time to open it) or when a TCP
    client connects.

    Args:
        path: The capture file.
        device: The device's name, to decode what the application writes.
        speed: Playback speed (2: twice as fast).
        start_after: Seconds between `on_connect` and the first chunk.
        on_done: Called once the last chunk has been played.
    """

    def __init__(
        self,
        path: str | Path,
        device: str,
        *,
        speed: float = 1.0,
        start_after: float = 0.0,
        on_done: Callable[[], None] | None = None,
    ) -> None:
        self.speed = check_real(speed, "speed", low=0, low_open=True)
        self.chunks = list(read_capture(path))
        self.start_after = float(start_after)
        self._decoder = profile(device).codec.command_decoder()
        #: What the application wrote, decoded, in order.
        self.commands: list[object] = []
        #: Bytes the application wrote; bytes of the capture played since the last
        #: (re)start of playback.
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
        """Start playing (again) from the first chunk: ``bytes_played`` counts this
        playback, so it never exceeds the capture's bytes."""
        self._t0 = now + self.start_after
        self._next = 0
        self.bytes_played = 0

    def hold(self) -> None:
        """Play nothing until the next `on_connect`: on TCP, where the server's
        start calls it too, playback then waits for the first client instead of
        playing to nobody."""
        self._t0 = None
        self._next = 0
        self.bytes_played = 0

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
