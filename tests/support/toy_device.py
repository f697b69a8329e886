"""A third device, whole, in one file: the example of "Adding a device" in the docs.

The *toy* is a small differential-drive base with a protocol of its own::

    A5 5A | type u8 | len u8 | data (len bytes) | check u8     check = XOR of type..data

    device -> host   0x01 telemetry  speed i16 mm/s, battery u16 mV   (50 Hz, unprompted)
                     0x82 pong       token u8, uptime u16 s            (reply to 0x02)
    host -> device   0x02 ping       token u8
                     0x03 drive      linear i16 mm/s, angular i16 mrad/s

It has everything a device package has (a codec, a :class:`~chassis_sdk.core.Device`
subclass, a firmware model and a :class:`~chassis_sdk.devices.DeviceProfile`) and
nothing else: lifetime, the close fence, the velocity watchdog and deadman, requests
with timeouts and retries, streams, events, odometry, stats, the simulator server,
``detect``, ``record``/``replay``/``plot`` and ``sim`` all come from the SDK.
``tests/test_toy_device.py`` registers it at run time (and, in a subprocess, through
an entry point) and proves each of those.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from functools import reduce
from operator import xor
from typing import ClassVar, TypeVar

from chassis_sdk.core import (
    INVALID,
    NEED_DATA,
    Device,
    FirmwareModel,
    FrameBuilder,
    FrameDecoder,
    FrameTable,
    Subscription,
    next_slot,
)
from chassis_sdk.core.validation import INT16, check_int, scale_to_int
from chassis_sdk.devices import Codec, DeviceProfile
from chassis_sdk.sim import LineFaults, SimulatorServer

__all__ = ["PROFILE", "Toy", "ToyDecoder", "ToyFirmware", "ToySimulator", "ToyTelemetry"]

HEAD = b"\xa5\x5a"

# --- messages ---------------------------------------------------------------------------
# --8<-- [start:messages]


@dataclass(frozen=True, slots=True)
class ToyTelemetry:
    """0x01: what the toy reports 50 times a second."""

    speed: float  #: m/s
    battery: float  #: V
    timestamp: float = 0.0


@dataclass(frozen=True, slots=True)
class Pong:
    """0x82: the reply to a ping, with the ping's token."""

    token: int
    uptime: int  #: seconds since power-up


@dataclass(frozen=True, slots=True)
class Ping:
    """0x02: ask for a pong carrying ``token``."""

    token: int


@dataclass(frozen=True, slots=True)
class Drive:
    """0x03: drive at ``linear_mm`` mm/s and ``angular_mrad`` mrad/s."""

    linear_mm: int
    angular_mrad: int


ToyMessage = ToyTelemetry | Pong
ToyCommand = Ping | Drive

# --8<-- [end:messages]

# --- codec ------------------------------------------------------------------------------
# --8<-- [start:codec]

_TELEMETRY = struct.Struct("<hH")
_PONG = struct.Struct("<BH")
_DRIVE = struct.Struct("<hh")


def encode(msg: ToyMessage | ToyCommand) -> bytes:
    """One frame for ``msg``."""
    if isinstance(msg, ToyTelemetry):
        kind, data = 0x01, _TELEMETRY.pack(round(msg.speed * 1000), round(msg.battery * 1000))
    elif isinstance(msg, Pong):
        kind, data = 0x82, _PONG.pack(msg.token, msg.uptime)
    elif isinstance(msg, Ping):
        kind, data = 0x02, bytes((check_int(msg.token, "token", low=0, high=255),))
    else:
        kind, data = 0x03, _DRIVE.pack(msg.linear_mm, msg.angular_mrad)
    body = bytes((kind, len(data))) + data
    return HEAD + body + bytes((reduce(xor, body, 0),))


def drive_command(linear: float, angular: float) -> Drive:
    """A drive command from m/s and rad/s; ``ValueError`` if either does not fit."""
    return Drive(
        scale_to_int(linear, 1000, INT16, "linear", "m/s"),
        scale_to_int(angular, 1000, INT16, "angular", "rad/s"),
    )


def _telemetry(b: bytes | bytearray, o: int, n: int, ts: float) -> ToyTelemetry:
    speed, millivolts = _TELEMETRY.unpack_from(b, o)
    return ToyTelemetry(speed / 1000, millivolts / 1000, ts)


def _pong(b: bytes | bytearray, o: int, n: int, ts: float) -> Pong:
    return Pong(*_PONG.unpack_from(b, o))


def _ping(b: bytes | bytearray, o: int, n: int, ts: float) -> Ping:
    return Ping(b[o])


def _drive(b: bytes | bytearray, o: int, n: int, ts: float) -> Drive:
    return Drive(*_DRIVE.unpack_from(b, o))


_M = TypeVar("_M")


class _ToyFraming(FrameDecoder[_M]):
    """The toy's framing over the SDK's scanner: only ``_try_frame`` is the toy's."""

    _head = HEAD
    _table: ClassVar[FrameTable] = {}

    def _try_frame(
        self, buf: bytes | bytearray, start: int, end: int, out: list[_M], ts: float
    ) -> int:
        if end - start < 4:
            return NEED_DATA
        entry = self._table.get(buf[start + 2])
        if entry is None or buf[start + 3] != entry[0]:
            return INVALID
        size = 4 + entry[0] + 1
        if end - start < size:
            return NEED_DATA
        if reduce(xor, buf[start + 2 : start + size - 1], 0) != buf[start + size - 1]:
            self.stats.checksum_errors += 1
            return INVALID
        out.append(entry[1](buf, start + 4, entry[0], ts))
        return size


