"""Protocol B codec: vendor vectors, round trips, prefixes, malformed input, properties,
and the recovery rate of good frames in a stream of noise."""

from __future__ import annotations

import math
import random
import struct

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chassis_sdk.devices.board.protocol import (
    DEVICE_HEAD,
    encode_frame,
    motor_pwm_command,
    servo_command,
    velocity_command,
)
from chassis_sdk.protocol import (
    BatteryReading,
    BoardCommandDecoder,
    BoardDecoder,
    BoardEncoder,
    BuzzerCommand,
    BuzzerReply,
    ImuSample,
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

pytestmark = pytest.mark.codec


def h(text: str) -> bytes:
    return bytes.fromhex(text.replace("0x", "").replace(",", " "))


ENC = BoardEncoder()

# --- vendor vectors -----------------------------------------------------------------------------

HOST_VECTORS = [
    pytest.param(LedCommand(SwitchAction.OFF, 1), "AB BC 01 03 00 01 05", id="led-off"),
    pytest.param(LedCommand(SwitchAction.ON, 1), "AB BC 01 03 01 01 06", id="led-on"),
    pytest.param(LedCommand(SwitchAction.READ, 1), "AB BC 01 03 02 01 07", id="led-read"),
    pytest.param(BuzzerCommand(SwitchAction.OFF, 1), "AB BC 02 03 00 01 06", id="buzzer-off"),
    pytest.param(BuzzerCommand(SwitchAction.ON, 1), "AB BC 02 03 01 01 07", id="buzzer-on"),
    pytest.param(BuzzerCommand(SwitchAction.READ, 1), "AB BC 02 03 02 01 08", id="buzzer-read"),
    pytest.param(MotorPwmCommand(Motor.REAR_LEFT, 4000), "AB BC 21 04 01 A0 0F D5", id="pwm"),
    pytest.param(VelocityCommand(200, 0), "AB BC 22 05 C8 00 00 00 EF", id="velocity-0.2"),
    pytest.param(VelocityCommand(500, 0), "ab bc 22 05 f4 01 00 00 1c", id="velocity-0.5"),
    pytest.param(VelocityCommand(500, 500), "ab bc 22 05 f4 01 f4 01 11", id="velocity-0.5-0.5"),
    pytest.param(VelocityCommand(800, 0), "ab bc 22 05 20 03 00 00 4a", id="velocity-0.8"),
    # 0x31 has no example (placeholders); len = 0x04 by the rule, 30 degrees = 300.
    pytest.param(ServoCommand(Servo.FIRST, 300), "AB BC 31 04 01 2C 01 63", id="servo-30deg"),
]

DEVICE_VECTORS = [
    pytest.param("FE CE 01 03 01 01 06", LedReply(1, True), id="led-reply"),
    pytest.param("FE CE 02 03 01 01 07", BuzzerReply(1, True), id="buzzer-reply"),
]


@pytest.mark.parametrize(("command", "wire"), HOST_VECTORS)
def test_host_vectors_encode_exactly(command: object, wire: str) -> None:
    assert ENC.encode(command) == h(wire)  # type: ignore[arg-type]


@pytest.mark.parametrize(("command", "wire"), HOST_VECTORS)
def test_host_vectors_decode(command: object, wire: str) -> None:
    assert BoardCommandDecoder().feed(h(wire)) == [command]


@pytest.mark.parametrize(("wire", "msg"), DEVICE_VECTORS)
def test_device_vectors_decode(wire: str, msg: object) -> None:
    assert BoardDecoder().feed(h(wire)) == [msg]


def test_doc_velocity_header_row_with_wrong_checksum_is_rejected() -> None:
    dec = BoardCommandDecoder()
    assert dec.feed(h("AB BC 22 05 01 22 A0 0F D5")) == []
    assert dec.stats.checksum_errors == 1
    assert dec.feed(h("AB BC 22 05 01 22 A0 0F F9")) == [VelocityCommand(0x2201, 0x0FA0)]


def test_si_builders_scale_and_check() -> None:
    assert velocity_command(0.5, 0.5) == VelocityCommand(500, 500)
    assert servo_command(2, 22.5) == ServoCommand(Servo.SECOND, 225)
    assert motor_pwm_command(Motor.FRONT_RIGHT, -4000) == MotorPwmCommand(Motor.FRONT_RIGHT, -4000)


@pytest.mark.parametrize(
    ("build", "match"),
    [
        pytest.param(lambda: velocity_command(math.nan, 0), "linear", id="nan-linear"),
        pytest.param(lambda: velocity_command(0, math.inf), "angular", id="inf-angular"),
        pytest.param(lambda: velocity_command(32.768, 0), "out of range", id="overflow-linear"),
        pytest.param(lambda: velocity_command(0, -32.769), "out of range", id="overflow-angular"),
        pytest.param(lambda: motor_pwm_command(0, 10), "unknown motor", id="motor-0"),
        pytest.param(lambda: motor_pwm_command(5, 10), "unknown motor", id="motor-5"),
        pytest.param(lambda: motor_pwm_command(1, 40000), "out of range", id="pwm-overflow"),
        pytest.param(lambda: servo_command(3, 10), "unknown servo", id="servo-3"),
        pytest.param(lambda: servo_command(1, 3276.8), "out of range", id="servo-overflow"),
        pytest.param(lambda: servo_command(1, math.nan), "finite", id="servo-nan"),
    ],
)
def test_builders_reject_bad_arguments(build: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        build()  # type: ignore[operator]


def test_builders_refuse_a_wrong_type_with_a_type_error() -> None:
    with pytest.raises(TypeError, match="pwm must be an integer"):
        motor_pwm_command(1, 1.5)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="unknown servo '1' \\(not an integer\\)"):
        servo_command("1", 10)  # type: ignore[arg-type]


# --- round trips --------------------------------------------------------------------------------

DEVICE_MESSAGES: list[object] = [
    ImuSample(
        Vector3(-1 / 164, 0.0, 164 / 164), Vector3(16 / 16.4, -33 / 16.4, 0.0), Vector3(300.0, -300.0, -420.0)
    ),
    ImuSample(
        Vector3(-32768 / 164, 32767 / 164, 0.0), Vector3(-32768 / 16.4, 32767 / 16.4, 0.0), Vector3(-32768.0, 32767.0, 0.0)
    ),
    VelocityFeedback(0.3, -0.25),
    VelocityFeedback(-32.768, 32.767),
    BatteryReading(12.34),
    LogMessage("servo 1 -> 30.0 deg"),
    LogMessage(""),
    LogMessage("ünïcode\ttext"),
    LedReply(0, False),
    LedReply(255, True),
    BuzzerReply(17, True),
]  # fmt: skip
HOST_COMMANDS: list[object] = [
    LedCommand(SwitchAction.READ, 255),
    BuzzerCommand(SwitchAction.ON, 0),
    MotorPwmCommand(Motor.FRONT_LEFT, -32768),
    VelocityCommand(-32768, 32767),
    ServoCommand(Servo.SECOND, -900),
]


def _approx_equal(a: object, b: object) -> bool:
    if isinstance(a, ImuSample) and isinstance(b, ImuSample):
        return all(
            x == pytest.approx(y, abs=1e-9)
            for va, vb in zip((a.accel, a.gyro, a.mag), (b.accel, b.gyro, b.mag), strict=True)
            for x, y in zip(va, vb, strict=True)
        )
    return a == b


@pytest.mark.parametrize("msg", DEVICE_MESSAGES, ids=lambda m: type(m).__name__)
def test_device_message_round_trip(msg: object) -> None:
    (back,) = BoardDecoder().feed(ENC.encode(msg))  # type: ignore[arg-type]
    assert _approx_equal(back, msg)


@pytest.mark.parametrize("msg", HOST_COMMANDS, ids=lambda m: type(m).__name__)
def test_host_command_round_trip(msg: object) -> None:
    assert BoardCommandDecoder().feed(ENC.encode(msg)) == [msg]  # type: ignore[arg-type]


ALL_FRAMES = [ENC.encode(m) for m in DEVICE_MESSAGES]  # type: ignore[arg-type]


@pytest.mark.parametrize("frame", ALL_FRAMES, ids=lambda f: f"0x{f[2]:02X}-{len(f)}")
def test_every_proper_prefix_needs_more_data(frame: bytes) -> None:
    for cut in range(len(frame)):
        dec = BoardDecoder()
        assert dec.feed(frame[:cut]) == []
        assert dec.stats.bytes_dropped == 0
        assert len(dec.feed(frame[cut:])) == 1


def test_byte_at_a_time_feeding() -> None:
    stream = b"".join(ALL_FRAMES)
    dec = BoardDecoder()
    out: list[object] = []
    for i in range(len(stream)):
        out += dec.feed(stream[i : i + 1], timestamp=0.0)
    assert len(out) == len(DEVICE_MESSAGES)
    assert all(_approx_equal(a, b) for a, b in zip(out, DEVICE_MESSAGES, strict=True))


def test_timestamps_are_stored() -> None:
    (imu,) = BoardDecoder().feed(ALL_FRAMES[0], timestamp=3.25)
    assert isinstance(imu, ImuSample)
    assert imu.timestamp == 3.25


# --- malformed input ---------------------------------------------------------------------------

GOOD = ENC.encode(BatteryReading(11.1))
GOOD_MSG = BatteryReading(11.1)


def _with(frame: bytes, index: int, value: int) -> bytes:
    b = bytearray(frame)
    b[index] = value
    return bytes(b)


MALFORMED = [
    pytest.param(b"\x01\x02\x03", 0, 0, id="garbage"),
    pytest.param(_with(GOOD, 6, GOOD[6] ^ 0x55), 1, 0, id="bad-checksum"),
    pytest.param(_with(GOOD, 2, 0x77), 0, 0, id="unknown-type"),
    pytest.param(_with(GOOD, 3, 0x09), 0, 0, id="wrong-length-for-type"),
    pytest.param(b"\xfe\xce\xf1\x00", 0, 0, id="log-length-zero"),
    pytest.param(encode_frame(DEVICE_HEAD, 0xF1, b"a\x01b"), 0, 1, id="log-control-bytes"),
    pytest.param(encode_frame(DEVICE_HEAD, 0xF1, b"\xff\xfe"), 0, 1, id="log-not-utf8"),
    pytest.param(encode_frame(DEVICE_HEAD, 0x01, b"\x05\x07"), 0, 1, id="led-state-not-bool"),
    pytest.param(b"\xfe\xfe", 0, 0, id="doubled-head-byte"),
]  # fmt: skip


@pytest.mark.parametrize(("junk", "checksum_errors", "malformed"), MALFORMED)
def test_malformed_input_is_skipped_and_next_frame_survives(
    junk: bytes, checksum_errors: int, malformed: int
) -> None:
    dec = BoardDecoder()
    assert dec.feed(junk + GOOD) == [GOOD_MSG]
    assert dec.stats.checksum_errors == checksum_errors
    assert dec.stats.malformed_frames == malformed
    assert dec.stats.bytes_dropped == len(junk)


def test_false_log_head_claiming_many_bytes_does_not_swallow_frames() -> None:
    bogus = b"\xfe\xce\xf1\xff"  # claims 254 bytes of log text
    stream = bogus + GOOD * 70
    out = BoardDecoder().feed(stream)
    assert out == [GOOD_MSG] * 70


# --- noise recovery ------------------------------------------------------------------------


def _unique_message(i: int, rng: random.Random) -> object:
    """A message that carries ``i``, so each good frame can be found in the output."""
    kind = i % 4
    if kind == 0:
        return ImuSample(
            Vector3(rng.randint(-500, 500) / 164, 0.0, 1.0),
            Vector3(0.0, 0.0, rng.randint(-99, 99) / 16.4),
            Vector3(float(i % 32768), -3.0, -420.0),
        )
    if kind == 1:
        return VelocityFeedback((i % 32768) / 1000, rng.randint(-999, 999) / 1000)
    if kind == 2:
        return BatteryReading((i % 32768) / 100)
    return LogMessage(f"event {i}")


def _noisy_stream(rng: random.Random, n_frames: int) -> tuple[bytes, list[object]]:
    """Good frames with noise between them: random bytes, bare heads, and truncated or
    corrupted frames (the realistic kinds of noise on a serial line)."""
    pool = DEVICE_MESSAGES
    stream = bytearray()
    sent: list[object] = []
    for i in range(n_frames):
        kind = rng.random()
        if kind < 0.4:
            stream += rng.randbytes(rng.randint(0, 24))
        elif kind < 0.6:
            stream += b"\xfe\xce" + rng.randbytes(rng.randint(0, 3))
        elif kind < 0.8:
            cut = ENC.encode(rng.choice(pool))  # type: ignore[arg-type]
            stream += cut[: rng.randint(1, len(cut) - 1)]
        else:
            bad = bytearray(ENC.encode(rng.choice(pool)))  # type: ignore[arg-type]
            bad[rng.randrange(2, len(bad))] ^= 1 << rng.randrange(8)
            stream += bad
        msg = _unique_message(i, rng)
        sent.append(msg)
        stream += ENC.encode(msg)  # type: ignore[arg-type]
    return bytes(stream), sent


def recovery_rate(seed: int, n_frames: int = 5000) -> float:
    """Share of good frames decoded from a noisy stream fed in random chunks."""
    rng = random.Random(seed)
    stream, sent = _noisy_stream(rng, n_frames)
    dec = BoardDecoder()
    out: list[object] = []
    pos = 0
    while pos < len(stream):
        step = rng.randint(1, 64)
        out += dec.feed(stream[pos : pos + step])
        pos += step
    received = {repr(m) for m in out}
    return sum(repr(m) in received for m in sent) / len(sent)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_recovers_at_least_99_5_percent_of_good_frames_from_noise(seed: int) -> None:
    rate = recovery_rate(seed)
    assert rate >= 0.995, f"recovered {rate:.4%}"


# --- properties ---------------------------------------------------------------------------------


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=600), st.lists(st.integers(1, 50), max_size=30))
def test_decoder_never_raises_and_bounds_its_buffer(data: bytes, cuts: list[int]) -> None:
    dec = BoardDecoder()
    pos = 0
    for cut in cuts:
        dec.feed(data[pos : pos + cut])
        pos += cut
    dec.feed(data[pos:])
    assert dec.buffered <= 259
    assert dec.stats.bytes_received == len(data)


