"""Protocol B, the controller-board protocol: frames, typed messages, encoder and decoders.

Frame layout (integers little-endian)::

    head (FE CE board->host, AB BC host->board) | type u8 | len u8 | data (len - 1) | check u8

``len`` counts the data bytes plus the check byte; ``check`` is
``(type + len + sum(data)) & 0xFF`` (the head is not summed).

Why the decoder is stricter than the framing requires
------------------------------------------------------
There is no tail and no sequence number, and the check is a single byte, so one random
candidate in 256 passes it. To keep noise from producing phantom messages the decoder
only accepts the known types, each with its exact length; log text (the one variable
frame) must be printable UTF-8. A candidate that fails any test gives up only its first
byte, and scanning resumes inside the buffer (see ``_framing``).

This module is I/O-free.
"""

from __future__ import annotations

import struct
from typing import Any, ClassVar, TypeVar

from ...core import compiled
from ...core.construct import frozen_builder
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
from ...core.validation import INT16, UINT8, check_int, check_member, scale_to_int
from .messages import (
    BatteryReading,
    BoardCommand,
    BoardMessage,
    BoardType,
    BuzzerCommand,
    BuzzerReply,
    ImuCounts,
    ImuSample,
    ImuScale,
    LedCommand,
    LedReply,
    LogMessage,
    Motor,
    MotorPwmCommand,
    Servo,
    ServoCommand,
    SwitchAction,
    Vector3,
    VelocityCommand,
    VelocityFeedback,
)

__all__ = [
    "DEVICE_HEAD",
    "HOST_HEAD",
    "BoardCommandDecoder",
    "BoardDecoder",
    "BoardEncoder",
    "encode_frame",
    "motor_pwm_command",
    "servo_command",
    "velocity_command",
]

#: Head of frames from the board to the host.
DEVICE_HEAD = b"\xfe\xce"
#: Head of frames from the host to the board.
HOST_HEAD = b"\xab\xbc"

#: The vendor document's IMU scale, the decoder's: accel counts per g, gyro counts
#: per °/s (see ImuScale for why 164 is not a standard accelerometer range).
ACCEL_SCALE = ImuScale().accel
GYRO_SCALE = ImuScale().gyro


def velocity_command(linear: float, angular: float) -> VelocityCommand:
    """Build a 0x22 command from m/s and rad/s (each sent × 1000 as int16).

    Raises:
        ValueError: NaN, infinite, or out of int16 range after scaling (±32.767).
    """
    return VelocityCommand(
        scale_to_int(linear, 1000, INT16, "linear", "m/s"),
        scale_to_int(angular, 1000, INT16, "angular", "rad/s"),
    )


def motor_pwm_command(motor: int, pwm: int) -> MotorPwmCommand:
    """Build a 0x21 command, checking the motor number and the int16 PWM value.

    Raises:
        ValueError: Unknown motor, or a PWM value that is not an int16 integer.
    """
    m = check_member(
        Motor,
        motor,
        "motor",
        "use Motor.REAR_LEFT (1), REAR_RIGHT (2), FRONT_LEFT (3) or FRONT_RIGHT (4)",
    )
    return MotorPwmCommand(m, check_int(pwm, "pwm", low=INT16[0], high=INT16[1]))


def servo_command(servo: int, angle: float) -> ServoCommand:
    """Build a 0x31 command from a servo number and an angle in degrees (sent × 10).

    Raises:
        ValueError: Unknown servo, or an angle that is NaN, infinite or overflows int16
            after scaling (±3276.7°).
    """
    s = check_member(Servo, servo, "servo", "use 1 or 2")
    return ServoCommand(s, scale_to_int(angle, 10, INT16, "angle", "degrees"))


def encode_frame(head: bytes, msg_type: int, data: bytes) -> bytes:
    """Wrap ``data`` in a protocol B frame with the given head.

    Raises:
        ValueError: ``msg_type`` out of range or more than 254 data bytes.
    """
    check_int(msg_type, "message type", low=0, high=0xFF)
    length = len(data) + 1
    if length > 0xFF:
        raise ValueError(f"{len(data)} data bytes do not fit a frame (max 254)")
    check = (msg_type + length + sum(data)) & 0xFF
    return head + bytes((msg_type, length)) + data + bytes((check,))


