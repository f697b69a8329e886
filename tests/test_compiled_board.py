"""Protocol B's compiled fast path (``chassis_sdk/devices/board/_compiled.pyx``) against
the pure code, which is the reference: a differential fuzz of random streams (every
frame type, noise, false heads, corruption, truncation, shifted frames, chunks of 1-4096
bytes, fed as bytes, bytearray and memoryview) compared after every chunk (messages,
their types and exact field values, stats, buffer); subclasses and changed decoders on
the pure path; ``CHASSIS_SDK_PURE=1``; and no reference leak over a million and a half
frames.

The pure side is ``FrameDecoder.feed`` called explicitly on a second decoder.
"""

from __future__ import annotations

import array
import dataclasses
import enum
import gc
import os
import random
import struct
import subprocess
import sys
from collections.abc import Callable
from typing import Any, ClassVar

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from chassis_sdk.core import compiled
from chassis_sdk.core.framing import DecoderStats, FrameDecoder, FrameTable
from chassis_sdk.devices.board import protocol
from chassis_sdk.devices.board.messages import VelocityFeedback
from chassis_sdk.devices.board.profile import COMMAND_EXAMPLES, EXAMPLES
from chassis_sdk.devices.board.protocol import (
    DEVICE_HEAD,
    HOST_HEAD,
    BoardCommandDecoder,
    BoardDecoder,
    encode_frame,
)

pytestmark = pytest.mark.codec

if protocol._compiled is None:
    pytest.skip(
        f"protocol B's compiled fast path is not active ({compiled.status()}): build it with "
        "`python setup.py build_ext --inplace`, and unset CHASSIS_SDK_PURE",
        allow_module_level=True,
    )

COMPILED_FEED: Any = protocol._compiled.feed
COMPILED_BIND: Any = protocol._compiled.bind
pure_feed: Any = FrameDecoder.feed

Decoder = BoardDecoder | BoardCommandDecoder


def shape(value: object) -> object:
    """``value`` as nested tuples that tell apart whatever ``==`` does not: types, enum
    members, exact floats (-0.0 and 0.0), fields left out of equality (``raw``)."""
    if isinstance(value, enum.Enum):
        return (type(value), "member", id(value))
    if isinstance(value, float):
        return (type(value), value.hex())
    if isinstance(value, int | str | bytes | type(None)):
        return (type(value), value)
    if isinstance(value, tuple):
        return (type(value), tuple(shape(v) for v in value))
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return (
            type(value),
            tuple(shape(getattr(value, f.name)) for f in dataclasses.fields(value)),
        )
    raise AssertionError(f"unexpected value in a message: {value!r}")


class Pair:
    """The same decoder class twice: one fed through the compiled path, one through the
    pure loop; `feed` feeds both and checks that they agree."""

    def __init__(self, make: Callable[[], Decoder]) -> None:
        self.fast: Any = make()
        self.pure: Any = make()
        assert type(self.fast).feed is COMPILED_FEED

    def feed(self, data: bytes | bytearray | memoryview, ts: object = 0.0) -> list[Any]:
        got: list[Any] = self.fast.feed(data, ts)
        want: list[Any] = pure_feed(self.pure, data, ts)
        assert got == want
        assert [type(m) for m in got] == [type(m) for m in want]
        assert [shape(m) for m in got] == [shape(m) for m in want]
        assert self.fast.stats.as_dict() == self.pure.stats.as_dict()
        assert type(self.fast._buf) is bytearray
        assert bytes(self.fast._buf) == bytes(self.pure._buf)
        return got


# --- streams ----------------------------------------------------------------------------------

i16 = st.integers(-32768, 32767)
u8 = st.integers(0, 255)


def _frame(head: bytes, msg_type: int, data: bytes) -> bytes:
    return encode_frame(head, msg_type, data)


