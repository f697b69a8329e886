"""Protocol A, the chassis protocol: frames, typed messages, encoder and decoders.

Frame layout (all integers little-endian)::

    ED DE | seq u16 | id u8 | len u8 | data (len - 10 bytes) | check u16 | BD BC

``len`` counts the whole frame, head to tail; ``check`` is the sum of every byte before
it, modulo 65536. The field tables and the vendor document's errata are in
``docs/protocols.md``.

This module is I/O-free: bytes in, messages out; messages in, bytes out.
"""

from __future__ import annotations

import struct
from typing import Any, ClassVar, TypeVar

from ...core import compiled
from ...core.construct import MemberCache, frozen_builder
from ...core.framing import (
    INVALID,
    NEED_DATA,
    Column,
    DecoderStats,
    FrameDecoder,
    FrameLayout,
    FrameTable,
    byte_sum,
)
from ...core.validation import INT16, check_int, check_real, scale_to_int
from .messages import (
    ChassisInfo,
    ChassisMessage,
    ChassisStatus,
    Command,
    CommandId,
    DockingState,
    DriverError,
    DriverStatus,
    DriveVelocity,
    DriveWheels,
    FaultClear,
    FirmwareVersion,
    HardwareVersion,
    HostCommand,
    MotorStatus,
    PowerTelemetry,
    ReplyId,
    ShipDate,
    Telemetry,
    WheelCurrents,
    WheelDriver,
    WheelSpeeds,
)

__all__ = [
    "ANGULAR_LIMIT",
    "HEAD",
    "TAIL",
    "ChassisCommandDecoder",
    "ChassisDecoder",
    "ChassisEncoder",
    "SequenceTracker",
    "encode_frame",
    "velocity_command",
    "wheel_speeds_command",
]

#: The two head bytes (0xDEED little-endian).
HEAD = b"\xed\xde"
#: The two tail bytes (0xBCBD little-endian).
TAIL = b"\xbd\xbc"
_HEADER = struct.Struct("<HHBB")
_CHECK = struct.Struct("<H")
_OVERHEAD = 10  # head 2 + seq 2 + id 1 + len 1 + check 2 + tail 2
#: The largest angular velocity a drive command may ask for (rad/s). The float32 field
#: holds far more, but the chassis reports its angular velocity as int16 mrad/s, so it
#: cannot even say it turns faster than this; a larger value is a mistake (degrees for
#: radians, a runaway controller), refused before anything is written.
ANGULAR_LIMIT = 32.767


_M = TypeVar("_M")


def velocity_command(linear: float, angular: float) -> DriveVelocity:
    """Build a linear-mode drive command from SI units, checking every value.

    Args:
        linear: Linear velocity in m/s (sent as int16 mm/s).
        angular: Angular velocity in rad/s (sent as float32), at most
            `ANGULAR_LIMIT` either way.

    Raises:
        ValueError: A value is NaN, infinite, or does not fit its wire field.
    """
    linear_mm = scale_to_int(linear, 1000, INT16, "linear", "m/s")
    wz = check_real(angular, "angular", low=-ANGULAR_LIMIT, high=ANGULAR_LIMIT, unit="rad/s")
    return DriveVelocity(linear_mm, wz)


def wheel_speeds_command(left: float, right: float) -> DriveWheels:
    """Build a wheel-mode drive command from left and right speeds in m/s.

    Raises:
        ValueError: A value is NaN, infinite, or overflows int16 mm/s.
    """
    return DriveWheels(
        scale_to_int(left, 1000, INT16, "left", "m/s"),
        scale_to_int(right, 1000, INT16, "right", "m/s"),
    )


def encode_frame(frame_id: int, payload: bytes, seq: int = 0) -> bytes:
    """Wrap ``payload`` in a protocol A frame (head, seq, id, len, check, tail).

    Raises:
        ValueError: ``frame_id`` or ``seq`` out of range, or the payload is too long.
    """
    check_int(frame_id, "frame id", low=0, high=0xFF)
    check_int(seq, "seq", low=0, high=0xFFFF)
    length = len(payload) + _OVERHEAD
    if length > 0xFF:
        raise ValueError(f"payload of {len(payload)} bytes does not fit a frame (max 245)")
    body = _HEADER.pack(0xDEED, seq, frame_id, length) + payload
    return body + _CHECK.pack(sum(body) & 0xFFFF) + TAIL


