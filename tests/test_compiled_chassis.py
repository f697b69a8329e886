"""Protocol A's compiled fast path against the pure code it mirrors (issue 29).

The pure ``FrameDecoder.feed`` is the reference: a differential test feeds the same random
streams (valid frames of every type, noise, false heads, corrupted and truncated frames,
sequence jumps, in chunks of 1-4096 bytes given as bytes, bytearray or memoryview) to a
decoder on each path and compares, after every chunk, the messages (equal, of the same
types, floats bit for bit, enum members the same objects), the stats, the buffer and
the sequence tracker. Subclasses and changed classes must get the pure behaviour;
``CHASSIS_SDK_PURE=1`` must give the pure path; millions of frames must leak nothing.
"""

from __future__ import annotations

import dataclasses
import enum
import gc
import os
import random
import struct
import subprocess
import sys
from typing import Any, ClassVar

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chassis_sdk.core import compiled
from chassis_sdk.core.framing import DecoderStats, FrameDecoder, FrameTable
from chassis_sdk.devices.chassis import protocol
from chassis_sdk.devices.chassis.messages import (
    ChassisStatus,
    DockingState,
    Telemetry,
    WheelSpeeds,
)
from chassis_sdk.devices.chassis.profile import COMMAND_EXAMPLES, EXAMPLES
from chassis_sdk.devices.chassis.protocol import (
    ChassisCommandDecoder,
    ChassisDecoder,
    ChassisEncoder,
    SequenceTracker,
)

pytestmark = pytest.mark.codec

if protocol._compiled is None:
    pytest.skip(
        f"protocol A's compiled fast path is not active ({compiled.status()}): build it "
        "with `python setup.py build_ext --inplace`, without CHASSIS_SDK_PURE=1",
        allow_module_level=True,
    )

Decoder = protocol._ProtocolADecoder[Any]
Make = type[Decoder]

# --- comparing the two paths -------------------------------------------------------------


def same(a: object, b: object) -> bool:
    """``a == b``, of the same types all the way down, floats bit for bit, enum members
    the same objects (pseudo-members of unknown values the same value and name: past
    its limit, the shared MemberCache builds one per frame on either path)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, enum.Enum):
        assert isinstance(b, enum.Enum)
        if a._name_ in type(a).__members__:
            return a is b
        return (a._value_, a._name_) == (b._value_, b._name_)
    if isinstance(a, float):
        assert isinstance(b, float)
        return a.hex() == b.hex()
    if dataclasses.is_dataclass(a) and not isinstance(a, type):
        return all(same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    if isinstance(a, tuple):
        assert isinstance(b, tuple)
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def state(dec: Decoder) -> tuple[object, ...]:
    t = dec.sequence
    return (
        dec.stats.as_dict(),
        bytes(dec._buf),
        type(dec._buf),
        t.gaps,
        t.scheme,
        t._last,
        list(t._by_id.items()),
        t._votes,
    )


def check_chunk(fast: Decoder, pure: Decoder, chunk: bytes, style: str, ts: object) -> None:
    def view(c: bytes) -> bytes | bytearray | memoryview:
        if style == "bytearray":
            return bytearray(c)
        if style == "memoryview":
            return memoryview(bytearray(c))
        return c

    got = fast.feed(view(chunk), ts)  # type: ignore[arg-type]
    want = FrameDecoder.feed(pure, view(chunk), ts)  # type: ignore[arg-type]
    assert type(got) is list
    assert len(got) == len(want)
    assert all(same(g, w) for g, w in zip(got, want, strict=True)), (got, want)
    assert state(fast) == state(pure)


# --- building streams --------------------------------------------------------------------


def frame(frame_id: int, payload: bytes, seq: int, length: int | None = None) -> bytes:
    """A protocol A frame; ``length``: the length byte, if not the true one."""
    size = len(payload) + 10
    body = b"\xed\xde" + struct.pack("<HBB", seq, frame_id, size if length is None else length)
    body += payload
    return body + struct.pack("<H", sum(body) & 0xFFFF) + b"\xbd\xbc"


def payload_for(table: FrameTable, frame_id: int, rnd: random.Random) -> bytes:
    size = table[frame_id][0]
    n = rnd.randrange(0, 40) if size == 0 else size - 10
    if frame_id == 0x88 and rnd.random() < 0.7:
        return bytes(rnd.randrange(32, 127) for _ in range(n))  # ASCII text, mostly
    return bytes(rnd.randrange(256) for _ in range(n))


def stream(table: FrameTable, examples: tuple[tuple[bytes, object], ...],
           seed: int, pieces: int) -> bytes:  # fmt: skip
    """Random pieces: frames of every type (most of them back to back, as a busy port
    sends them), numbered by one counter, by one per id, or anyhow, with jumps; the
    vendor's examples; noise, false heads, corrupted and cut frames, wrong length bytes."""
    rnd = random.Random(seed)
    ids = list(table)
    hot = ids[0]  # 0x81 for the device table
    scheme = rnd.choice(["shared", "per-id", "random"])
    shared = rnd.randrange(0x10000)
    per_id = {i: rnd.randrange(0x10000) for i in ids}
    out = []
    for _ in range(pieces):
        kind = rnd.random()
        fid = hot if rnd.random() < 0.6 else rnd.choice(ids)
        if scheme == "shared":
            seq = shared
        elif scheme == "per-id":
            seq = per_id[fid]
        else:
            seq = rnd.randrange(0x10000)
        if rnd.random() < 0.03:
            seq = rnd.randrange(0x10000)  # a jump
        shared = (seq + 1) & 0xFFFF
        per_id[fid] = (seq + 1) & 0xFFFF
        good = frame(fid, payload_for(table, fid, rnd), seq)
        if kind < 0.70:
            out.append(good)
        elif kind < 0.75:
            out.append(rnd.choice(examples)[0])
        elif kind < 0.80:
            out.append(bytes(rnd.randrange(256) for _ in range(rnd.randrange(1, 60))))
        elif kind < 0.85:  # a false head, perhaps with a plausible id and length
            head = b"\xed\xde" + bytes(rnd.randrange(256) for _ in range(rnd.randrange(0, 8)))
            out.append(head)
        elif kind < 0.90:  # a corrupted byte anywhere
            bad = bytearray(good)
            bad[rnd.randrange(len(bad))] ^= 1 << rnd.randrange(8)
            out.append(bytes(bad))
        elif kind < 0.95:  # cut short
            out.append(good[: rnd.randrange(1, len(good))])
        else:  # a wrong length byte with a valid check (as the vendor's 0x89 example)
            out.append(frame(fid, payload_for(table, fid, rnd), seq, rnd.randrange(256)))
    return b"".join(out)


