"""Phantom frames: protocol B frames that pass the one-byte checksum although line noise
made them, per MB of damaged stream, and the good frames recovered; with and without
the decoder's alignment check, in the same run.

    python benchmarks/phantoms.py [--quick]

A stream like the simulated board's (an IMU frame every tick, velocity every 5th,
battery every 20th) is damaged byte by byte with the simulator's fault model
(``chassis_sdk.sim.LineFaults``: inserted noise bytes, bit flips, lost bytes) and
decoded twice: fed as written (one chunk per tick, as a port delivers it) and in
random chunks of 1-200 bytes. A decoded frame that was never sent is a phantom. The
"before" column is the same decoder with ``check_alignment`` off: the framing alone.
"""

from __future__ import annotations

import argparse
import itertools
import platform
import random
import struct
from collections.abc import Iterable

from chassis_sdk.devices.board.protocol import DEVICE_HEAD, encode_frame
from chassis_sdk.protocol import BoardDecoder
from chassis_sdk.sim import LineFaults
from chassis_sdk.sim.server import FaultCounts, damage


class _FramingOnly(BoardDecoder):
    check_alignment = False


def board_ticks(n: int, seed: int = 1) -> list[list[bytes]]:
    """``n`` ticks of board output, each a list of frames written together."""
    rng = random.Random(seed)
    ticks = []
    for i in range(n):
        imu = struct.pack(
            "<9h",
            *(164 + rng.randrange(-20, 20), rng.randrange(-30, 30), rng.randrange(-30, 30)),
            *(rng.randrange(-50, 50) for _ in range(3)),
            *(300, -300, -420),
        )
        tick = [encode_frame(DEVICE_HEAD, 0x11, imu)]
        if i % 5 == 0:
            tick.append(encode_frame(DEVICE_HEAD, 0x12, struct.pack("<hh", 250, -500)))
        if i % 20 == 0:
            tick.append(encode_frame(DEVICE_HEAD, 0x13, struct.pack("<h", 1000 + i % 500)))
        ticks.append(tick)
    return ticks


def decode(decoder: BoardDecoder, chunks: Iterable[bytes]) -> list[str]:
    out: list[str] = []
    for chunk in chunks:
        out += map(repr, decoder.feed(chunk))
    return out


def measure(ticks: list[list[bytes]], faults: LineFaults) -> list[tuple[str, str, float, float]]:
    sent = set(decode(_FramingOnly(), [b"".join(f for tick in ticks for f in tick)]))
    counts = FaultCounts()
    damaged = [b"".join(damage(f, faults, counts) for f in tick) for tick in ticks]
    data = b"".join(damaged)
    rng = random.Random(9)
    cuts = [0]
    while cuts[-1] < len(data):
        cuts.append(cuts[-1] + rng.randint(1, 200))
    randomly = [data[a:b] for a, b in itertools.pairwise(cuts)]
    rows = []
    for how, chunks in (("as written", damaged), ("random chunks", randomly)):
        for name, factory in (("framing only", _FramingOnly), ("with alignment", BoardDecoder)):
            out = decode(factory(), chunks)
            phantoms = sum(m not in sent for m in out)
            good = len(set(out) & sent)
            rows.append((how, name, phantoms / (len(data) / 1e6), good / len(sent)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="a smaller stream (CI)")
    args = parser.parse_args()
    ticks = board_ticks(6_000 if args.quick else 60_000)
    print(f"machine: {platform.machine()}, Python {platform.python_version()}")
    models = {
        "noise 2%, flips 0.3%, drops 0.3%": LineFaults(
            noise_rate=0.02, bit_flip_rate=0.003, drop_rate=0.003, seed=3
        ),
        "noise 2% (inserted bytes)": LineFaults(noise_rate=0.02, seed=4),
        "drops 1% (lost bytes)": LineFaults(drop_rate=0.01, seed=5),
        "bit flips 1%": LineFaults(bit_flip_rate=0.01, seed=6),
    }
    print(f"{'damage':34} {'fed':14} {'decoder':15} {'phantoms/MB':>12} {'good frames':>12}")
    for label, faults in models.items():
        for how, name, per_mb, recovered in measure(ticks, faults):
            print(f"{label:34} {how:14} {name:15} {per_mb:12.1f} {recovered:12.2%}")


if __name__ == "__main__":
    main()