@st.composite
def device_frames(draw: st.DrawFn, head: bytes = DEVICE_HEAD) -> bytes:
    """A frame of any type the board sends, with any content (malformed ones too)."""
    kind = draw(st.sampled_from(["imu", "imu", "imu", "velocity", "battery", "log", "switch"]))
    if kind == "imu":
        counts = draw(st.lists(i16, min_size=9, max_size=9))
        return _frame(head, 0x11, struct.pack("<9h", *counts))
    if kind == "velocity":
        return _frame(head, 0x12, struct.pack("<hh", draw(i16), draw(i16)))
    if kind == "battery":
        return _frame(head, 0x13, struct.pack("<h", draw(i16)))
    if kind == "log":
        text = draw(st.one_of(st.binary(max_size=40), st.text(max_size=30).map(str.encode)))
        return _frame(head, 0xF1, text[:254])
    return _frame(head, draw(st.sampled_from([1, 2])), bytes((draw(u8), draw(st.integers(0, 3)))))


@st.composite
def command_frames(draw: st.DrawFn, head: bytes = HOST_HEAD) -> bytes:
    """A frame of any type the host sends, with any content (malformed ones too)."""
    kind = draw(st.sampled_from(["switch", "pwm", "velocity", "servo"]))
    if kind == "switch":
        return _frame(
            head, draw(st.sampled_from([1, 2])), bytes((draw(st.integers(0, 4)), draw(u8)))
        )
    if kind == "pwm":
        return _frame(head, 0x21, struct.pack("<Bh", draw(st.integers(0, 6)), draw(i16)))
    if kind == "velocity":
        return _frame(head, 0x22, struct.pack("<hh", draw(i16), draw(i16)))
    return _frame(head, 0x31, struct.pack("<Bh", draw(st.integers(0, 4)), draw(i16)))


@st.composite
def damaged(draw: st.DrawFn, frames: st.SearchStrategy[bytes]) -> bytes:
    """A frame flipped, cut, shifted (a byte lost or inserted) or with its length changed."""
    frame = bytearray(draw(frames))
    how = draw(st.sampled_from(["flip", "truncate", "delete", "insert", "length", "check"]))
    at = draw(st.integers(0, len(frame) - 1))
    if how == "flip":
        frame[at] ^= 1 << draw(st.integers(0, 7))
    elif how == "truncate":
        del frame[at:]
    elif how == "delete":
        del frame[at]
    elif how == "insert":
        frame.insert(at, draw(u8))
    elif how == "length":
        frame[3] = draw(u8)
    else:
        frame[-1] = draw(u8)
    return bytes(frame)


def ending_in(frame: bytes, last: int) -> bytes:
    """``frame`` with its first data byte changed so that its check byte is ``last``."""
    if len(frame) < 6:
        return frame
    out = bytearray(frame)
    out[4] = (out[4] + last - out[-1]) & 0xFF
    out[-1] = last
    return bytes(out)


def pieces(head: bytes, good: st.SearchStrategy[bytes]) -> st.SearchStrategy[bytes]:
    """What a line carries: good frames (the vendor examples too), noise, false heads
    (a head and anything, or a head with a known type and length and wrong content),
    damaged frames, lone head bytes, the other direction's frames, good frames ending
    in the head's first byte and what may follow them (the alignment rule's waits)."""
    examples = [f for f, _ in EXAMPLES] + [f for f, _ in COMMAND_EXAMPLES]
    other = command_frames() if head == DEVICE_HEAD else device_frames()
    after_head = st.sampled_from([0x01, 0x11, 0x13, 0x21, 0x22, 0x33]).flatmap(
        lambda t: st.binary(max_size=2).map(lambda rest: head[1:] + bytes((t,)) + rest)
    )
    return st.one_of(
        good,
        good,
        good,
        good.map(lambda f: ending_in(f, head[0])),
        after_head,
        st.sampled_from(examples),
        st.binary(min_size=1, max_size=64),
        st.binary(max_size=24).map(lambda tail: head + tail),
        st.tuples(st.sampled_from([1, 2, 0x11, 0x12, 0x13, 0x21, 0x22, 0x31, 0xF1]), u8).flatmap(
            lambda tl: st.binary(min_size=tl[1], max_size=tl[1]).map(
                lambda rest: head + bytes(tl) + rest
            )
        ),
        damaged(good),
        st.sampled_from([head[:1], head, head + head[:1], head[:1] * 3]),
        other,
    )