CODECS = [
    pytest.param(ChassisDecoder, EXAMPLES, id="chassis"),
    pytest.param(ChassisCommandDecoder, COMMAND_EXAMPLES, id="chassis-commands"),
]


def test_the_module_s_decoders_run_compiled() -> None:
    assert compiled._loaded["chassis_sdk.devices.chassis._compiled"] == "compiled"
    module = protocol._compiled
    assert module is not None
    assert vars(ChassisDecoder)["feed"] is module.feed
    assert vars(ChassisCommandDecoder)["feed"] is module.feed


@pytest.mark.slow
@pytest.mark.parametrize(("make", "examples"), CODECS)
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_differential_random_streams(
    make: Make, examples: tuple[tuple[bytes, object], ...], data: st.DataObject
) -> None:
    seed = data.draw(st.integers(0, 2**32), label="seed")
    pieces = data.draw(st.integers(1, 400), label="pieces")
    raw = stream(make._table, examples, seed, pieces)
    fast, pure = make(), make()
    pos = 0
    while pos < len(raw):
        size = data.draw(st.one_of(st.integers(1, 64), st.integers(1, 4096)), label="chunk")
        style = data.draw(st.sampled_from(["bytes", "bytearray", "memoryview"]), label="as")
        ts = data.draw(st.one_of(st.floats(0, 1e6), st.integers(0, 10)), label="ts")
        check_chunk(fast, pure, raw[pos : pos + size], style, ts)
        pos += size
    check_chunk(fast, pure, b"", "bytes", 0.0)


@pytest.mark.parametrize(("make", "examples"), CODECS)
def test_differential_every_split_of_the_examples(
    make: Make, examples: tuple[tuple[bytes, object], ...]
) -> None:
    raw = b"\x00\xed" + b"".join(f for f, _ in examples) * 3 + b"\xed"
    for size in (1, 2, 3, 5, 7, 11, 13, 28, 64, 4096):
        fast, pure = make(), make()
        for i in range(0, len(raw), size):
            check_chunk(fast, pure, raw[i : i + size], "bytes", 1.5)
        assert fast.stats.frames == 3 * len(examples)