_I16 = struct.Struct("<h")
_IMU = struct.Struct("<9h")
_TWO_I16 = struct.Struct("<hh")
_ID_I16 = struct.Struct("<Bh")


def _request_id(rid: int) -> int:
    return check_int(rid, "request id", low=UINT8[0], high=UINT8[1])


def _pack(msg: BoardMessage | BoardCommand) -> tuple[bytes, int, bytes]:
    """Return ``(head, type, data)`` for any message of this protocol."""
    if isinstance(msg, LedCommand | BuzzerCommand):
        t = BoardType.LED if isinstance(msg, LedCommand) else BoardType.BUZZER
        return HOST_HEAD, t, bytes((SwitchAction(msg.action), _request_id(msg.request_id)))
    if isinstance(msg, MotorPwmCommand):
        return HOST_HEAD, BoardType.MOTOR_PWM, _ID_I16.pack(msg.motor, msg.pwm)
    if isinstance(msg, VelocityCommand):
        return HOST_HEAD, BoardType.VELOCITY, _TWO_I16.pack(msg.linear_milli, msg.angular_milli)
    if isinstance(msg, ServoCommand):
        return HOST_HEAD, BoardType.SERVO, _ID_I16.pack(msg.servo, msg.angle_tenths)
    if isinstance(msg, ImuSample):
        raw = (
            *(round(v * ACCEL_SCALE) for v in msg.accel),
            *(round(v * GYRO_SCALE) for v in msg.gyro),
            *(round(v) for v in msg.mag),
        )
        return DEVICE_HEAD, BoardType.IMU, _IMU.pack(*raw)
    if isinstance(msg, VelocityFeedback):
        return (
            DEVICE_HEAD,
            BoardType.VELOCITY_FEEDBACK,
            _TWO_I16.pack(round(msg.linear * 1000), round(msg.angular * 1000)),
        )
    if isinstance(msg, BatteryReading):
        return DEVICE_HEAD, BoardType.BATTERY, _I16.pack(round(msg.voltage * 100))
    if isinstance(msg, LogMessage):
        return DEVICE_HEAD, BoardType.LOG, msg.text.encode("utf-8")
    if isinstance(msg, LedReply | BuzzerReply):
        t = BoardType.LED if isinstance(msg, LedReply) else BoardType.BUZZER
        return DEVICE_HEAD, t, bytes((_request_id(msg.request_id), int(msg.on)))
    raise TypeError(f"not a protocol B message: {msg!r}")


class BoardEncoder:
    """Turns protocol B messages into frames (host commands with ``AB BC``, board
    messages with ``FE CE``). Stateless: protocol B has no sequence number.

    Examples:
        >>> BoardEncoder().encode(LedCommand(SwitchAction.ON, 1)).hex(" ")
        'ab bc 01 03 01 01 06'
    """

    __slots__ = ()

    def encode(self, msg: BoardMessage | BoardCommand) -> bytes:
        """Encode one message.

        Raises:
            ValueError: A field does not fit its wire type.
        """
        try:
            head, msg_type, data = _pack(msg)
        except (struct.error, OverflowError, UnicodeEncodeError) as exc:
            raise ValueError(f"{msg!r} does not fit the wire format: {exc}") from None
        return encode_frame(head, msg_type, data)


# --- decoding ----------------------------------------------------------------------------

# Parsers follow the core's convention (core.framing.Parser): (buffer, offset of the
# data, data length, timestamp).
_ALLOWED_CONTROL = frozenset(b"\t\n\r")


_build_imu = frozen_builder(ImuSample)
_tuple_new = tuple.__new__