class ToyDecoder(_ToyFraming[ToyMessage]):
    """What the toy sends."""

    _table: ClassVar[FrameTable] = {0x01: (4, _telemetry), 0x82: (3, _pong)}


class ToyCommandDecoder(_ToyFraming[ToyCommand]):
    """What the host sends (the firmware model's decoder)."""

    _table: ClassVar[FrameTable] = {0x02: (1, _ping), 0x03: (4, _drive)}


# --8<-- [end:codec]

# --- the device -------------------------------------------------------------------------
# --8<-- [start:device]


class Toy(Device[ToyMessage, int]):
    """The toy base: ``set_velocity``/``stop`` (from :class:`Device`), :meth:`ping`,
    and :meth:`telemetry`. Options are those of every device."""

    device_name = "toy"

    def _make_decoder(self) -> ToyDecoder:
        return ToyDecoder()

    def _init_protocol(self) -> None:
        self._telemetry = self._stream("telemetry")
        self._next_token = 0
        self._handlers = {
            ToyTelemetry: self._on_telemetry,
            Pong: lambda m: self._reply(m.token, m),
        }

    def _on_telemetry(self, t: ToyTelemetry) -> None:
        self._telemetry.publish(t)
        self._battery(t.battery, t.timestamp)
        self._integrate(t.speed, 0.0, t.timestamp)

    def _zero_frame(self) -> bytes:
        return encode(Drive(0, 0))

    def _velocity_builder(self, linear: float, angular: float) -> FrameBuilder:
        drive_command(linear, angular)  # ValueError before anything is written
        return lambda v, w: encode(drive_command(v, w))

    async def ping(self) -> int:
        """Ping the toy (retried ``retries`` times); return its uptime in seconds.

        Raises:
            RequestTimeoutError: No pong within ``request_timeout`` on any attempt.
        """

        def build() -> tuple[bytes, int]:
            token = self._next_token
            self._next_token = (token + 1) & 0xFF
            return encode(Ping(token)), token

        pong: Pong = await self._request(build, read_only=True, name="ping")
        return pong.uptime

    def telemetry(self) -> Subscription[ToyTelemetry]:
        """Subscribe to the 50 Hz telemetry."""
        return self._subscribe(self._telemetry)

    @property
    def latest_telemetry(self) -> ToyTelemetry | None:
        """The most recent telemetry, or ``None``."""
        return self._telemetry.latest


# --8<-- [end:device]

# --- the firmware model -----------------------------------------------------------------
# --8<-- [start:firmware]


class ToyFirmware(FirmwareModel[ToyCommand]):
    """Sends telemetry every 20 ms, answers pings, and drives as told; like real
    firmware it stops by itself 0.5 s after the last drive command."""

    PERIOD = 0.02
    TIMEOUT = 0.5

    def __init__(self) -> None:
        super().__init__()
        self._power_on()

    def _power_on(self) -> None:
        self._decoder = ToyCommandDecoder()
        self.speed = 0.0
        self.battery = 12.6
        self._booted = 0.0
        self._last_drive = -math.inf
        self._next = 0.0

    def on_connect(self, now: float) -> None:
        self._booted = self._booted or now
        self._next = now

    def _execute(self, cmd: ToyCommand, now: float) -> bytes:
        if isinstance(cmd, Ping):
            return encode(Pong(cmd.token, int(now - self._booted) & 0xFFFF))
        self.speed = cmd.linear_mm / 1000
        self._last_drive = now
        return b""

    def poll(self, now: float) -> bytes:
        if self.booting(now) or now < self._next:
            return b""
        if now - self._last_drive > self.TIMEOUT:
            self.speed = 0.0
        self._next = next_slot(self._next, self.PERIOD, now)
        return encode(ToyTelemetry(self.speed, self.battery))

    def next_deadline(self) -> float:
        return self._next


class ToySimulator(SimulatorServer):
    """The toy firmware on a pty (or on ``tcp_port``), with line ``faults``."""

    firmware: ToyFirmware

    def __init__(self, *, tcp_port: int | None = None, faults: LineFaults | None = None) -> None:
        super().__init__(ToyFirmware(), tcp_port=tcp_port, faults=faults)


# --8<-- [end:firmware]

# --- the registry entry -----------------------------------------------------------------
# --8<-- [start:profile]

PROFILE = DeviceProfile(
    name="toy",
    summary="a toy differential base (A5 5A frames)",
    recognised_by="toy telemetry (0x01)",
    device=Toy,
    firmware=ToyFirmware,
    codec=Codec(
        decoder=ToyDecoder,
        command_decoder=ToyCommandDecoder,
        examples=(
            (bytes.fromhex("A55A 01 04 2C01 3031 29"), ToyTelemetry(0.3, 12.592)),
            (bytes.fromhex("A55A 82 03 07 0A00 8C"), Pong(7, 10)),
        ),
        command_examples=(
            (bytes.fromhex("A55A 02 01 07 04"), Ping(7)),
            (bytes.fromhex("A55A 03 04 C800 F4FF C4"), Drive(200, -12)),
        ),
        max_buffered=8,
    ),
)

# --8<-- [end:profile]