def test_telemetry_values_of_every_field() -> None:
    """Every docking value (most unknown: pseudo-members from the shared cache), negative
    and extreme speeds, any status bits: the C unpacking of 0x81 against the parser's."""
    rnd = random.Random(29)
    frames = []
    for i in range(3000):
        v, st_, dk = rnd.randrange(0x10000), rnd.randrange(0x10000), rnd.randrange(0x10000)
        if i % 3 == 0:
            dk = rnd.randrange(8)
        speeds = [rnd.choice([-32768, -1, 0, 1, 32767, rnd.randrange(-32768, 32768)])
                  for _ in range(6)]  # fmt: skip
        payload = struct.pack("<HHH6h", v, st_, dk, *speeds)
        frames.append(frame(0x81, payload, i & 0xFFFF))
    fast, pure = ChassisDecoder(), ChassisDecoder()
    check_chunk(fast, pure, b"".join(frames), "bytes", 2.0)
    assert fast.stats.frames == 3000
    msgs: list[Any] = ChassisDecoder().feed(b"".join(frames[:10]))
    assert all(type(m.wheels) is WheelSpeeds for m in msgs)
    assert all(type(m.status) is ChassisStatus for m in msgs)
    assert all(type(m.docking) is DockingState for m in msgs)


def test_the_wheels_are_left_to_reference_counting() -> None:
    """WheelSpeeds holds only floats: the compiled path leaves it untracked by the
    collector (the pure path's is tracked; CPython untracks only exact tuples); the
    Telemetry itself is tracked. A collection with them alive changes nothing."""
    frames = b"".join(f for f, m in EXAMPLES if type(m) is Telemetry)
    assert frames
    msgs: list[Any] = ChassisDecoder().feed(frames * 50, 1.0)
    pure: list[Any] = FrameDecoder.feed(ChassisDecoder(), frames * 50, 1.0)
    assert msgs
    assert all(not gc.is_tracked(m.wheels) and gc.is_tracked(m) for m in msgs)
    gc.collect()
    assert msgs == pure
    del msgs
    gc.collect()


def test_bind_refuses_wheels_that_would_have_a_dict() -> None:
    """Only a tuple subclass without a __dict__ may be left untracked: bind refuses
    any other before it changes anything, and the decoders keep working."""

    class WithDict(tuple):  # type: ignore[type-arg]
        pass

    args: dict[str, Any] = {
        "decoder_cls": ChassisDecoder,
        "command_cls": ChassisCommandDecoder,
        "pure_feed": FrameDecoder.feed,
        "try_frame": protocol._ProtocolADecoder._try_frame,
        "tracker_cls": SequenceTracker,
        "stats_cls": DecoderStats,
        "parse_telemetry": protocol._parse_telemetry,
        "telemetry_cls": Telemetry,
        "status": protocol._status,
        "docking": protocol._docking,
    }
    bind: Any = protocol._compiled.bind  # type: ignore[union-attr]
    with pytest.raises(TypeError, match="without a __dict__"):
        bind(**args, wheels_cls=WithDict)
    frames = b"".join(f for f, _ in EXAMPLES)
    assert ChassisDecoder().feed(frames) == [m for _, m in EXAMPLES]


def test_the_timestamp_object_is_stored_as_given() -> None:
    """The pure parser stores ``ts`` itself: an int stays an int."""
    enc = ChassisEncoder()
    t = Telemetry(24.6, ChassisStatus(0), DockingState.DOCKED, 0.1, 0.2, WheelSpeeds(1, 2, 3, 4))
    (msg,) = ChassisDecoder().feed(enc.encode(t), 7)
    assert isinstance(msg, Telemetry)
    assert type(msg.timestamp) is int
    assert msg.timestamp == 7


# --- what must take the pure path --------------------------------------------------------


class CountingTry(ChassisDecoder):
    __slots__ = ("tries",)

    def __init__(self) -> None:
        super().__init__()
        self.tries = 0

    def _try_frame(self, buf: Any, start: int, end: int, out: list[Any], ts: float) -> int:
        self.tries += 1
        return super()._try_frame(buf, start, end, out, ts)


def _telemetry_bytes(n: int) -> bytes:
    enc = ChassisEncoder()
    t = Telemetry(24.6, ChassisStatus(8), DockingState.SEARCHING, 0.3, -0.2,
                  WheelSpeeds(0.2, 0.4, 0.2, 0.4))  # fmt: skip
    return b"".join(enc.encode(t) for _ in range(n))


def test_a_subclass_gets_the_pure_feed() -> None:
    assert CountingTry.feed is FrameDecoder.feed
    dec = CountingTry()
    assert len(dec.feed(_telemetry_bytes(5))) == 5
    assert dec.tries == 1  # the pure loop called the override (one call: back to back)