# --- payload packers ---------------------------------------------------------------------

_U16 = struct.Struct("<H")
_TELEMETRY = struct.Struct("<HHHhhhhhh")
_DRIVER = struct.Struct("<4H4H4h4H2H2H")
_POWER = struct.Struct("<4h2H")
_INFO = struct.Struct("<5H")
_DATE = struct.Struct("<3B")
_DRIVE_V = struct.Struct("<Hhf")
_DRIVE_W = struct.Struct("<HhhH")


def _tenths(x: float) -> int:
    return round(x * 10)


def _milli(x: float) -> int:
    return round(x * 1000)


def _pack(msg: ChassisMessage | HostCommand) -> tuple[int, bytes]:
    """Return ``(frame id, payload)`` for any message of this protocol."""
    if isinstance(msg, Command):
        return msg.id, _U16.pack(msg.value)
    if isinstance(msg, DriveVelocity):
        return CommandId.DRIVE, _DRIVE_V.pack(0, msg.linear_mm, msg.angular)
    if isinstance(msg, DriveWheels):
        return CommandId.DRIVE, _DRIVE_W.pack(1, msg.left_mm, msg.right_mm, 0)
    if isinstance(msg, Telemetry):
        return ReplyId.TELEMETRY, _TELEMETRY.pack(
            _tenths(msg.voltage),
            msg.status,
            msg.docking,
            _milli(msg.linear),
            _milli(msg.angular),
            *(_milli(w) for w in msg.wheels),
        )
    if isinstance(msg, DriverStatus):
        w = msg.wheels
        return ReplyId.DRIVER_STATUS, _DRIVER.pack(
            *(d.errors for d in w),
            *(d.motor for d in w),
            *(_tenths(d.current) for d in w),
            *(_tenths(d.peak_current) for d in w),
            _tenths(msg.temperature_front),
            _tenths(msg.temperature_rear),
            _tenths(msg.voltage_front),
            _tenths(msg.voltage_rear),
        )
    if isinstance(msg, PowerTelemetry):
        return ReplyId.POWER, _POWER.pack(
            *(_tenths(c) for c in msg.currents),
            _tenths(msg.voltage_front),
            _tenths(msg.voltage_rear),
        )
    if isinstance(msg, FirmwareVersion):
        return ReplyId.FIRMWARE_VERSION, _U16.pack(msg.version)
    if isinstance(msg, HardwareVersion):
        return ReplyId.HARDWARE_VERSION, msg.text.encode("ascii")
    if isinstance(msg, ChassisInfo):
        return ReplyId.CHASSIS_INFO, _INFO.pack(
            _milli(msg.track_width),
            _milli(msg.wheelbase),
            _milli(msg.wheel_diameter),
            msg.gear_ratio,
            msg.encoder_resolution,
        )
    if isinstance(msg, ShipDate):
        return ReplyId.SHIP_DATE, _DATE.pack(msg.year - 2000, msg.month, msg.day)
    raise TypeError(f"not a protocol A message: {msg!r}")


