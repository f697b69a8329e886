"""Whole captures decoded into arrays (core.columns) find the very frames the streaming
decoders find, with the same values: on the vendor examples, on a table of hostile
byte strings, on random noisy streams in random chunks (hypothesis), and through
``capture_columns`` on JSON-lines and MCAP files."""

from __future__ import annotations

import dataclasses
import itertools
import json
import operator
from pathlib import Path
from typing import Any

import numpy as np  # the `columns` extra (in `all`): missing, these tests fail
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from chassis_sdk.cli.devices import checked, commands
from chassis_sdk.core.framing import Column, FrameDecoder
from chassis_sdk.devices import DeviceProfile, profile
from chassis_sdk.recording.capture import capture_columns
from chassis_sdk.recording.columns import Columns, decode_columns, decode_joined

PROTOCOLS = ["chassis", "board"]


def streamed(chunks: list[tuple[float, bytes]], decoder: FrameDecoder[Any]) -> list[Any]:
    """``(t, message)`` of the streaming decoder, chunk by chunk."""
    return [(t, m) for t, data in chunks for m in decoder.feed(data, t)]


def field(message: object, column: Column) -> float:
    """A message's value of ``column`` (``wheels.front_left``), codes as integers."""
    value = operator.attrgetter(column.name)(message)
    return int(value) if column.divisor is None else float(value)


def assert_same(chunks: list[tuple[float, bytes]], protocol: str) -> Columns:
    """Columns and the streaming decoder agree: which frames, in which order, their
    values, their times (never later: the streaming decoder may emit a frame a chunk
    late, while it waits to decide a candidate before it), and the byte counts."""
    decoder = profile(protocol).codec.decoder()
    cols = decode_columns(chunks, profile(protocol).codec.decoder())
    objects = streamed(chunks, decoder)
    spec = type(decoder).columns
    names = dict(spec.values())
    assert cols.frames == len(objects) == decoder.stats.frames
    assert cols.bytes == decoder.stats.bytes_received
    assert cols.bytes_dropped == decoder.stats.bytes_dropped + decoder.buffered
    rare = [(t, m) for t, m in objects if type(m).__name__ not in names]
    assert len(cols.messages) == len(rare)
    for (t_obj, m_obj), (t_col, col) in zip(rare, cols.messages, strict=True):
        assert t_col <= t_obj
        m_col: Any = col
        if hasattr(m_obj, "timestamp"):
            m_obj = dataclasses.replace(m_obj, timestamp=0.0)
            m_col = dataclasses.replace(m_col, timestamp=0.0)
        assert m_col == m_obj
    for name, columns in names.items():
        mine = [(t, m) for t, m in objects if type(m).__name__ == name]
        table = cols.tables.get(name)
        if not mine:
            assert table is None
            continue
        assert table is not None
        assert list(table) == ["t", *(c.name for c in columns)]
        assert np.all(table["t"] <= np.array([t for t, _ in mine]))
        for c in columns:
            expected = [field(m, c) for _, m in mine]
            if c.divisor is None:
                assert table[c.name].tolist() == expected, c.name
            else:
                assert np.allclose(table[c.name], expected, rtol=0, atol=1e-12), c.name
    return cols


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_every_vendor_example_alone_and_all_together(protocol: str) -> None:
    examples = profile(protocol).codec.examples
    for frame, _ in examples:
        assert assert_same([(1.0, frame)], protocol).frames == 1
    together = [(i * 0.01, frame) for i, (frame, _) in enumerate(examples)]
    assert assert_same(together, protocol).frames == len(examples)


def test_the_telemetry_columns_are_in_si_units() -> None:
    from chassis_sdk.protocol import (
        ChassisEncoder,
        ChassisStatus,
        DockingState,
        Telemetry,
        WheelSpeeds,
    )

    t = Telemetry(24.6, ChassisStatus.HARDWARE_ESTOP, DockingState.SEARCHING, 0.3, -0.2,
                  WheelSpeeds(0.2, 0.4, -0.2, -0.4))  # fmt: skip
    encoder = ChassisEncoder()
    encoder.encode(t)
    frame = encoder.encode(t)  # the second: sequence number 1
    cols = decode_columns([(2.5, frame)], profile("chassis").codec.decoder())
    row = {k: v.tolist() for k, v in cols["Telemetry"].items()}
    assert row == {
        "t": [2.5], "voltage": [24.6], "status": [1], "docking": [int(DockingState.SEARCHING)],
        "linear": [0.3], "angular": [-0.2], "wheels.front_left": [0.2],
        "wheels.front_right": [0.4], "wheels.rear_left": [-0.2], "wheels.rear_right": [-0.4],
        "seq": [1],
    }  # fmt: skip