@settings(max_examples=300, deadline=None)
@given(
    idx=st.lists(st.integers(0, len(DEVICE_MESSAGES) - 1), min_size=1, max_size=10),
    cuts=st.lists(st.integers(1, 40), max_size=30),
)
def test_random_chunking_yields_every_frame(idx: list[int], cuts: list[int]) -> None:
    msgs = [DEVICE_MESSAGES[i] for i in idx]
    stream = b"".join(ENC.encode(m) for m in msgs)  # type: ignore[arg-type]
    dec = BoardDecoder()
    out: list[object] = []
    pos = 0
    for cut in cuts:
        out += dec.feed(stream[pos : pos + cut])
        pos += cut
    out += dec.feed(stream[pos:])
    assert len(out) == len(msgs)
    assert all(_approx_equal(a, b) for a, b in zip(out, msgs, strict=True))


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_command_decoder_never_raises(data: bytes) -> None:
    BoardCommandDecoder().feed(data)


# --- misaligned candidates (phantoms) -----------------------------------------------------------


def _phantom_swallowing(next_frame: bytes) -> bytes:
    """An IMU candidate that checks out although its last byte is ``next_frame``'s
    first: what a byte lost inside a frame leaves, 1 time in 256."""
    data = bytearray(18)
    data[0] = (0xFE - 0x11 - 0x13) & 0xFF  # makes the one-byte check come out as 0xFE
    assert next_frame[0] == 0xFE
    return DEVICE_HEAD + bytes((0x11, 0x13)) + bytes(data)  # + next_frame's 0xFE