def test_a_subclass_that_calls_super_feed_gets_the_pure_loop() -> None:
    class Wrapping(CountingTry):
        __slots__ = ()

        def feed(self, data: Any, timestamp: float = 0.0) -> list[Any]:
            return super().feed(data, timestamp)

    class Again(ChassisDecoder):
        __slots__ = ("tries",)

        def feed(self, data: Any, timestamp: float = 0.0) -> list[Any]:
            return ChassisDecoder.feed(self, data, timestamp)  # the compiled one

        def _try_frame(self, buf: Any, start: int, end: int, out: list[Any], ts: float) -> int:
            self.tries = getattr(self, "tries", 0) + 1
            return super()._try_frame(buf, start, end, out, ts)

    dec = Wrapping()
    assert len(dec.feed(_telemetry_bytes(3))) == 3
    assert dec.tries == 1
    again = Again()
    assert len(again.feed(_telemetry_bytes(3))) == 3
    assert again.tries == 1


def test_a_subclass_with_its_own_parser_gets_it() -> None:
    seen: list[int] = []

    def parse(b: Any, o: int, n: int, ts: float) -> object:
        seen.append(o)
        return protocol._parse_telemetry(b, o, n, ts)

    class OwnParser(ChassisDecoder):
        __slots__ = ()
        _table: ClassVar[FrameTable] = {**ChassisDecoder._table, 0x81: (28, parse)}

    assert len(OwnParser().feed(_telemetry_bytes(4))) == 4
    assert seen == [6, 34, 62, 90]


def test_a_changed_table_is_honoured(monkeypatch: pytest.MonkeyPatch) -> None:
    seen: list[int] = []

    def parse(b: Any, o: int, n: int, ts: float) -> object:
        seen.append(o)
        return protocol._parse_telemetry(b, o, n, ts)

    monkeypatch.setattr(ChassisDecoder, "_table", {**ChassisDecoder._table, 0x81: (28, parse)})
    assert len(ChassisDecoder().feed(_telemetry_bytes(2))) == 2
    assert seen == [6, 34]
    monkeypatch.setattr(ChassisDecoder, "_table", {0x8A: ChassisDecoder._table[0x8A]})
    assert ChassisDecoder().feed(_telemetry_bytes(2) + EXAMPLES[0][0]) == [EXAMPLES[0][1]]


@pytest.mark.parametrize(
    "entry",
    [
        pytest.param([28, protocol._parse_telemetry], id="list"),
        pytest.param((True, protocol._parse_telemetry), id="bool-size"),
        pytest.param((5, protocol._parse_telemetry), id="too-small"),
        pytest.param((2**70, protocol._parse_telemetry), id="huge"),
        pytest.param((30, protocol._parse_telemetry), id="other-size"),
        pytest.param((0, protocol._parse_telemetry), id="variable"),
    ],
)
def test_an_unexpected_table_entry_decodes_as_the_pure_code_does(
    monkeypatch: pytest.MonkeyPatch, entry: Any
) -> None:
    monkeypatch.setattr(ChassisDecoder, "_table", {**ChassisDecoder._table, 0x81: entry})
    raw = stream(ChassisDecoder._table, EXAMPLES, 7, 200) if entry[0] in (28, 0, 30) else b""
    raw = raw or b"".join(f for f, _ in EXAMPLES) + b"\x00\xed\xde\x00" + EXAMPLES[0][0]
    for size in (1, 9, 4096):
        fast, pure = ChassisDecoder(), ChassisDecoder()
        for i in range(0, len(raw), size):
            try:
                want: object = FrameDecoder.feed(pure, raw[i : i + size])
            except Exception as exc:  # a broken table may break the pure code too
                want = type(exc)
            try:
                got: object = fast.feed(raw[i : i + size])
            except Exception as exc:
                got = type(exc)
            assert got == want
            assert state(fast) == state(pure)


