"""Checks run on every fuzz input, for each of the four decoders.

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

from chassis_sdk.protocol import board as b
from chassis_sdk.protocol import chassis as a
from chassis_sdk.sim import BoardFirmware, ChassisFirmware

#: name -> (decoder factory, largest possible frame, i.e. buffer bound)
TARGETS: dict[str, tuple[Callable[[], Any], int]] = {
    "chassis": (a.ChassisDecoder, 256),
    "chassis-commands": (a.ChassisCommandDecoder, 256),
    # Protocol B holds up to three bytes past a frame whose end could start a head.
    "board": (b.BoardDecoder, 262),
    "board-commands": (b.BoardCommandDecoder, 262),
}


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
    factory, bound = TARGETS[target]
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
    """Valid frames of every kind the target decodes (each behind a chunk-seed byte),
    and all of them in one stream, so mutation starts past the checksums."""
    reads = [
        a.CommandId.FIRMWARE_VERSION,
        a.CommandId.HARDWARE_VERSION,
        a.CommandId.CHASSIS_INFO,
        a.CommandId.SHIP_DATE,
        a.CommandId.DRIVER_STATUS,
    ]
    enc = a.ChassisEncoder(7)
    benc = b.BoardEncoder()
    if target == "chassis":
        fw = ChassisFirmware()
        frames = [enc.encode(m) for m in (fw.telemetry(), fw.power(), fw.driver_status())]
        frames += [fw.receive(enc.read(c), 0.0) for c in reads]
        # The vendor document's 0x89 example, wrong length byte and all.
        frames.append(bytes.fromhex("EDDE000089 12 D502F401AA001E00E803 E505BDBC"))
    elif target == "chassis-commands":
        frames = [
            enc.encode(a.velocity_command(0.3, -0.2)),
            enc.encode(a.wheel_speeds_command(0.1, 0.2)),
            enc.set_telemetry(True),
            enc.emergency_stop(True),
            enc.clear_faults(a.FaultClear.DRIVER | a.FaultClear.FRONT_BUMPER),
            enc.docking(True),
            enc.set_power_telemetry(False),
            *(enc.read(c) for c in reads),
        ]
    elif target == "board":
        bfw = BoardFirmware()
        bfw.on_connect(0.0)
        frames = [bfw.poll(0.0)]  # a log line, IMU, velocity and battery
        frames.append(bfw.receive(benc.encode(b.LedCommand(b.SwitchAction.READ, 9)), 0.0))
        frames.append(bfw.receive(benc.encode(b.BuzzerCommand(b.SwitchAction.ON, 8)), 0.0))
    else:
        frames = [
            benc.encode(b.LedCommand(b.SwitchAction.ON, 1)),
            benc.encode(b.BuzzerCommand(b.SwitchAction.READ, 2)),
            benc.encode(b.velocity_command(0.2, 0.5)),
            benc.encode(b.motor_pwm_command(b.Motor.REAR_LEFT, -300)),
            benc.encode(b.servo_command(b.Servo(2), 45.0)),
        ]
    return [bytes((i,)) + f for i, f in enumerate(frames)] + [b"\x00" + b"".join(frames)]