class ChassisEncoder:
    """Turns messages into protocol A frames, numbering them with a wrapping uint16.

    One encoder per link: the sequence number increments once per frame encoded,
    whatever its id, and wraps from 65535 to 0. The host uses it for commands; the
    simulator uses it for the chassis's frames.

    Examples:
        >>> enc = ChassisEncoder()
        >>> enc.encode(Command(CommandId.FIRMWARE_VERSION)).hex(" ")
        'ed de 00 00 07 0c 00 00 de 01 bd bc'
    """

    __slots__ = ("seq",)

    def __init__(self, seq: int = 0) -> None:
        #: The sequence number the next frame will carry.
        self.seq = seq & 0xFFFF

    def encode(self, msg: ChassisMessage | HostCommand) -> bytes:
        """Encode one message as a frame with the next sequence number.

        Raises:
            ValueError: A field does not fit its wire type (checked before the
                sequence number advances).
        """
        try:
            frame_id, payload = _pack(msg)
        except struct.error as exc:
            raise ValueError(f"{msg!r} does not fit the wire format: {exc}") from None
        except (OverflowError, UnicodeEncodeError) as exc:
            raise ValueError(f"{msg!r} does not fit the wire format: {exc}") from None
        frame = encode_frame(frame_id, payload, self.seq)
        self.seq = (self.seq + 1) & 0xFFFF
        return frame

    # Convenience builders for every host command, named as in the API.
    def set_telemetry(self, enabled: bool) -> bytes:
        """0x01: switch the 50 Hz telemetry on or off."""
        return self.encode(Command(CommandId.TELEMETRY, int(enabled)))

    def drive_velocity(self, linear: float, angular: float) -> bytes:
        """0x02 mode 0 from SI units (m/s, rad/s)."""
        return self.encode(velocity_command(linear, angular))

    def drive_wheels(self, left: float, right: float) -> bytes:
        """0x02 mode 1 from SI units (m/s)."""
        return self.encode(wheel_speeds_command(left, right))

    def emergency_stop(self, active: bool) -> bytes:
        """0x03: engage (True) or release (False) the software emergency stop."""
        return self.encode(Command(CommandId.EMERGENCY_STOP, int(active)))

    def clear_faults(self, faults: FaultClear) -> bytes:
        """0x05: clear the latched ``faults``."""
        return self.encode(Command(CommandId.CLEAR_FAULTS, int(faults)))

    def docking(self, enabled: bool) -> bytes:
        """0x06: start (True) or stop (False) automatic docking."""
        return self.encode(Command(CommandId.DOCKING, int(enabled)))

    def read(self, request: CommandId) -> bytes:
        """0x07, 0x08, 0x09, 0x0A or 0xB0: a read request."""
        if request not in _READ_REQUESTS:
            raise ValueError(f"{request!r} is not a read request")
        return self.encode(Command(request, _READ_REQUESTS[request]))

    def set_power_telemetry(self, enabled: bool) -> bytes:
        """0xB1: switch the 20 Hz current/voltage upload on or off."""
        return self.encode(Command(CommandId.POWER_TELEMETRY, int(enabled)))


#: Read requests and the data word each carries (REPLY_TO gives the id of each reply).
_READ_REQUESTS: dict[CommandId, int] = {
    CommandId.FIRMWARE_VERSION: 0,
    CommandId.HARDWARE_VERSION: 0,
    CommandId.CHASSIS_INFO: 0,
    CommandId.SHIP_DATE: 0,
    CommandId.DRIVER_STATUS: 1,
}
#: The reply id each read request is answered with.
REPLY_TO: dict[CommandId, ReplyId] = {
    CommandId.FIRMWARE_VERSION: ReplyId.FIRMWARE_VERSION,
    CommandId.HARDWARE_VERSION: ReplyId.HARDWARE_VERSION,
    CommandId.CHASSIS_INFO: ReplyId.CHASSIS_INFO,
    CommandId.SHIP_DATE: ReplyId.SHIP_DATE,
    CommandId.DRIVER_STATUS: ReplyId.DRIVER_STATUS,
}


# --- decoding ----------------------------------------------------------------------------

# Parsers follow the core's convention (core.framing.Parser): they get the offset of the
# frame's data, which starts 6 bytes after the head; the sequence number sits 4 bytes
# before the data, the frame id 2 bytes before it.
_DATA = 6
_SEQ = -4
_ID = -2
#: 0x81 from its sequence number: the number and the data in one unpack.
_TELEMETRY_FRAME = struct.Struct("<H2x" + _TELEMETRY.format[1:])
#: The header after the head (sequence number, frame id, length byte), and the frame's
#: last four bytes (check, tail): one unpack each instead of a byte at a time.
_SEQ_ID_LEN = struct.Struct("<HBB")
_CHECK_TAIL = struct.Struct("<HH")


_build_telemetry = frozen_builder(Telemetry)
_status = MemberCache(ChassisStatus)
_docking = MemberCache(DockingState)
_tuple_new = tuple.__new__


def _parse_telemetry(b: bytes | bytearray, o: int, n: int, ts: float) -> Telemetry:
    # The hot path (50 Hz per chassis): see _fast.py for why it is built this way.
    seq, v, st, dk, vx, wz, fl, fr, rl, rr = _TELEMETRY_FRAME.unpack_from(b, o + _SEQ)
    wheels = _tuple_new(WheelSpeeds, (fl / 1000, fr / 1000, rl / 1000, rr / 1000))
    return _build_telemetry(
        v / 10, _status[st], _docking[dk], vx / 1000, wz / 1000, wheels, seq, ts
    )


