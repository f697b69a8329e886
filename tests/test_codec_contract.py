"""The contract every codec keeps, checked on every registered device's decoders (both
directions) and on the toy device's, from the examples in their profiles.

In the style of h11's ``tr()``: each input is fed whole, one byte at a time, and with
trailing data; every proper prefix of a frame is "need more data" (nothing decoded,
nothing dropped); noise between frames is skipped and counted, never swallowing a frame;
a damaged frame decodes to nothing. A device's own codec tests hold the values (vendor
vectors, round trips); these hold the framing that every device shares.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pytest

from chassis_sdk.core import FrameDecoder
from chassis_sdk.devices import DeviceProfile, profiles

from .support.toy_device import PROFILE as TOY

pytestmark = pytest.mark.codec


@dataclass(frozen=True)
class Codec:
    name: str
    make: Callable[[], FrameDecoder[Any]]
    examples: tuple[tuple[bytes, object], ...]

    @property
    def head(self) -> bytes:
        return self.make()._head


def _codecs(devices: list[DeviceProfile]) -> list[Codec]:
    found = []
    for d in devices:
        found.append(Codec(d.name, d.codec.decoder, tuple(d.codec.examples)))
        found.append(
            Codec(f"{d.name}-commands", d.codec.command_decoder, tuple(d.codec.command_examples))
        )
    return found


CODECS = _codecs([*profiles().values(), TOY])
BY_CODEC = [pytest.param(c, id=c.name) for c in CODECS]
BY_EXAMPLE = [
    pytest.param(c, frame, msg, id=f"{c.name}-{type(msg).__name__}-{i}")
    for c in CODECS
    for i, (frame, msg) in enumerate(c.examples)
]


def feed_all(codec: Codec, chunks: list[bytes]) -> tuple[list[object], FrameDecoder[Any]]:
    decoder = codec.make()
    out: list[object] = []
    for chunk in chunks:
        out += decoder.feed(chunk)
    return out, decoder


def test_every_registered_device_is_covered() -> None:
    names = {c.name for c in CODECS}
    for name in [*profiles(), "toy"]:
        assert {name, f"{name}-commands"} <= names


@pytest.mark.parametrize("codec", BY_CODEC)
def test_whole_buffer_byte_by_byte_and_in_every_split(codec: Codec) -> None:
    stream = b"".join(frame for frame, _ in codec.examples)
    expected = [msg for _, msg in codec.examples]
    whole, decoder = feed_all(codec, [stream])
    assert whole == expected
    assert (decoder.stats.frames, decoder.stats.bytes_dropped, decoder.buffered) == (
        len(expected),
        0,
        0,
    )
    assert feed_all(codec, [bytes((b,)) for b in stream])[0] == expected
    for cut in range(1, len(stream)):
        assert feed_all(codec, [stream[:cut], stream[cut:]])[0] == expected


@pytest.mark.parametrize(("codec", "frame", "msg"), BY_EXAMPLE)
def test_every_proper_prefix_is_need_more_data(codec: Codec, frame: bytes, msg: object) -> None:
    for cut in range(1, len(frame)):
        decoder = codec.make()
        assert decoder.feed(frame[:cut]) == [], f"decoded from {cut} of {len(frame)} bytes"
        assert decoder.stats.bytes_dropped == 0
        assert decoder.feed(frame[cut:]) == [msg]


@pytest.mark.parametrize(("codec", "frame", "msg"), BY_EXAMPLE)
def test_trailing_data_waits_for_the_rest(codec: Codec, frame: bytes, msg: object) -> None:
    following, after = codec.examples[0]
    part = following[: len(following) // 2]
    decoder = codec.make()
    assert decoder.feed(frame + part) == [msg]
    assert decoder.buffered == len(part)
    assert decoder.feed(following[len(part) :]) == [after]
    assert decoder.buffered == 0


@pytest.mark.parametrize("codec", BY_CODEC)
def test_noise_between_frames_is_counted_and_swallows_nothing(codec: Codec) -> None:
    noise = bytes(b for b in range(256) if b not in codec.head)[:23]
    stream = b"".join(noise + frame for frame, _ in codec.examples) + noise
    out, decoder = feed_all(codec, [stream])
    assert out == [msg for _, msg in codec.examples]
    assert decoder.stats.bytes_dropped == len(noise) * (len(codec.examples) + 1)


@pytest.mark.parametrize("codec", BY_CODEC)
def test_a_lone_head_at_the_end_is_kept_for_the_next_chunk(codec: Codec) -> None:
    frame, msg = codec.examples[0]
    decoder = codec.make()
    assert decoder.feed(b"\x00" + codec.head[:1]) == []
    assert decoder.buffered == 1
    assert decoder.feed(codec.head[1:] + frame[2:]) == [msg]


def _damaged() -> list[Any]:
    """A readable table: each example with its last byte (a check or a tail) changed,
    with its head's second byte changed, and cut short then followed by a good frame."""
    cases = []
    for c in CODECS:
        for i, (frame, msg) in enumerate(c.examples):
            tag = f"{c.name}-{type(msg).__name__}-{i}"
            last = frame[:-1] + bytes((frame[-1] ^ 0x5A,))
            cases.append(pytest.param(c, last, id=f"{tag}-last-byte-changed"))
            head = frame[:1] + bytes((frame[1] ^ 0x01,)) + frame[2:]
            cases.append(pytest.param(c, head, id=f"{tag}-head-broken"))
    return cases


@pytest.mark.parametrize(("codec", "damaged"), _damaged())
def test_a_damaged_frame_decodes_to_nothing_and_hides_no_good_frame(
    codec: Codec, damaged: bytes
) -> None:
    good, msg = codec.examples[-1]
    out, decoder = feed_all(codec, [damaged + good])
    assert out == [msg]
    assert decoder.stats.bytes_dropped >= 1