def streams(head: bytes, good: st.SearchStrategy[bytes]) -> st.SearchStrategy[bytes]:
    return st.lists(pieces(head, good), max_size=40).map(b"".join)


def as_style(chunk: bytes, style: int) -> bytes | bytearray | memoryview:
    if style == 1:
        return bytearray(chunk)
    if style == 2:
        return memoryview(chunk)
    if style == 3:
        return memoryview(b"\x00" + chunk + b"\x00")[1:-1]  # a view into a larger buffer
    return chunk


chunking = st.lists(
    st.tuples(st.one_of(st.integers(1, 8), st.integers(1, 4096)), st.integers(0, 3)),
    min_size=1,
    max_size=64,
)
timestamps = st.one_of(st.just(0.0), st.floats(allow_nan=False), st.integers(0, 10**6))


def run(pair: Pair, stream: bytes, cuts: list[tuple[int, int]], ts: object) -> None:
    pos = i = 0
    while pos < len(stream):
        size, style = cuts[i % len(cuts)]
        pair.feed(as_style(stream[pos : pos + size], style), ts)
        pos += size
        i += 1


@settings(max_examples=400, deadline=None)
@given(stream=streams(DEVICE_HEAD, device_frames()), cuts=chunking, ts=timestamps)
def test_board_decoder_paths_agree_on_random_streams(
    stream: bytes, cuts: list[tuple[int, int]], ts: object
) -> None:
    run(Pair(BoardDecoder), stream, cuts, ts)


@settings(max_examples=250, deadline=None)
@given(stream=streams(HOST_HEAD, command_frames()), cuts=chunking, ts=timestamps)
def test_command_decoder_paths_agree_on_random_streams(
    stream: bytes, cuts: list[tuple[int, int]], ts: object
) -> None:
    run(Pair(BoardCommandDecoder), stream, cuts, ts)


@settings(max_examples=150, deadline=None)
@given(stream=streams(DEVICE_HEAD, device_frames()), cuts=chunking)
def test_paths_agree_without_the_alignment_rule(stream: bytes, cuts: list[tuple[int, int]]) -> None:
    pair = Pair(BoardDecoder)
    pair.fast.check_alignment = False
    pair.pure.check_alignment = False
    run(pair, stream, cuts, 1.5)


@pytest.mark.parametrize("make", [BoardDecoder, BoardCommandDecoder])
def test_paths_agree_on_a_long_noisy_stream(make: Callable[[], Decoder]) -> None:
    """Half a megabyte of frames with 2 % of their bytes damaged, in random chunks."""
    rng = random.Random(29)
    examples = EXAMPLES if make is BoardDecoder else COMMAND_EXAMPLES
    head = DEVICE_HEAD if make is BoardDecoder else HOST_HEAD
    parts = []
    for _ in range(20_000):
        frame = bytearray(rng.choice(examples)[0])
        if make is BoardDecoder and rng.random() < 0.5:
            frame = bytearray(_frame(head, 0x11, rng.randbytes(18)))
        for i in range(len(frame)):
            if rng.random() < 0.02:
                frame[i] = rng.randrange(256)
        if rng.random() < 0.02:
            del frame[rng.randrange(len(frame))]
        parts.append(bytes(frame))
    stream = b"".join(parts)
    pair = Pair(make)
    pos = 0
    decoded = 0
    while pos < len(stream):
        size = rng.choice([1, 2, 3, 23, 64, 512, 4096])
        decoded += len(pair.feed(as_style(stream[pos : pos + size], rng.randrange(4)), 2.0))
        pos += size
    assert decoded > 12_000  # about 70 % of the frames are intact
    assert pair.fast.stats.checksum_errors > 0
    assert pair.fast.stats.misaligned_frames > 0 or make is BoardCommandDecoder


