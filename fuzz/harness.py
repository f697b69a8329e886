"""Checks run on every fuzz input, for both decoders of every registered device.

Kept free of atheris so the test suite can run the same checks on a seeded corpus
(``tests/test_fuzz_harness.py``); ``fuzz/run.py`` drives them with atheris.

For an input ``data`` (the first byte seeds the chunk sizes) each check asserts:

* feeding never raises, whatever the bytes and however they are split;
* the result does not depend on the split: whole, byte at a time and in random
  chunks give the same messages and the same counters;
* the buffer stays within one maximal frame, and the counters add up
  (``bytes_dropped + buffered <= bytes_received == len(data)``).
"""

from __future__ import annotations

import random
from collections.abc import Callable
from typing import Any

from chassis_sdk.devices import profiles


def targets() -> dict[str, tuple[Callable[[], Any], int]]:
    """Every registered device's two decoders: name -> (decoder factory, the most bytes
    it may hold after ``feed``). ``NAME`` decodes what the device sends,
    ``NAME-commands`` what the host sends."""
    found: dict[str, tuple[Callable[[], Any], int]] = {}
    for name, device in profiles().items():
        found[name] = (device.codec.decoder, device.codec.max_buffered)
        found[f"{name}-commands"] = (device.codec.command_decoder, device.codec.max_buffered)
    return found


def _decode(factory: Callable[[], Any], data: bytes, sizes: list[int]) -> tuple[list[Any], Any]:
    dec = factory()
    out: list[Any] = []
    pos = 0
    for size in sizes:
        out += dec.feed(data[pos : pos + size])
        pos += size
    out += dec.feed(data[pos:])
    return out, dec


def check(target: str, blob: bytes) -> None:
    """Run every check of ``target`` on one input."""
    factory, bound = targets()[target]
    if not blob:
        return
    rng = random.Random(blob[0])
    data = blob[1:]
    whole, dec = _decode(factory, data, [])
    assert dec.buffered <= bound, (dec.buffered, bound)
    stats = dec.stats
    assert stats.bytes_received == len(data)
    assert stats.bytes_dropped + dec.buffered <= len(data)
    assert stats.frames == len(whole)
    for sizes in ([1] * len(data), [rng.randint(1, 40) for _ in range(len(data) // 8 + 1)]):
        parts, dec2 = _decode(factory, data, sizes)
        assert parts == whole, "the split changed the messages"
        assert dec2.stats == stats, "the split changed the counters"
        assert dec2.buffered == dec.buffered


def seeds(target: str) -> list[bytes]:
    """Valid frames of every kind the target decodes (the device profile's examples),
    each behind a chunk-seed byte, and all of them in one stream, so mutation starts
    past the checksums."""
    name, _, direction = target.partition("-")
    device = profiles()[name]
    examples = device.codec.command_examples if direction else device.codec.examples
    frames = [frame for frame, _ in examples]
    return [bytes((i,)) + f for i, f in enumerate(frames)] + [b"\x00" + b"".join(frames)]