def _parse_driver(b: bytes | bytearray, o: int, n: int, ts: float) -> DriverStatus:
    f = _DRIVER.unpack_from(b, o)
    fl, fr, rl, rr = (
        WheelDriver(DriverError(f[i]), MotorStatus(f[4 + i]), f[8 + i] / 10, f[12 + i] / 10)
        for i in range(4)
    )
    return DriverStatus(fl, fr, rl, rr, f[16] / 10, f[17] / 10, f[18] / 10, f[19] / 10)


def _parse_power(b: bytes | bytearray, o: int, n: int, ts: float) -> PowerTelemetry:
    a, bb, c, d, vf, vr = _POWER.unpack_from(b, o)
    seq = _U16.unpack_from(b, o + _SEQ)[0]
    return PowerTelemetry(WheelCurrents(a / 10, bb / 10, c / 10, d / 10), vf / 10, vr / 10, seq, ts)


def _parse_firmware(b: bytes | bytearray, o: int, n: int, ts: float) -> FirmwareVersion:
    return FirmwareVersion(_U16.unpack_from(b, o)[0])


def _parse_hardware(b: bytes | bytearray, o: int, n: int, ts: float) -> HardwareVersion | None:
    raw = bytes(b[o : o + n])
    try:
        return HardwareVersion(raw.decode("ascii").rstrip("\x00"))
    except UnicodeDecodeError:
        return None


def _parse_info(b: bytes | bytearray, o: int, n: int, ts: float) -> ChassisInfo:
    tw, wb, wd, gr, enc = _INFO.unpack_from(b, o)
    return ChassisInfo(tw / 1000, wb / 1000, wd / 1000, gr, enc)


def _parse_date(b: bytes | bytearray, o: int, n: int, ts: float) -> ShipDate:
    y, m, d = _DATE.unpack_from(b, o)
    return ShipDate(2000 + y, m, d)


def _parse_command(b: bytes | bytearray, o: int, n: int, ts: float) -> Command:
    return Command(CommandId(b[o + _ID]), _U16.unpack_from(b, o)[0])


def _parse_drive(b: bytes | bytearray, o: int, n: int, ts: float) -> HostCommand | None:
    mode = _U16.unpack_from(b, o)[0]
    if mode == 0:
        _, vx, wz = _DRIVE_V.unpack_from(b, o)
        return DriveVelocity(vx, wz)
    if mode == 1:
        _, left, right, _reserved = _DRIVE_W.unpack_from(b, o)
        return DriveWheels(left, right)
    return None


# The value each type's length field must hold (here it counts the whole frame, head to
# tail), or 0 if the type's length varies.

_DEVICE_FRAMES: FrameTable = {
    ReplyId.TELEMETRY: (28, _parse_telemetry),
    ReplyId.DRIVER_STATUS: (50, _parse_driver),
    ReplyId.POWER: (22, _parse_power),
    ReplyId.FIRMWARE_VERSION: (12, _parse_firmware),
    ReplyId.HARDWARE_VERSION: (0, _parse_hardware),
    ReplyId.CHASSIS_INFO: (20, _parse_info),
    ReplyId.SHIP_DATE: (13, _parse_date),
}

#: The framing as data (core.columns decodes whole captures with it): the frame id at 4,
#: a fixed size from the table (the length byte unchecked), else the length byte gives
#: the whole frame (10..255); a 16-bit sum of everything before the check; the tail.
_LAYOUT = FrameLayout(
    type_at=4, length_at=5, header=6, fixed_is_length=False, size_of_length=0,
    min_length=_OVERHEAD, sum_from=0, check_size=2, tail=TAIL, data_at=_DATA,
    overhead=_OVERHEAD,
)  # fmt: skip


def _wheels(prefix: str, at: int, divisor: float) -> tuple[Column, ...]:
    names = ("front_left", "front_right", "rear_left", "rear_right")
    return tuple(Column(f"{prefix}.{n}", at + 2 * i, "h", divisor) for i, n in enumerate(names))