# --- the edges of feed --------------------------------------------------------------------------


def test_a_memoryview_of_wider_items_counts_as_the_pure_path_counts() -> None:
    """``len(data)`` counts items, not bytes, for a memoryview of a wider format."""
    frame = EXAMPLES[1][0] + b"\x00"  # 10 bytes: five uint16
    pair = Pair(BoardDecoder)
    view = memoryview(array.array("H", frame))
    assert len(view) == 5
    assert len(pair.feed(view)) == 1
    assert pair.fast.stats.bytes_received == 5
    pair.feed(b"\xfe")  # held: the next chunk is appended to it
    assert len(pair.feed(memoryview(array.array("H", EXAMPLES[1][0][1:] + b"\x00\x00")))) == 1
    assert pair.fast.stats.bytes_received == 11


@pytest.mark.parametrize("data", ["FE CE", 7, None, [0xFE, 0xCE], 3.5], ids=repr)
@pytest.mark.parametrize("held", [b"", b"\xfe"], ids=["empty", "holding"])
def test_a_wrong_type_fails_as_on_the_pure_path(data: object, held: bytes) -> None:
    fast: Any = BoardDecoder()
    pure: Any = BoardDecoder()
    fast.feed(held)
    pure_feed(pure, held)
    outcomes: list[tuple[object, object]] = []
    calls: list[Callable[[], object]] = [lambda: fast.feed(data), lambda: pure_feed(pure, data)]
    for call in calls:
        try:
            outcomes.append(("ok", call()))
        except Exception as exc:
            outcomes.append((type(exc), str(exc)))
    assert outcomes[0] == outcomes[1]
    assert fast.stats.as_dict() == pure.stats.as_dict()
    assert fast._buf == pure._buf


def test_the_imu_sample_is_built_as_the_pure_parser_builds_it() -> None:
    frame = EXAMPLES[0][0]
    (fast,) = BoardDecoder().feed(frame, 4)
    (pure,) = pure_feed(BoardDecoder(), frame, 4)
    assert fast == pure == dataclasses.replace(EXAMPLES[0][1], timestamp=4)
    assert fast.raw == pure.raw
    assert type(fast.raw) is type(pure.raw)
    assert fast.timestamp == 4
    assert type(fast.timestamp) is int
    assert hash(fast.accel) == hash(pure.accel)
    assert hash(fast.raw) == hash(pure.raw)
    assert repr(fast) == repr(pure)
    with pytest.raises(dataclasses.FrozenInstanceError):
        fast.timestamp = 5.0  # type: ignore[misc]


def test_the_sample_s_tuples_are_left_to_reference_counting() -> None:
    """The three vectors and the counts hold only floats and ints, so the compiled path
    leaves them untracked by the collector (the pure path's stay tracked: CPython
    untracks only exact tuples); the sample itself is tracked.
    A collection with them alive, and their release, change nothing."""
    frame = EXAMPLES[0][0]
    msgs: list[Any] = BoardDecoder().feed(frame * 500, 1.0)
    assert len(msgs) == 500
    for m in msgs[:5]:
        assert not any(gc.is_tracked(t) for t in (m.accel, m.gyro, m.mag, m.raw))
        assert gc.is_tracked(m)
    (pure,) = pure_feed(BoardDecoder(), frame, 1.0)
    assert gc.is_tracked(pure.accel)  # the pure path's, for good
    gc.collect()
    assert msgs[0] == msgs[-1] == pure
    del msgs
    gc.collect()


