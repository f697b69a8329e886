"""CPU share and memory of the SDK process with 1, 8 and 32 chassis on one event loop,
each streaming full 50 Hz telemetry into an ``async for`` loop.

    python benchmarks/load.py             # 1, 8, 32 chassis, both transports
    python benchmarks/load.py --n 8 --backend pyserial-asyncio --json

The simulators run in another process (``_simulators.py``), so the figures are the
SDK's alone: CPU is ``time.process_time()`` over ``time.monotonic()`` during a
10-second window after a 1-second warm-up (100 % = one core); memory is the growth of
the process's resident set from before the first ``Chassis`` to the end of the window.
Each configuration runs in a fresh process. The "floor" rows read the same streams with
nothing but ``os.read``: the cost of the wake-ups themselves on this machine, which no
reader can go below.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

SIMULATORS = Path(__file__).with_name("_simulators.py")
BACKENDS = ["pyserial-asyncio", "pyserial-asyncio-fast", "serialx"]
COUNTS = [1, 8, 32]
WINDOW = 10.0
QUICK: list[str] = []


def rss_bytes() -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


async def start_simulators(n: int) -> tuple[asyncio.subprocess.Process, list[str]]:
    """Start ``_simulators.py`` with ``n`` chassis; return it and their ports."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(SIMULATORS), str(n),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
    )  # fmt: skip
    assert proc.stdout is not None
    return proc, [(await proc.stdout.readline()).decode().strip() for _ in range(n)]


async def measure_floor(n: int) -> dict[str, object]:
    """The same streams read by the least any reader can do: ``loop.add_reader`` and
    ``os.read``, no parsing. What this machine charges for the wake-ups alone."""
    proc, ports = await start_simulators(n)
    assert proc.stdin is not None
    loop = asyncio.get_running_loop()
    fds = [os.open(p, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK) for p in ports]
    try:
        for fd in fds:
            loop.add_reader(fd, os.read, fd, 4096)
        await asyncio.sleep(1.0)
        c0, t0 = time.process_time(), time.monotonic()
        await asyncio.sleep(WINDOW)
        cpu = (time.process_time() - c0) / (time.monotonic() - t0) * 100
    finally:
        for fd in fds:
            loop.remove_reader(fd)
            os.close(fd)
        proc.stdin.close()
        await proc.wait()
    return {"backend": "raw os.read", "chassis": n, "cpu_percent": cpu}


async def measure(n: int) -> dict[str, object]:
    from chassis_sdk import Chassis

    proc, ports = await start_simulators(n)
    assert proc.stdin is not None
    base = rss_bytes()
    frames = [0] * n

    async def consume(i: int, robot: Chassis) -> None:
        async for _ in robot.telemetry():
            frames[i] += 1

    try:
        async with contextlib.AsyncExitStack() as stack:
            robots = [await stack.enter_async_context(Chassis(p)) for p in ports]
            tasks = [asyncio.ensure_future(consume(i, r)) for i, r in enumerate(robots)]
            await asyncio.sleep(1.0)
            f0, c0, t0 = sum(frames), time.process_time(), time.monotonic()
            await asyncio.sleep(WINDOW)
            f1, c1, t1 = sum(frames), time.process_time(), time.monotonic()
            rss = rss_bytes()
            for task in tasks:
                task.cancel()
            backend = robots[0].transport_backend
            drops = sum(r.stats.queue_drops + r.stats.sequence_gaps for r in robots)
    finally:
        proc.stdin.close()
        await proc.wait()
    cpu = (c1 - c0) / (t1 - t0) * 100
    return {
        "backend": backend,
        "chassis": n,
        "cpu_percent": cpu,
        "cpu_percent_per_chassis": cpu / n,
        "frames_per_s": (f1 - f0) / (t1 - t0),
        "rss_growth_mb": (rss - base) / 1e6,
        "rss_per_chassis_kb": (rss - base) / n / 1e3,
        "lost": drops,
    }


def run_one(n: int, backend: str) -> dict[str, object]:
    out = subprocess.run(
        [sys.executable, __file__, "--n", str(n), "--backend", backend, "--json", *QUICK],
        env=dict(os.environ, CHASSIS_SDK_BACKEND=backend),
        check=True, capture_output=True, text=True,
    )  # fmt: skip
    result: dict[str, object] = json.loads(out.stdout)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, help="number of chassis (default: 1, 8 and 32)")
    parser.add_argument("--backend", choices=BACKENDS)
    parser.add_argument("--json", action="store_true", help="one configuration, as JSON")
    parser.add_argument("--floor", action="store_true", help="(with --json) the raw reader")
    parser.add_argument("--quick", action="store_true", help="1 and 8 chassis, 3 s (for CI)")
    args = parser.parse_args()
    if args.quick:
        global WINDOW
        WINDOW = 3.0
        COUNTS[:] = [1, 8]
        QUICK.append("--quick")
    if args.json:
        job = measure_floor(args.n or 1) if args.floor else measure(args.n or 1)
        print(json.dumps(asyncio.run(job)))
        return
    print(f"{'transport':<24}{'chassis':>8}{'CPU %':>8}{'% each':>8}{'frames/s':>10}"
          f"{'RSS +MB':>9}{'KB each':>9}{'lost':>6}")  # fmt: skip
    for backend in [args.backend] if args.backend else BACKENDS:
        for n in [args.n] if args.n else COUNTS:
            try:
                r = run_one(n, backend)
            except subprocess.CalledProcessError as exc:
                print(f"{backend}: not measured ({exc.stderr.strip().splitlines()[-1]})")
                break
            print(f"{backend:<24}{n:>8}{r['cpu_percent']:>8.2f}{r['cpu_percent_per_chassis']:>8.2f}"
                  f"{r['frames_per_s']:>10.0f}{r['rss_growth_mb']:>9.1f}"
                  f"{r['rss_per_chassis_kb']:>9.0f}{r['lost']:>6}")  # fmt: skip
    for n in [args.n] if args.n else COUNTS:
        out = subprocess.run(
            [sys.executable, __file__, "--n", str(n), "--json", "--floor", *QUICK],
            check=True, capture_output=True, text=True,
        )  # fmt: skip
        r = json.loads(out.stdout)
        print(f"{'floor: raw os.read':<24}{n:>8}{r['cpu_percent']:>8.2f}"
              f"{r['cpu_percent'] / n:>8.2f}")  # fmt: skip
    print(
        f"(50 Hz telemetry per chassis into an async for; {WINDOW:.0f} s window; "
        "100 % = one core; target <= 1 % per chassis, 32 chassis <= 25 %)"
    )


if __name__ == "__main__":
    main()