def test_a_changed_try_frame_or_head_sends_the_call_to_the_pure_loop(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    calls: list[int] = []
    original = protocol._ProtocolADecoder._try_frame

    def wrapped(self: Any, buf: Any, start: int, end: int, out: list[Any], ts: float) -> int:
        calls.append(start)
        return original(self, buf, start, end, out, ts)

    monkeypatch.setattr(protocol._ProtocolADecoder, "_try_frame", wrapped)
    assert len(ChassisDecoder().feed(_telemetry_bytes(2))) == 2
    assert calls == [0]
    monkeypatch.undo()
    monkeypatch.setattr(ChassisDecoder, "_head", b"\xed")  # a one-byte head: the pure loop
    raw = _telemetry_bytes(2)
    fast, pure = ChassisDecoder(), ChassisDecoder()
    check_chunk(fast, pure, raw, "bytes", 0.0)


def test_a_replaced_tracker_is_called() -> None:
    class Recording(SequenceTracker):
        __slots__ = ("calls",)

        def __init__(self) -> None:
            super().__init__()
            self.calls: list[tuple[int, int]] = []

        def update(self, frame_id: int, seq: int) -> None:
            self.calls.append((frame_id, seq))
            super().update(frame_id, seq)

    dec = ChassisDecoder()
    dec.sequence = Recording()
    dec.feed(_telemetry_bytes(3))
    assert dec.sequence.calls == [(0x81, 0), (0x81, 1), (0x81, 2)]


@pytest.mark.integration
def test_pure_env_gives_the_pure_path() -> None:
    code = (
        "from chassis_sdk.core import compiled\n"
        "from chassis_sdk.core.framing import FrameDecoder\n"
        "from chassis_sdk.devices.chassis.protocol import ChassisDecoder, ChassisCommandDecoder\n"
        "from chassis_sdk.devices.chassis.profile import EXAMPLES\n"
        "print(compiled.status())\n"
        "print(ChassisDecoder.feed is FrameDecoder.feed is ChassisCommandDecoder.feed)\n"
        "print(ChassisDecoder().feed(b''.join(f for f, _ in EXAMPLES)) == [m for _, m in EXAMPLES])\n"
    )
    env = {**os.environ, "CHASSIS_SDK_PURE": "1"}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True
    ).stdout.splitlines()
    assert out == ["pure (CHASSIS_SDK_PURE=1)", "True", "True"]


# --- no reference leak -------------------------------------------------------------------


@pytest.mark.slow
def test_no_reference_leak_over_a_million_frames() -> None:
    """Every path of the compiled code (0x81 in C, the other frames through their Python
    parsers, the tracker's usual case and its Python update, checksum errors, noise, a
    buffer held over) over 1.2 million frames: the interpreter's allocated blocks stay
    put after a warm-up (one leaked object per frame would add a million)."""
    raw = stream(ChassisDecoder._table, EXAMPLES, 1, 3000)
    chunks = [raw[i : i + 4096] for i in range(0, len(raw), 4096)]
    chunks += [raw[i : i + 37] for i in range(0, 37 * 400, 37)]  # held over, per call
    dec = ChassisDecoder()
    per_round = 0
    for c in chunks:
        per_round += len(dec.feed(c))
    rounds = 1_200_000 // per_round + 1
    gc.collect()
    before = sys.getallocatedblocks()
    for _ in range(rounds):
        for c in chunks:
            dec.feed(c)
    gc.collect()
    grown = sys.getallocatedblocks() - before
    assert dec.stats.frames >= 1_200_000
    assert grown < 1000, grown


def test_a_changed_tracker_class_is_honoured(monkeypatch: pytest.MonkeyPatch) -> None:
    ChassisDecoder().feed(_telemetry_bytes(3))  # what feed checked is recorded by now
    calls: list[tuple[int, int]] = []
    original = SequenceTracker.update

    def update(self: SequenceTracker, frame_id: int, seq: int) -> None:
        calls.append((frame_id, seq))
        original(self, frame_id, seq)

    monkeypatch.setattr(SequenceTracker, "update", update)
    ChassisDecoder().feed(_telemetry_bytes(3))
    assert calls == [(0x81, 0), (0x81, 1), (0x81, 2)]


def test_replaced_stats_are_counted_through_their_own_attributes() -> None:
    class Counting(DecoderStats):
        __slots__ = ("sets",)
        sets: int

        def __init__(self) -> None:
            object.__setattr__(self, "sets", 0)
            super().__init__()  # 7 sets, one per counter

        def __setattr__(self, name: str, value: object) -> None:
            if name != "sets":
                self.sets += 1
            super().__setattr__(name, value)

    raw = b"\x00\x01" + _telemetry_bytes(3)
    fast, pure = ChassisDecoder(), ChassisDecoder()
    fast.stats, pure.stats = Counting(), Counting()
    check_chunk(fast, pure, raw, "bytes", 0.0)
    assert fast.stats.as_dict() == DecoderStats(3 * 28 + 2, 3, 2).as_dict()
    assert fast.stats.sets == pure.stats.sets == 7 + 3  # received, dropped, frames
