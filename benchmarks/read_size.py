"""What one ``os.read`` of a telemetry frame costs, by the size asked for.

    python benchmarks/read_size.py           # a table
    python benchmarks/read_size.py --json    # the figures as JSON

A read allocates a buffer of the size asked for and shrinks it to what arrived. Past
glibc's mmap threshold (128 KiB by default) the allocation is a fresh mapping, every
time: serialx asks for 256 KiB per wake-up, so the SDK sets it to
:data:`chassis_sdk.core.transport.READ_SIZE` (64 KiB). Each figure is one ``os.write``
of a 24-byte frame into a pty and one ``os.read`` of it, in microseconds, beside the
floor measured in the same run: the same with a 1 KiB read (pyserial-asyncio's size).
Every measurement runs in a fresh process, as a new application's reads do: glibc
raises its threshold when a large *mapped* block is freed, so what a process did before
changes the figure. In the SDK's own processes it stayed low: under ``strace -f -c``,
``latency.py --backend serialx --quick`` made 660 ``mmap`` + ``mremap`` + ``munmap``
triples (one per read) at 256 KiB and none at 64 KiB, and measured 70 us more per
round trip at p50. Rounds alternate between sizes so
that the machine's load falls on all of them alike.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import tty

FLOOR = 1024
SERIALX = 256 * 1024
FRAME = bytes(24)


def per_read(master: int, slave: int, size: int, n: int) -> float:
    """Microseconds per write + read of one frame with reads of ``size``."""
    t0 = time.perf_counter()
    for _ in range(n):
        os.write(master, FRAME)
        os.read(slave, size)
    return (time.perf_counter() - t0) / n * 1e6


def child(size: int, n: int) -> None:
    """One measurement, in this fresh process (which imports nothing more: an import
    can free a large block and raise the threshold): print microseconds per read."""
    master, slave = os.openpty()
    tty.setraw(slave)
    print(per_read(master, slave, size, n))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("-n", type=int, default=5000, help="reads per size per round")
    parser.add_argument("--child", type=int, metavar="SIZE", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.n)
        return
    from chassis_sdk.core.transport import READ_SIZE

    sizes = [FLOOR, 16 * 1024, READ_SIZE, 128 * 1024, SERIALX]
    samples: dict[int, list[float]] = {size: [] for size in sizes}
    for _ in range(args.rounds):
        for size in sizes:
            cmd = [sys.executable, __file__, "--child", str(size), "-n", str(args.n)]
            out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
            samples[size].append(float(out))
    figures = {size: statistics.median(s) for size, s in samples.items()}
    floor = figures[FLOOR]
    if args.json:
        print(json.dumps({"floor_us": floor, "us": {str(k): v for k, v in figures.items()}}))
        return
    print(f"{'read size':>10} {'us per read':>12} {'vs floor':>9}")
    for size, us in figures.items():
        note = "  (floor)" if size == FLOOR else "  (serialx default)" if size == SERIALX else ""
        note = "  (the SDK's)" if size == READ_SIZE else note
        print(f"{size:>10} {us:>12.2f} {us / floor:>8.2f}x{note}")
    print(
        f"(median of {args.rounds} rounds of {args.n} write + read pairs of a 24-byte "
        "frame on a pty, each in a fresh process)"
    )


if __name__ == "__main__":
    main()