def _parse_imu(b: bytes | bytearray, o: int, n: int, ts: float) -> ImuSample:
    # The hot path (100 Hz): see _fast.py for why it is built this way.
    counts = _IMU.unpack_from(b, o)
    ax, ay, az, gx, gy, gz, mx, my, mz = counts
    return _build_imu(
        _tuple_new(Vector3, (ax / ACCEL_SCALE, ay / ACCEL_SCALE, az / ACCEL_SCALE)),
        _tuple_new(Vector3, (gx / GYRO_SCALE, gy / GYRO_SCALE, gz / GYRO_SCALE)),
        _tuple_new(Vector3, (float(mx), float(my), float(mz))),
        ts,
        _tuple_new(ImuCounts, counts),
    )


def _parse_velocity(b: bytes | bytearray, o: int, n: int, ts: float) -> VelocityFeedback:
    v, w = _TWO_I16.unpack_from(b, o)
    return VelocityFeedback(v / 1000, w / 1000, ts)


def _parse_battery(b: bytes | bytearray, o: int, n: int, ts: float) -> BatteryReading:
    return BatteryReading(_I16.unpack_from(b, o)[0] / 100, ts)


def _parse_log(b: bytes | bytearray, o: int, n: int, ts: float) -> LogMessage | None:
    raw = bytes(b[o : o + n])
    if any(c < 0x20 and c not in _ALLOWED_CONTROL for c in raw) or 0x7F in raw:
        return None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        return None
    return LogMessage(text.rstrip("\r\n"), ts)


def _parse_switch_reply(
    b: bytes | bytearray, o: int, n: int, ts: float
) -> LedReply | BuzzerReply | None:
    state = b[o + 1]
    if state > 1:
        return None
    cls = LedReply if b[o - 2] == BoardType.LED else BuzzerReply
    return cls(b[o], bool(state))


def _parse_switch_cmd(
    b: bytes | bytearray, o: int, n: int, ts: float
) -> LedCommand | BuzzerCommand | None:
    action = b[o]
    if action > 2:
        return None
    cls = LedCommand if b[o - 2] == BoardType.LED else BuzzerCommand
    return cls(SwitchAction(action), b[o + 1])


def _parse_pwm(b: bytes | bytearray, o: int, n: int, ts: float) -> MotorPwmCommand | None:
    motor, pwm = _ID_I16.unpack_from(b, o)
    if not 1 <= motor <= 4:
        return None
    return MotorPwmCommand(Motor(motor), pwm)


def _parse_velocity_cmd(b: bytes | bytearray, o: int, n: int, ts: float) -> VelocityCommand:
    v, w = _TWO_I16.unpack_from(b, o)
    return VelocityCommand(v, w)


def _parse_servo(b: bytes | bytearray, o: int, n: int, ts: float) -> ServoCommand | None:
    servo, angle = _ID_I16.unpack_from(b, o)
    if not 1 <= servo <= 2:
        return None
    return ServoCommand(Servo(servo), angle)


# The value each type's length byte must hold (what it counts: the layout below), or 0
# if the type's length varies.

_DEVICE_FRAMES: FrameTable = {
    BoardType.IMU: (0x13, _parse_imu),
    BoardType.VELOCITY_FEEDBACK: (0x05, _parse_velocity),
    BoardType.BATTERY: (0x03, _parse_battery),
    BoardType.LED: (0x03, _parse_switch_reply),
    BoardType.BUZZER: (0x03, _parse_switch_reply),
    BoardType.LOG: (0, _parse_log),
}

#: The framing as data (core.columns decodes whole captures with it): type at 2, length
#: byte at 3 (the table's value, or any but 0 for variable frames), 4 + length bytes in
#: all, an 8-bit sum from the type to the check, no tail; the alignment rule.
_LAYOUT = FrameLayout(
    type_at=2, length_at=3, header=4, fixed_is_length=True, size_of_length=4, min_length=1,
    sum_from=2, check_size=1, tail=b"", data_at=4, overhead=5, no_head_inside=True,
)  # fmt: skip


def _xyz(prefix: str, at: int, divisor: float) -> tuple[Column, ...]:
    return tuple(
        Column(f"{prefix}.{axis}", at + 2 * i, "h", divisor) for i, axis in enumerate("xyz")
    )