def test_bind_refuses_tuples_that_would_have_a_dict() -> None:
    """Only tuple subclasses without a __dict__ may be left untracked: bind refuses any
    other before it changes anything, and the decoders keep working."""
    from chassis_sdk.devices.board.messages import ImuCounts, ImuSample, Vector3

    class WithDict(tuple):  # type: ignore[type-arg]
        pass

    args: dict[str, Any] = {
        "decoder_cls": BoardDecoder,
        "command_cls": BoardCommandDecoder,
        "pure_feed": FrameDecoder.feed,
        "try_frame": protocol._ProtocolBDecoder._try_frame,
        "swallows_a_head": protocol._ProtocolBDecoder._swallows_a_head,
        "parse_imu": protocol._parse_imu,
        "imu_cls": ImuSample,
        "vector_cls": Vector3,
        "counts_cls": ImuCounts,
        "stats_cls": DecoderStats,
        "accel_scale": protocol.ACCEL_SCALE,
        "gyro_scale": protocol.GYRO_SCALE,
    }
    for name in ("vector_cls", "counts_cls"):
        with pytest.raises(TypeError, match="without a __dict__"):
            COMPILED_BIND(**{**args, name: WithDict})

    class PlainStats:  # counters in a __dict__, not in slots
        def __init__(self) -> None:
            self.bytes_received = self.frames = self.bytes_dropped = 0

    with pytest.raises(TypeError, match="not slot descriptors"):
        COMPILED_BIND(**{**args, "stats_cls": PlainStats})
    assert BoardDecoder().feed(EXAMPLES[0][0]) == [EXAMPLES[0][1]]


#: A velocity frame that checks out with a plausible battery frame's start inside it.
MISALIGNED = _frame(DEVICE_HEAD, 0x12, DEVICE_HEAD + b"\x13\x03")


# --- who gets which path ------------------------------------------------------------------------


def test_the_module_s_decoders_feed_through_the_compiled_path() -> None:
    assert compiled.status() != "no protocol imported"
    assert "pure" not in compiled.status() or "board: compiled" in compiled.status()
    assert BoardDecoder.feed is COMPILED_FEED
    assert BoardCommandDecoder.feed is COMPILED_FEED


class CountingDecoder(BoardDecoder):
    """A subclass that overrides ``_try_frame``: only the pure loop calls it."""

    calls: ClassVar[list[int]] = []

    def _try_frame(
        self, buf: bytes | bytearray, start: int, end: int, out: list[Any], ts: float
    ) -> int:
        self.calls.append(start)
        return super()._try_frame(buf, start, end, out, ts)


def test_a_subclass_overriding_try_frame_gets_the_pure_path() -> None:
    assert CountingDecoder.feed is FrameDecoder.feed
    CountingDecoder.calls.clear()
    assert CountingDecoder().feed(EXAMPLES[0][0] * 3) == [EXAMPLES[0][1]] * 3
    assert CountingDecoder.calls == [0, 23, 46]


def test_a_subclass_overriding_a_parser_gets_the_pure_path() -> None:
    def parse_imu(b: bytes | bytearray, o: int, n: int, ts: float) -> str:
        return "mine"

    class MyImu(BoardDecoder):
        _table: ClassVar[FrameTable] = {**BoardDecoder._table, 0x11: (0x13, parse_imu)}

    assert MyImu.feed is FrameDecoder.feed
    assert MyImu().feed(EXAMPLES[0][0] + EXAMPLES[1][0]) == ["mine", EXAMPLES[1][1]]


def test_a_subclass_s_own_feed_and_super_feed_run_the_pure_loop() -> None:
    looked_up = []

    class Own(BoardDecoder):
        def feed(self, data: bytes | bytearray | memoryview, timestamp: float = 0.0) -> list[Any]:
            return [*BoardDecoder.feed(self, data, timestamp), "own"]

        def __getattribute__(self, name: str) -> Any:
            looked_up.append(name)
            return super().__getattribute__(name)

    class Below(Own):
        pass

    assert Below.feed is Own.feed  # a feed of the subclass's own is kept
    assert Below().feed(EXAMPLES[0][0]) == [EXAMPLES[0][1], "own"]
    assert "_try_frame" in looked_up  # the compiled feed sent the subclass to the pure loop