class _FramingOnly(BoardDecoder):
    check_alignment = False


def test_a_candidate_that_swallows_the_next_frames_head_is_refused() -> None:
    good = ENC.encode(VelocityFeedback(0.25, -0.5))
    stream = _phantom_swallowing(good) + good
    # Framing alone takes the phantom (all zeros: an IMU reading 0 g) and loses the
    # good frame whose head it swallowed.
    plain = _FramingOnly().feed(stream)
    assert [type(m) for m in plain] == [ImuSample]
    for feed in (
        lambda d: d.feed(stream),
        lambda d: [m for b in stream for m in d.feed(bytes((b,)))],
    ):
        dec = BoardDecoder()
        assert feed(dec) == [VelocityFeedback(0.25, -0.5)]
        assert dec.stats.misaligned_frames == 1


def test_a_frame_that_could_end_in_a_head_waits_for_three_more_bytes() -> None:
    # Mag z = -420 (5C FE) makes the data end in 0xFE; pick the x value so that the
    # check byte is 0xCE too: the frame ends in FE CE, which may start a frame.
    for x in range(-32768, 32768):
        frame = ENC.encode(
            ImuSample(Vector3(x / 164.0, 0, 0), Vector3(0, 0, 0), Vector3(300, -300, -420))
        )
        if frame.endswith(b"\xfe\xce"):
            break
    dec = BoardDecoder()
    assert dec.feed(frame) == []  # undecided: FE CE could be a frame's start
    nxt = ENC.encode(VelocityFeedback(0.25, -0.5))
    assert len(dec.feed(nxt[:1])) == 1  # 0xFE is no type: it was this frame's end
    assert dec.feed(nxt[1:]) == [VelocityFeedback(0.25, -0.5)]
    # Followed by a plausible type and length instead, it would be refused: the one
    # shape in which a good frame is lost (its data must spell FE CE 12 05 itself).
    dec = BoardDecoder()
    assert dec.feed(frame + b"\x12\x05") == []
    assert dec.stats.misaligned_frames == 1