#: The high-rate frames as columns (names as a CSV export flattens the messages).
_DEVICE_COLUMNS: dict[int, tuple[str, tuple[Column, ...]]] = {
    BoardType.IMU: ("ImuSample", (
        *_xyz("accel", 0, ACCEL_SCALE), *_xyz("gyro", 6, GYRO_SCALE), *_xyz("mag", 12, 1),
        *(Column(f"raw.{name}", 2 * i, "h", None) for i, name in enumerate(ImuCounts._fields)),
    )),
    BoardType.VELOCITY_FEEDBACK: ("VelocityFeedback", (
        Column("linear", 0, "h", 1000), Column("angular", 2, "h", 1000),
    )),
    BoardType.BATTERY: ("BatteryReading", (Column("voltage", 0, "h", 100),)),
}  # fmt: skip

_HOST_FRAMES: FrameTable = {
    BoardType.LED: (0x03, _parse_switch_cmd),
    BoardType.BUZZER: (0x03, _parse_switch_cmd),
    BoardType.MOTOR_PWM: (0x04, _parse_pwm),
    BoardType.VELOCITY: (0x05, _parse_velocity_cmd),
    BoardType.SERVO: (0x04, _parse_servo),
}

_M = TypeVar("_M")

# The optional compiled fast path (chassis_sdk/core/compiled.py), or None: the pure code.
_compiled = compiled.load("chassis_sdk.devices.board._compiled")


class _ProtocolBDecoder(FrameDecoder[_M]):
    """Framing for protocol B, parametrised by head and the table of accepted types.

    Why a frame that checks out can still be refused
    -------------------------------------------------
    The check is one byte, so one corrupted candidate in 256 passes it. On a noisy
    line many corrupted candidates are *shifted*. A byte lost inside a frame makes it
    run on into the next frame, whose head then lies inside the candidate: if the
    checksum happens to pass, the result is a phantom made of the wrong bytes (an IMU
    sample reading 0 g) and, worse, the good frame after it loses its head and is lost
    too. So a candidate that checks out but has a plausible frame start inside it (the
    head, a known type and that type's length) is refused as misaligned (counted in
    ``stats.misaligned_frames``); scanning resumes inside it, which recovers the good
    frame. A good frame is refused only if its own data spells a plausible head,
    about one frame in ten million.

    The decision uses only the candidate's bytes and up to three after it, never
    where a chunk happens to end, so the output still does not depend on how the port
    split the bytes: a candidate whose last bytes could begin a head (it ends in
    ``FE`` or ``FE CE ...``, one frame in 256) waits for up to three more bytes.

    What no framing rule can catch (measured in ``benchmarks/phantoms.py``): a byte
    *inserted* into a frame leaves a candidate that ends one byte early and looks
    exactly like a good frame followed by line noise, and two bit flips that cancel
    in the 8-bit sum leave a frame of the right shape. Refusing candidates followed
    by stray bytes would remove the first kind too, but it loses good frames in
    proportion to the noise (0.3 % to 1.9 % at 2 % noise), so it is not done.

    Which ``feed`` runs
    -------------------
    With the compiled fast path built, `BoardDecoder` and `BoardCommandDecoder` feed
    through it: the same messages, stats and buffer as the pure loop. It reads the
    head, the table and ``check_alignment`` from the decoder at every call, and hands
    the call to the pure loop if ``_try_frame`` or ``_swallows_a_head`` was changed on
    the class or the instance. A subclass gets the pure `FrameDecoder.feed` back (see
    ``__init_subclass__``): it may override ``_try_frame``, ``_table`` or a parser,
    which only the pure loop calls.
    """

    _table: ClassVar[FrameTable] = {}
    layout = _LAYOUT
    #: Refuse checked-out candidates that what follows shows to be misaligned.
    check_alignment: ClassVar[bool] = True

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """Give a subclass that would inherit the compiled ``feed`` the pure one.

        The compiled ``feed`` mirrors this module's own two decoders, not what a
        subclass may change (a ``_try_frame``, a parser, the table's meaning): only the
        pure loop calls a subclass's overrides. A ``feed`` the subclass (or a base of
        its own) defines is kept. The compiled ``feed`` also checks the exact type, so
        a ``super().feed()`` from a subclass runs the pure loop too.
        """
        super().__init_subclass__(**kwargs)
        if _compiled is not None and cls.feed is _compiled.feed:
            cls.feed = FrameDecoder.feed  # type: ignore[method-assign]

    def _try_frame(
        self, buf: bytes | bytearray, start: int, end: int, out: list[_M], ts: float
    ) -> int:
        if end - start < 4:
            return NEED_DATA
        msg_type = buf[start + 2]
        entry = self._table.get(msg_type)
        if entry is None:
            return INVALID
        expected, parser = entry
        length = buf[start + 3]
        if length != expected if expected else length == 0:
            return INVALID
        stop = start + 4 + length
        if stop > end:
            return NEED_DATA
        if (msg_type + length + byte_sum(buf[start + 4 : stop - 1], 0)) & 0xFF != buf[stop - 1]:
            self.stats.checksum_errors += 1
            return INVALID
        msg = parser(buf, start + 4, length - 1, ts)
        if msg is None:
            self.stats.malformed_frames += 1
            return INVALID
        head = self._head
        # The usual frame has no head byte pair inside and is not cut after an FE:
        # one search, no call.
        if self.check_alignment and (
            buf.find(head, start + 1, stop + 1) >= 0 or (stop >= end and buf[stop - 1] == head[0])
        ):
            swallowed = self._swallows_a_head(buf, start, stop, end)
            if swallowed is None:
                return NEED_DATA
            if swallowed:
                self.stats.misaligned_frames += 1
                return INVALID
        out.append(msg)
        return stop - start

    def _swallows_a_head(
        self, buf: bytes | bytearray, start: int, stop: int, end: int
    ) -> bool | None:
        """Whether a plausible frame starts inside ``buf[start:stop]``; ``None`` if a
        start within its last three bytes cannot be told until more bytes arrive."""
        head = self._head
        table = self._table
        # Whole heads starting inside (one search for the common case: none at all)...
        i = buf.find(head, start + 1, stop + 1)
        while i >= 0:
            if i + 2 >= end:
                return None
            entry = table.get(buf[i + 2])
            if entry is not None:
                if i + 3 >= end:
                    return None
                expected, length = entry[0], buf[i + 3]
                if length == expected if expected else length != 0:
                    return True
            i = buf.find(head, i + 1, stop + 1)
        # ...and a head whose first byte is the candidate's last, when the next byte
        # has not arrived yet.
        if stop >= end and buf[stop - 1] == head[0]:
            return None
        return False