def test_an_instance_s_changed_try_frame_is_honoured() -> None:
    decoder = BoardDecoder()
    calls = []

    def try_frame(buf: bytes | bytearray, start: int, end: int, out: list[Any], ts: float) -> int:
        calls.append(start)
        return protocol._ProtocolBDecoder._try_frame(decoder, buf, start, end, out, ts)

    decoder._try_frame = try_frame  # type: ignore[method-assign]
    assert decoder.feed(EXAMPLES[0][0] * 2) == [EXAMPLES[0][1]] * 2
    assert calls == [0, 23]


def test_a_class_s_changed_swallows_a_head_is_honoured(monkeypatch: pytest.MonkeyPatch) -> None:
    # A frame with a plausible head inside, which the alignment rule asks about.
    inner = _frame(DEVICE_HEAD, 0x13, DEVICE_HEAD)
    asked = []

    def swallows(self: object, buf: bytes, start: int, stop: int, end: int) -> bool:
        asked.append(start)
        return False

    monkeypatch.setattr(BoardDecoder, "_swallows_a_head", swallows)
    assert len(BoardDecoder().feed(inner + b"\x00" * 4)) == 1
    assert asked == [0]


def test_an_instance_s_table_and_alignment_rule_are_honoured() -> None:
    stream = MISALIGNED + b"\x00" * 4
    refusing = BoardDecoder()
    assert refusing.feed(stream) == []
    assert refusing.stats.misaligned_frames == 1
    decoder = BoardDecoder()
    decoder.check_alignment = False  # type: ignore[misc]
    assert [type(m) for m in decoder.feed(stream)] == [VelocityFeedback]
    decoder = BoardDecoder()
    decoder._table = {0x12: BoardDecoder._table[0x12]}  # type: ignore[misc]
    assert decoder.feed(EXAMPLES[0][0] + EXAMPLES[1][0]) == [EXAMPLES[1][1]]
    assert decoder.stats.bytes_dropped == len(EXAMPLES[0][0])


def test_a_changed_head_is_honoured_and_another_type_goes_to_the_pure_loop() -> None:
    decoder = BoardDecoder()
    decoder._head = HOST_HEAD
    assert decoder.feed(COMMAND_EXAMPLES[2][0]) == []  # a command frame with the device table
    assert decoder.stats.bytes_dropped == len(COMMAND_EXAMPLES[2][0])
    assert decoder.feed(HOST_HEAD + EXAMPLES[1][0][2:]) == [EXAMPLES[1][1]]
    bytes_head = BoardDecoder()
    bytes_head._head = memoryview(DEVICE_HEAD)  # type: ignore[assignment]
    assert bytes_head.feed(EXAMPLES[1][0]) == [EXAMPLES[1][1]]