def _chassis(i: int) -> bytes:
    return profile("chassis").codec.examples[i][0]


def _board(i: int) -> bytes:
    return profile("board").codec.examples[i][0]


def _imu(data: bytes) -> bytes:
    """A checked-out IMU frame (0x11) of 18 data bytes, whatever they spell."""
    return b"\xfe\xce\x11\x13" + data + bytes([(0x11 + 0x13 + sum(data)) & 0xFF])


def _corrupt(frame: bytes, at: int) -> bytes:
    out = bytearray(frame)
    out[at] ^= 0x55
    return bytes(out)


# name, protocol, bytes: each decoded both ways and compared.
HOSTILE = [
    ("noise only", "chassis", bytes(range(256))),
    ("a false head before a frame", "chassis", b"\xed\xde\x00" + _chassis(0)),
    ("a head inside a good frame's data", "chassis", b"\xed\xde" + _chassis(0)[2:] + _chassis(0)),
    ("bad check, then good", "chassis", _corrupt(_chassis(0), 7) + _chassis(0)),
    ("bad tail, then good", "chassis", _corrupt(_chassis(0), -1) + _chassis(0)),
    (
        "variable frame claiming 255 at the end",
        "chassis",
        _chassis(0) + b"\xed\xde\x00\x00\x88\xff",
    ),
    ("cut off at the end", "chassis", _chassis(0) + _chassis(0)[:-3]),
    ("a lone head byte at the end", "chassis", _chassis(0) + b"\xed"),
    ("variable frame too short", "chassis", b"\xed\xde\x00\x00\x88\x05" + _chassis(0)),
    ("noise only", "board", bytes(range(256))),
    ("bad check, then good", "board", _corrupt(_board(0), -1) + _board(0)),
    ("a byte lost: the next head inside", "board", _board(0)[:5] + _board(0)[6:] + _board(0)),
    ("a frame ending in FE at the end", "board", b"\xfe\xce\x13\x03\x00\xfe\x14"),
    ("a head in the last two bytes", "board", _board(0) + b"\xfe\xce"),
    ("a head and a type in the last three bytes", "board", _board(0) + b"\xfe\xce\x11"),
    ("data spelling a head: refused", "board", _imu(b"\xfe\xce\x01\x03" + bytes(14)) + _board(0)),
    ("data spelling a head of an unknown type", "board", _imu(b"\xfe\xce\x77\x03" + bytes(14))),
    ("data ending on FE, then nothing", "board", _imu(bytes(17) + b"\xfe")),
    ("zero-length log", "board", b"\xfe\xce\xf1\x00" + _board(0)),
    ("cut off at the end", "board", _board(0) + _board(0)[:-1]),
]


@pytest.mark.parametrize(
    ("protocol", "data"), [(p, d) for _, p, d in HOSTILE], ids=[f"{p}: {n}" for n, p, _ in HOSTILE]
)
def test_hostile_bytes_decode_the_same_both_ways(protocol: str, data: bytes) -> None:
    assert_same([(0.0, data)], protocol)
    assert_same([(0.0, data), (0.01, _board(0) if protocol == "board" else _chassis(0))], protocol)
    assert_same([(i * 0.01, data[i : i + 1]) for i in range(len(data))], protocol)


def streams(protocol: str) -> st.SearchStrategy[list[tuple[float, bytes]]]:
    """Example frames, cut or corrupted ones, and noise rich in head bytes, in random
    chunks."""
    frames = [frame for frame, _ in profile(protocol).codec.examples]
    head = frames[0][:2]
    noise = st.binary(max_size=8) | st.lists(
        st.sampled_from([head[:1], head[1:], head, b"\x00", b"\x13", b"\x81", b"\xff"]),
        max_size=6,
    ).map(b"".join)
    frame = st.sampled_from(frames)
    cut = st.tuples(frame, st.integers(0, 30)).map(lambda p: p[0][: p[1]])
    flipped = st.tuples(frame, st.integers(0, 60), st.integers(1, 255)).map(
        lambda p: bytes(b ^ p[2] if i == p[1] % len(p[0]) else b for i, b in enumerate(p[0]))
    )
    piece = st.one_of(frame, frame, frame, noise, cut, flipped)

    def chunked(pair: tuple[bytes, list[int]]) -> list[tuple[float, bytes]]:
        data, cuts = pair
        edges = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
        return [(i * 0.01, data[a:b]) for i, (a, b) in enumerate(itertools.pairwise(edges))]

    data = st.lists(piece, max_size=30).map(b"".join)
    return st.tuples(data, st.lists(st.integers(0, 10_000), max_size=20)).map(chunked)


@pytest.mark.parametrize("protocol", PROTOCOLS)
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_random_noisy_streams_decode_the_same_both_ways(protocol: str, data: st.DataObject) -> None:
    assert_same(data.draw(streams(protocol)), protocol)