class BoardDecoder(_ProtocolBDecoder[BoardMessage]):
    """Sans-IO decoder of everything the board sends (0x11, 0x12, 0x13, 0xF1, replies).

    Examples:
        >>> BoardDecoder().feed(bytes.fromhex("FE CE 01 03 01 01 06"))
        [LedReply(request_id=1, on=True)]
    """

    _head = DEVICE_HEAD
    _table = _DEVICE_FRAMES
    columns = _DEVICE_COLUMNS


class BoardCommandDecoder(_ProtocolBDecoder[BoardCommand]):
    """Sans-IO decoder of what the host sends to the board (simulator, captures)."""

    _head = HOST_HEAD
    _table = _HOST_FRAMES


if _compiled is not None:
    # The compiled feed for this module's own two decoders only, mirroring the pure objects
    # it is given here (subclasses: see _ProtocolBDecoder.__init_subclass__).
    _compiled.bind(
        decoder_cls=BoardDecoder,
        command_cls=BoardCommandDecoder,
        pure_feed=FrameDecoder.feed,
        try_frame=_ProtocolBDecoder._try_frame,
        swallows_a_head=_ProtocolBDecoder._swallows_a_head,
        parse_imu=_parse_imu,
        imu_cls=ImuSample,
        vector_cls=Vector3,
        counts_cls=ImuCounts,
        stats_cls=DecoderStats,
        accel_scale=ACCEL_SCALE,
        gyro_scale=GYRO_SCALE,
    )
    BoardDecoder.feed = _compiled.feed  # type: ignore[method-assign]
    BoardCommandDecoder.feed = _compiled.feed  # type: ignore[method-assign]