def _board_stream(rng: random.Random, n: int) -> list[bytes]:
    frames = []
    for i in range(n):
        accel = Vector3(1 + rng.randrange(-20, 20) / 164, rng.randrange(-30, 30) / 164, 0.0)
        frames.append(
            ENC.encode(ImuSample(accel, Vector3(1.0, -2.0, 0.5), Vector3(300, -300, -420)))
        )
        if i % 5 == 0:
            frames.append(ENC.encode(VelocityFeedback(0.25, rng.randrange(-500, 500) / 1000)))
    return frames


def test_lost_bytes_make_far_fewer_phantoms_and_no_fewer_good_frames() -> None:
    """Deterministic: a fixed stream, fixed damage, fixed chunking."""
    rng = random.Random(5)
    frames = _board_stream(rng, 20_000)
    sent = {repr(m) for m in _FramingOnly().feed(b"".join(frames))}
    damaged = bytearray()
    for frame in frames:
        damaged += bytes(b for b in frame if rng.random() >= 0.01)  # 1 % of bytes lost
    results = {}
    for name, factory in (("plain", _FramingOnly), ("aligned", BoardDecoder)):
        dec = factory()
        out = [repr(m) for m in dec.feed(bytes(damaged))]
        phantoms = sum(m not in sent for m in out)
        results[name] = (phantoms, len(set(out) & sent), dec.stats.misaligned_frames)
    plain, aligned = results["plain"], results["aligned"]
    assert plain[0] >= 10  # the damage does make phantoms through framing alone
    assert aligned[0] * 5 <= plain[0]  # at least 80 % fewer
    assert aligned[1] >= plain[1]  # and no good frame lost for it
    assert aligned[2] >= plain[0] - aligned[0]


