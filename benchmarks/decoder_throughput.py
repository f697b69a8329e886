"""Decoder throughput for both protocols (frames/s and MB/s), median of several runs,
side by side with pymavlink in the same run.

    pip install ".[bench]"     # pymavlink, for the comparison
    python benchmarks/decoder_throughput.py

Measures the decoders of a whole capture into numpy columns (what ``plot`` uses), then
ChassisDecoder on 0x81 telemetry (28 bytes) and BoardDecoder on 0x11 IMU
frames (23 bytes), fed in 4 KiB chunks (what a busy port delivers) and one frame per
call (a quiet port), against the wire limit at 115200 baud (11,520 bytes/s, 8N1), and
pymavlink's MAVLink 2 parser on its 40-byte ATTITUDE message, fed the same way. The
ratios are taken within this run, so a busy machine slows both sides alike.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from chassis_sdk.protocol import (
    BoardDecoder,
    BoardEncoder,
    ChassisDecoder,
    ChassisEncoder,
    ChassisStatus,
    DockingState,
    ImuSample,
    Telemetry,
    Vector3,
    WheelSpeeds,
)

WIRE_BYTES_PER_S = 115200 / 10
RUNS = 7
N = 50_000


def chassis_stream() -> tuple[bytes, int]:
    enc = ChassisEncoder()
    t = Telemetry(24.6, ChassisStatus.REMOTE_OFFLINE, DockingState.SEARCHING, 0.3, -0.2,
                  WheelSpeeds(0.2, 0.4, 0.2, 0.4))  # fmt: skip
    frames = [enc.encode(t) for _ in range(N)]
    return b"".join(frames), len(frames[0])


def board_stream() -> tuple[bytes, int]:
    s = ImuSample(Vector3(0.01, -0.02, 1.0), Vector3(0.5, -0.5, 10.0), Vector3(300, -300, -420))
    frame = BoardEncoder().encode(s)
    return frame * N, len(frame)


def mavlink_stream() -> tuple[bytes, int] | None:
    try:
        from pymavlink.dialects.v20 import common as mavlink
    except ImportError:
        return None
    sender = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = mavlink.MAVLink_attitude_message(1000, 0.1, -0.2, 0.3, 0.01, 0.02, 0.03).pack(sender)
    return frame * N, len(frame)


class MavlinkDecoder:
    """pymavlink's parser behind the same ``feed`` call."""

    def __init__(self) -> None:
        from pymavlink.dialects.v20 import common as mavlink

        self._parser = mavlink.MAVLink(None)

    def feed(self, data: bytes) -> list[object]:
        return self._parser.parse_buffer(data) or []


def measure(make_decoder: Callable[[], Any], stream: bytes, chunk: int) -> float:
    """Seconds to decode the whole stream in chunks of `chunk` bytes."""
    chunks = [stream[i : i + chunk] for i in range(0, len(stream), chunk)]
    dec = make_decoder()
    t0 = time.perf_counter()
    n = 0
    for c in chunks:
        n += len(dec.feed(c))
    elapsed = time.perf_counter() - t0
    assert n == N, n
    return elapsed


def columns(cases: list[tuple[str, Callable[[], Any], tuple[bytes, int]]]) -> dict[str, float]:
    """A whole capture into arrays (numpy, ``capture_columns``) against the decoder
    one object per frame, on the same bytes, printed first."""
    try:
        from chassis_sdk.recording.columns import decode_joined
    except ImportError:
        print("numpy is not installed (pip install '.[columns]'): no column figures")
        return {}
    rates = {}
    for name, dec, (stream, _) in cases:
        objects = statistics.median(measure(dec, stream, 4096) for _ in range(RUNS))
        times = []
        for _ in range(RUNS):
            t0 = time.perf_counter()
            found = decode_joined(stream, [0.0], [len(stream)], dec())
            times.append(time.perf_counter() - t0)
            assert found.frames == N, found.frames
        secs = statistics.median(times)
        mb = len(stream) / secs / 1e6
        rates[name] = N / secs
        print(f"{name + ' columns':<20} {'whole':<11}{N / secs:>12,.0f}{mb:>8.1f}"
              f"{'':>14}  {objects / secs:.0f}x objects")  # fmt: skip
    return rates


def main() -> None:
    global RUNS, N
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer, shorter runs (for CI)")
    parser.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    args = parser.parse_args()
    if args.quick:
        RUNS, N = 3, 10_000
    cases: list[tuple[str, Callable[[], Any], tuple[bytes, int]]] = [
        ("chassis 0x81", ChassisDecoder, chassis_stream()),
        ("board 0x11", BoardDecoder, board_stream()),
    ]
    mav = mavlink_stream()
    if mav is not None:
        cases.append(("pymavlink ATTITUDE", MavlinkDecoder, mav))
    print(f"{'decoder':<20}{'chunking':<12}{'frames/s':>12}{'MB/s':>8}{'x wire limit':>14}")
    column_rates = columns(cases[:2])
    rates: dict[tuple[str, str], float] = {}
    for name, dec, (stream, size) in cases:
        for label, chunk in [("4 KiB", 4096), ("per frame", size)]:
            secs = statistics.median(measure(dec, stream, chunk) for _ in range(RUNS))
            fps = rates[name, label] = N / secs
            wire_fps = WIRE_BYTES_PER_S / size
            print(f"{name:<20}{label:<12}{fps:>12,.0f}{len(stream) / secs / 1e6:>8.1f}"
                  f"{fps / wire_fps:>14,.0f}")  # fmt: skip
    a, b = WIRE_BYTES_PER_S / 28, WIRE_BYTES_PER_S / 23
    print(f"(median of {RUNS} runs of {N:,} frames; wire limit at 115200 baud: "
          f"{a:.0f} frames/s of 0x81, {b:.0f} of 0x11)")  # fmt: skip
    ratios = {}
    if mav is None:
        print("pymavlink is not installed (pip install '.[bench]'): no comparison")
    for label in ("4 KiB", "per frame") if mav is not None else ():
        ratio = ratios[label] = rates["chassis 0x81", label] / rates["pymavlink ATTITUDE", label]
        print(f"protocol A decoder / pymavlink, {label}: {ratio:.2f}x (target >= 5x)")
    if args.json:
        report = {
            "frames_per_s": {f"{name} / {label}": fps for (name, label), fps in rates.items()},
            "columns_frames_per_s": column_rates,
            "vs_pymavlink": ratios,
        }
        Path(args.json).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