def test_the_class_s_values_changed_after_a_feed_are_honoured(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """feed keeps what it read from the class while the class's version tag holds:
    a head, table or alignment rule changed on the class afterwards is read again."""
    stream = MISALIGNED + b"\x00" * 4
    assert BoardDecoder().feed(stream) == []  # read from the class, and kept
    monkeypatch.setattr(BoardDecoder, "check_alignment", False)
    assert [type(m) for m in BoardDecoder().feed(stream)] == [VelocityFeedback]
    monkeypatch.undo()
    assert BoardDecoder().feed(stream) == []
    monkeypatch.setattr(BoardDecoder, "_table", {0x12: BoardDecoder._table[0x12]})
    decoder = BoardDecoder()
    assert decoder.feed(EXAMPLES[0][0] + EXAMPLES[1][0]) == [EXAMPLES[1][1]]
    assert decoder.stats.bytes_dropped == len(EXAMPLES[0][0])
    monkeypatch.undo()
    monkeypatch.setattr(BoardDecoder, "_head", HOST_HEAD)
    assert BoardDecoder().feed(HOST_HEAD + EXAMPLES[1][0][2:]) == [EXAMPLES[1][1]]
    monkeypatch.undo()
    assert BoardDecoder().feed(EXAMPLES[1][0]) == [EXAMPLES[1][1]]


def test_replaced_stats_are_counted_through_their_own_attributes() -> None:
    class Counting(DecoderStats):
        __slots__ = ("sets",)
        sets: int

        def __init__(self) -> None:
            object.__setattr__(self, "sets", 0)
            super().__init__()  # one set per counter

        def __setattr__(self, name: str, value: object) -> None:
            if name != "sets":
                self.sets += 1
            super().__setattr__(name, value)

    raw = b"\x00\x01" + EXAMPLES[0][0] * 3
    pair = Pair(BoardDecoder)
    pair.fast.stats, pair.pure.stats = Counting(), Counting()
    initial = pair.fast.stats.sets
    pair.feed(raw)
    assert pair.fast.stats.frames == 3
    assert pair.fast.stats.bytes_dropped == 2
    assert pair.fast.stats.sets == pair.pure.stats.sets == initial + 3  # received, dropped, frames


@pytest.mark.integration
def test_pure_env_gives_the_pure_path() -> None:
    code = (
        "from chassis_sdk.core import compiled\n"
        "from chassis_sdk.core.framing import FrameDecoder\n"
        "from chassis_sdk.devices.board import protocol as p\n"
        "from chassis_sdk.devices.board.profile import EXAMPLES\n"
        "print(compiled.status())\n"
        "print(p._compiled is None, p.BoardDecoder.feed is FrameDecoder.feed,"
        " p.BoardCommandDecoder.feed is FrameDecoder.feed)\n"
        "print(p.BoardDecoder().feed(EXAMPLES[0][0]) == [EXAMPLES[0][1]])\n"
    )
    env = {**os.environ, "CHASSIS_SDK_PURE": "1"}
    done = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    )
    assert done.stdout.splitlines() == [
        "pure (CHASSIS_SDK_PURE=1)",
        "True True True",
        "True",
    ]


# --- no reference leak --------------------------------------------------------------------------


def test_no_reference_leak_over_a_million_and_a_half_frames() -> None:
    """Every frame type, noise, false heads, held partial frames, the three input
    types: after warm-up, the interpreter's allocated blocks stay where they were."""
    rng = random.Random(7)
    ts = float(rng.randrange(1000))  # a float of its own: its references are counted
    table, head = BoardDecoder._table, BoardDecoder._head
    frames = [f for f, _ in EXAMPLES] + [
        _frame(DEVICE_HEAD, 0x11, rng.randbytes(18)) for _ in range(8)
    ]
    noisy = [
        b"\x00\xfe\x11",  # a false head
        DEVICE_HEAD + b"\x13\x03\x00\x00\x00",  # a checksum error
        _frame(DEVICE_HEAD, 0xF1, b"\x01bad"),  # malformed
        MISALIGNED,
    ]
    body = b"".join(rng.choice(frames) for _ in range(4000))
    stream = body + b"".join(noisy) + body
    chunks = [stream[i : i + 4093] for i in range(0, len(stream), 4093)]
    small = [stream[i : i + 23] for i in range(0, 23 * 2000, 23)]
    decoder = BoardDecoder()

    def one_pass(k: int) -> int:
        n = 0
        for i, c in enumerate(chunks):
            n += len(decoder.feed(as_style(c, (i + k) % 3), ts))
        for c in small:
            n += len(decoder.feed(c))
        return n

    for k in range(3):
        one_pass(k)
    gc.collect()
    before = sys.getallocatedblocks()
    references = [sys.getrefcount(x) for x in (ts, table, head, decoder._buf, decoder.stats)]
    total = 0
    k = 0
    while total < 1_500_000:
        total += one_pass(k)
        k += 1
    gc.collect()
    grown = sys.getallocatedblocks() - before
    assert total >= 1_500_000
    assert grown < 200, f"{grown} blocks more after {total} frames"
    assert [sys.getrefcount(x) for x in (ts, table, head, decoder._buf, decoder.stats)] == (
        references
    )