@pytest.mark.parametrize("protocol", PROTOCOLS)
@settings(max_examples=200, deadline=None)
@given(payload=st.binary(min_size=64, max_size=64))
def test_a_column_type_accepts_every_frame_that_checks_out(protocol: str, payload: bytes) -> None:
    """Columns never ask a parser, so a column type's parser must refuse nothing."""
    decoder = profile(protocol).codec.decoder()
    layout = type(decoder).layout
    assert layout is not None
    for kind in type(decoder).columns:
        size = type(decoder)._table[kind][0]
        total = size + layout.size_of_length if layout.fixed_is_length else size
        parser = type(decoder)._table[kind][1]
        data = payload[: total - layout.overhead]
        assert parser(bytes(layout.data_at) + data + bytes(8), layout.data_at, len(data), 0.0)


def write_jsonl(path: Path, rx: list[tuple[float, bytes]], tx: list[tuple[float, bytes]]) -> None:
    lines = [{"capture": 1, "port": "test"}]
    lines += [{"t": t, "data": d.hex()} for t, d in rx] + [{"t": t, "tx": d.hex()} for t, d in tx]
    path.write_text("".join(json.dumps(x) + "\n" for x in lines))


def session(seconds: float) -> tuple[list[tuple[float, bytes]], list[tuple[float, bytes]]]:
    """A chassis driving a circle: (received, sent), the simulator's firmware model."""
    from chassis_sdk.protocol import ChassisEncoder
    from chassis_sdk.sim import ChassisFirmware

    fw, enc = ChassisFirmware(), ChassisEncoder()
    fw.on_connect(0.0)
    rx, tx = [], []
    for step in range(int(seconds * 100)):
        t = step * 0.01
        if step % 5 == 0:
            frame = enc.drive_velocity(0.3, 0.2)
            fw.receive(frame, t)
            tx.append((t, frame))
        out = fw.poll(t)
        if out:
            rx.append((t, out))
    return rx, tx


def test_capture_columns_reads_a_jsonl_capture_both_ways(tmp_path: Path) -> None:
    rx, tx = session(3.0)
    path = tmp_path / "drive.jsonl"
    write_jsonl(path, rx, tx)
    cols = capture_columns(path, "chassis")
    assert len(cols["Telemetry"]["t"]) == 150  # 50 Hz for 3 s
    assert cols["Telemetry"]["linear"][-1] == pytest.approx(0.3, abs=0.01)
    assert cols.frames == len(streamed(rx, profile("chassis").codec.decoder()))
    sent = capture_columns(path, "chassis", commands=True)
    assert [type(m).__name__ for _, m in sent.messages] == ["DriveVelocity"] * len(tx)
    assert [t for t, _ in sent.messages] == [t for t, _ in tx]


def test_capture_columns_reads_an_mcap_recording(tmp_path: Path) -> None:
    from chassis_sdk import Chassis
    from chassis_sdk.recording import open_recording

    rx, _ = session(2.0)
    device: Any = Chassis("/dev/columns-test")
    path = tmp_path / "drive.mcap"
    recording = open_recording(path, device)
    for t, data in rx:
        device.feed(data, 100.0 + t)
    recording.close()
    cols = capture_columns(path, "chassis")
    assert len(cols["Telemetry"]["t"]) == 100
    assert np.all(np.diff(cols["Telemetry"]["seq"]) == 1)


def test_what_cannot_be_decoded_into_columns_is_a_clear_error(tmp_path: Path) -> None:
    class Unlaid(FrameDecoder[object]):
        _head = b"\xaa\x55"

    with pytest.raises(ValueError, match="Unlaid has no layout"):
        decode_columns([(0.0, b"\xaa\x55")], Unlaid())
    with pytest.raises(ValueError, match="add up to 3, not 2 bytes"):
        decode_joined(b"\x00\x01", [0.0], [3], profile("chassis").codec.decoder())
    assert decode_columns([], profile("board").codec.decoder()).frames == 0
    not_a_capture = tmp_path / "x.jsonl"
    not_a_capture.write_text("hello\n")
    with pytest.raises(ValueError, match="not a chassis-sdk capture"):
        capture_columns(not_a_capture, "chassis")
    chassis = profile("chassis")
    unlaid = DeviceProfile(
        name="unlaid",
        summary="a chassis whose decoder has no layout",
        recognised_by=chassis.recognised_by,
        device=chassis.device,
        firmware=chassis.firmware,
        codec=dataclasses.replace(chassis.codec, decoder=Unlaid),
    )
    with pytest.raises(ValueError, match="a plot needs both decoders' layout"):
        checked(unlaid, commands("chassis"))
    assert isinstance(chassis, DeviceProfile)
