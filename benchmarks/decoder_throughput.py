"""Decoder throughput for both protocols (frames/s and MB/s), median of several runs.

    python benchmarks/decoder_throughput.py

Measures ChassisDecoder on 0x81 telemetry and BoardDecoder on 0x11 IMU frames, fed in
4 KiB chunks (what a busy port delivers) and one frame per call (a quiet port), and
compares with the wire limit at 115200 baud (11,520 bytes/s, 8N1).
"""

from __future__ import annotations

import statistics
import time

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


def measure(make_decoder: type, stream: bytes, chunk: int) -> float:
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


def main() -> None:
    print(f"{'decoder':<16}{'chunking':<12}{'frames/s':>12}{'MB/s':>8}{'x wire limit':>14}")
    for name, dec, (stream, size) in [
        ("chassis 0x81", ChassisDecoder, chassis_stream()),
        ("board 0x11", BoardDecoder, board_stream()),
    ]:
        for label, chunk in [("4 KiB", 4096), ("per frame", size)]:
            secs = statistics.median(measure(dec, stream, chunk) for _ in range(RUNS))
            fps = N / secs
            wire_fps = WIRE_BYTES_PER_S / size
            print(f"{name:<16}{label:<12}{fps:>12,.0f}{len(stream) / secs / 1e6:>8.1f}"
                  f"{fps / wire_fps:>14,.0f}")  # fmt: skip
    a, b = WIRE_BYTES_PER_S / 28, WIRE_BYTES_PER_S / 23
    print(f"(median of {RUNS} runs of {N:,} frames; wire limit at 115200 baud: "
          f"{a:.0f} frames/s of 0x81, {b:.0f} of 0x11)")  # fmt: skip


if __name__ == "__main__":
    main()