# --- IMU units: the document's scale, the raw counts, another scale, SI -----------------------


def test_imu_keeps_the_raw_counts_and_offers_si_values() -> None:
    from chassis_sdk.protocol import ImuCounts, ImuScale

    frame = encode_frame(
        DEVICE_HEAD, 0x11, struct.pack("<9h", 164, -328, 16384, 164, 0, -1640, 300, 0, -420)
    )
    (imu,) = BoardDecoder().feed(frame)
    assert isinstance(imu, ImuSample)
    assert imu.raw == ImuCounts(164, -328, 16384, 164, 0, -1640, 300, 0, -420)
    assert imu.accel == Vector3(1.0, -2.0, 16384 / 164)  # the document's 164 per g
    assert imu.gyro == pytest.approx(Vector3(10.0, 0.0, -100.0))  # 16.4 per deg/s
    assert imu == ImuSample(imu.accel, imu.gyro, imu.mag, imu.timestamp)  # raw is not compared
    assert imu.linear_acceleration.x == pytest.approx(9.80665)
    assert imu.angular_velocity.z == pytest.approx(math.radians(-100.0))
    other = imu.scaled(ImuScale(accel=16384.0, gyro=65.5))
    assert other.accel.z == pytest.approx(1.0)
    assert other.gyro.x == pytest.approx(164 / 65.5)
    assert other.raw == imu.raw
    with pytest.raises(ValueError, match="no raw counts"):
        ImuSample(Vector3(0, 0, 1), Vector3(0, 0, 0), Vector3(0, 0, 0)).scaled(ImuScale())
    with pytest.raises(ValueError, match="imu scale accel"):
        ImuScale(accel=0.0)