#: The high-rate frames as columns (names as a CSV export flattens the messages).
_DEVICE_COLUMNS: dict[int, tuple[str, tuple[Column, ...]]] = {
    ReplyId.TELEMETRY: ("Telemetry", (
        Column("voltage", 0, "H", 10), Column("status", 2, "H", None),
        Column("docking", 4, "H", None), Column("linear", 6, "h", 1000),
        Column("angular", 8, "h", 1000), *_wheels("wheels", 10, 1000),
        Column("seq", _SEQ, "H", None),
    )),
    ReplyId.POWER: ("PowerTelemetry", (
        *_wheels("currents", 0, 10), Column("voltage_front", 8, "H", 10),
        Column("voltage_rear", 10, "H", 10), Column("seq", _SEQ, "H", None),
    )),
}  # fmt: skip

_HOST_FRAMES: FrameTable = {
    int(cid): ((18, _parse_drive) if cid == CommandId.DRIVE else (12, _parse_command))
    for cid in CommandId
}


class SequenceTracker:
    """Counts breaks in a chassis's frame numbers (FRAME-NUMS), whichever way it counts.

    The document does not say whether the chassis keeps one counter for every frame it
    sends (0x81, 0xB1 and replies interleaved) or one counter per frame id. Each scheme
    predicts the next number differently, so every frame is checked against both:

    * a frame that only the *shared* prediction gets right is evidence for it, one that
      only the *per-id* prediction gets right is evidence for that; after
      `EVIDENCE` more votes for one scheme than the other, it is the scheme;
    * once the scheme is known, a frame it did not predict is a gap (counted once,
      however many frames were lost);
    * before that, a frame that *neither* predicts is a gap under either scheme, so it
      is counted; one that only one of them predicts is not (it cannot be told apart
      from evidence), so a gap in the first few frames may go uncounted, never a
      false one.

    Sans-IO: the decoder calls `update` for every valid frame; the device calls
    `reset` on every new connection (a reconnect starts counting afresh).
    """

    #: Votes ahead that settle the scheme.
    EVIDENCE = 3

    __slots__ = ("_by_id", "_last", "_votes", "gaps", "scheme")

    def __init__(self) -> None:
        #: Breaks found so far (kept across :meth:`reset`).
        self.gaps = 0
        #: ``None`` until known, then ``"shared"`` or ``"per-id"``.
        self.scheme: str | None = None
        self._last: int | None = None
        self._by_id: dict[int, int] = {}
        self._votes = 0  # > 0: shared is ahead; < 0: per-id is ahead

    def reset(self) -> None:
        """Forget the last numbers (a new connection); the scheme and count stay."""
        self._last = None
        self._by_id.clear()

    def update(self, frame_id: int, seq: int) -> None:
        """Check one frame's number."""
        last = self._last
        by_id = self._by_id
        previous = by_id.get(frame_id)
        self._last = by_id[frame_id] = seq
        if last is None:
            return
        shared = seq == (last + 1) & 0xFFFF
        per_id = previous is None or seq == (previous + 1) & 0xFFFF
        if shared and per_id:  # the usual frame: both schemes agree, nothing to learn
            return
        scheme = self.scheme
        if scheme is None:
            if shared != per_id:
                self._votes += 1 if shared else -1
                if abs(self._votes) >= self.EVIDENCE:
                    self.scheme = "shared" if self._votes > 0 else "per-id"
            elif not shared:
                self.gaps += 1
        elif not (shared if scheme == "shared" else per_id):
            self.gaps += 1


class _ProtocolADecoder(FrameDecoder[_M]):
    """Framing for protocol A, parametrised by the table of frames it accepts.

    For a frame id with a fixed size, the size comes from the table, not from the length
    byte: the vendor's own 0x89 example carries a wrong length byte with a valid
    checksum, and firmware built from the same source may do the same. Trusting the table
    also means a false head in noise never makes us wait for 255 bytes. The mismatch is
    counted in ``stats.length_mismatches``. Only variable-size frames (0x88) use the
    length byte, bounded to 10..255.
    """

    _head = HEAD
    _table: ClassVar[FrameTable] = {}
    layout = _LAYOUT

    __slots__ = ("sequence",)

    def __init__(self) -> None:
        super().__init__()
        #: Breaks in the frame numbers (see :class:`SequenceTracker`).
        self.sequence = SequenceTracker()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Give every subclass the pure `FrameDecoder.feed` unless it defines its own.

        The compiled ``feed`` (when built) mirrors this module's own two decoders, whose
        ``_try_frame`` and parsers it knows; a subclass may override any of them (or
        ``_table``, ``_head``), and only the pure loop calls the overrides. This module's
        decoders get the compiled ``feed`` after they are defined, below.
        """
        super().__init_subclass__(**kwargs)
        if "feed" not in cls.__dict__:
            cls.feed = FrameDecoder.feed  # type: ignore[method-assign]

    def _try_frame(
        self, buf: bytes | bytearray, start: int, end: int, out: list[_M], ts: float
    ) -> int:
        # Decodes the frame at ``start`` and, while another one follows right after it
        # (a chunk from a busy port holds many), those too: this saves the shared loop's
        # scan and call per frame, a third of a frame's cost in the profile. A failure
        # past the first frame returns what was consumed so far, uncounted: the shared
        # loop comes back to that frame and it is counted then, once.
        table = self._table
        stats = self.stats
        track = self.sequence.update
        first = start
        while True:
            if end - start < 6:
                return NEED_DATA if start == first else start - first
            seq, frame_id, claimed = _SEQ_ID_LEN.unpack_from(buf, start + 2)
            entry = table.get(frame_id)
            if entry is None:
                return INVALID if start == first else start - first
            size, parser = entry
            if size == 0:
                if claimed < _OVERHEAD:
                    return INVALID if start == first else start - first
                size = claimed
            stop = start + size
            if stop > end:
                return NEED_DATA if start == first else start - first
            check, tail = _CHECK_TAIL.unpack_from(buf, stop - 4)
            if tail != 0xBCBD:
                return INVALID if start == first else start - first
            if byte_sum(buf[start : stop - 4], 0) & 0xFFFF != check:
                if start != first:
                    return start - first
                stats.checksum_errors += 1
                return INVALID
            msg = parser(buf, start + _DATA, size - _OVERHEAD, ts)
            if msg is None:
                if start != first:
                    return start - first
                stats.malformed_frames += 1
                return INVALID
            if claimed != size:
                stats.length_mismatches += 1
            track(frame_id, seq)
            out.append(msg)
            start = stop
            if end - start < 2 or buf[start] != 0xED or buf[start + 1] != 0xDE:
                return start - first


class ChassisDecoder(_ProtocolADecoder[ChassisMessage]):
    """Sans-IO decoder of everything the chassis sends (0x81, 0xB0, 0xB1, 0x87-0x8A).

    Examples:
        >>> dec = ChassisDecoder()
        >>> dec.feed(bytes.fromhex("ED DE 00 00 8A 0D 18 01 02 7D 02 BD BC"))
        [ShipDate(year=2024, month=1, day=2)]
    """

    _table = _DEVICE_FRAMES
    columns = _DEVICE_COLUMNS


class ChassisCommandDecoder(_ProtocolADecoder[HostCommand]):
    """Sans-IO decoder of what the host sends (used by the simulator and for captures)."""

    _table = _HOST_FRAMES


# The compiled fast path (issue 29), when built: the same feed for this module's own two
# decoders, never for their subclasses (see _ProtocolADecoder.__init_subclass__; the
# compiled feed checks the exact type too, for a subclass whose feed calls super().feed).
# It reads _table, _head, _try_frame and the tracker on every call, so a changed table
# is honoured and anything else changed sends the call to the pure FrameDecoder.feed.
_compiled = compiled.load("chassis_sdk.devices.chassis._compiled")
if _compiled is not None:
    _compiled.bind(
        decoder_cls=ChassisDecoder,
        command_cls=ChassisCommandDecoder,
        pure_feed=FrameDecoder.feed,
        try_frame=_ProtocolADecoder._try_frame,
        tracker_cls=SequenceTracker,
        stats_cls=DecoderStats,
        parse_telemetry=_parse_telemetry,
        telemetry_cls=Telemetry,
        wheels_cls=WheelSpeeds,
        status=_status,
        docking=_docking,
    )
    ChassisDecoder.feed = ChassisCommandDecoder.feed = _compiled.feed  # type: ignore[method-assign]
