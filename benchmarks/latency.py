"""Latency as an application feels it, over a real pty, against a firmware process.

    python benchmarks/latency.py            # both transports, side by side
    python benchmarks/latency.py --backend pyserial-asyncio --json   # one, as JSON

Three figures, each p50 and p99 (and max):

* **write -> async for**: from the firmware process's ``os.write`` of a 0x81 frame to
  the application's ``async for`` body receiving it (2,000 frames at 200 Hz);
* **round trip**: ``await robot.get_firmware_version()``, 2,000 in a row;
* **watchdog jitter**: how far each resend of a held ``set_velocity`` arrives from the
  ``resend_interval`` (20 ms here) after the one before, measured where the firmware
  reads it, while 50 Hz telemetry is being consumed (300 intervals).

Both processes read ``time.monotonic()`` (CLOCK_MONOTONIC, one clock per machine).
"""

from __future__ import annotations

import argparse
import asyncio
import itertools
import json
import os
import statistics
import subprocess
import sys
import time
import tty
from pathlib import Path

FIRMWARE = Path(__file__).with_name("_firmware.py")
BACKENDS = ["pyserial-asyncio", "pyserial-asyncio-fast", "serialx"]
N_FRAMES = 2000
N_REQUESTS = 2000
RESEND = 0.02
N_RESENDS = 300
QUICK: list[str] = []


def summary(samples: list[float]) -> dict[str, float]:
    """p50, p99 and max, in milliseconds."""
    q = statistics.quantiles(samples, n=100, method="inclusive")
    return {"p50": q[49] * 1e3, "p99": q[98] * 1e3, "max": max(samples) * 1e3, "n": len(samples)}


async def measure() -> dict[str, object]:
    from chassis_sdk import Chassis

    master, slave = os.openpty()
    tty.setraw(slave)
    proc = await asyncio.create_subprocess_exec(
        sys.executable, str(FIRMWARE), str(master), pass_fds=(master,),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE,
    )  # fmt: skip
    os.close(master)
    assert proc.stdin is not None
    assert proc.stdout is not None

    async def ask(line: str) -> list[float]:
        assert proc.stdin is not None
        assert proc.stdout is not None
        proc.stdin.write(line.encode() + b"\n")
        await proc.stdin.drain()
        result: list[float] = json.loads(await proc.stdout.readline())
        return result

    try:
        async with Chassis(os.ttyname(slave), resend_interval=RESEND) as robot:
            # 1. firmware write -> async for
            arrived: dict[int, float] = {}
            sub = robot.telemetry()
            written = asyncio.ensure_future(ask(f"stream {N_FRAMES} 0.005"))
            async for t in sub:
                arrived[t.seq] = time.monotonic()
                if t.seq == N_FRAMES - 1:
                    break
            sent = await written
            latency = [arrived[i] - sent[i] for i in range(N_FRAMES) if i in arrived]

            # 2. request round trip
            rtt = []
            for _ in range(N_REQUESTS):
                t0 = time.perf_counter()
                await robot.get_firmware_version()
                rtt.append(time.perf_counter() - t0)

            # 3. watchdog resend jitter, with 50 Hz telemetry being consumed meanwhile
            await ask("drives")
            hold = RESEND * (N_RESENDS + 1) + 0.01
            streaming = asyncio.ensure_future(ask(f"stream {int(hold / 0.02) + 5} 0.02"))

            async def consume() -> None:
                async for _ in robot.telemetry():
                    pass

            consumer = asyncio.ensure_future(consume())
            await robot.set_velocity(0.1, 0.0, duration=hold)
            await streaming
            drives = await ask("drives")
            consumer.cancel()
            intervals = [b - a for a, b in itertools.pairwise(drives)][:N_RESENDS]
            jitter = [abs(i - RESEND) for i in intervals]
            backend = robot.transport_backend
            lost = N_FRAMES - len(latency)
    finally:
        assert proc.stdin is not None
        proc.stdin.write(b"quit\n")
        await proc.wait()
        os.close(slave)
    return {
        "backend": backend,
        "latency": summary(latency),
        "frames_lost": lost,
        "round_trip": summary(rtt),
        "jitter": summary(jitter),
    }


def run_one(backend: str) -> dict[str, object]:
    env = dict(os.environ, CHASSIS_SDK_BACKEND=backend)
    out = subprocess.run(
        [sys.executable, __file__, "--backend", backend, "--json", *QUICK],
        env=env, check=True, capture_output=True, text=True,
    )  # fmt: skip
    result: dict[str, object] = json.loads(out.stdout)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", choices=BACKENDS)
    parser.add_argument("--json", action="store_true", help="print one backend's figures as JSON")
    parser.add_argument("--quick", action="store_true", help="fewer samples (for CI)")
    args = parser.parse_args()
    if args.quick:
        global N_FRAMES, N_REQUESTS, N_RESENDS
        QUICK.append("--quick")
        N_FRAMES, N_REQUESTS, N_RESENDS = 300, 300, 50
    if args.json:
        if args.backend:
            os.environ["CHASSIS_SDK_BACKEND"] = args.backend
        print(json.dumps(asyncio.run(measure())))
        return
    backends = [args.backend] if args.backend else BACKENDS
    results = []
    for backend in backends:
        try:
            results.append(run_one(backend))
        except subprocess.CalledProcessError as exc:
            print(f"{backend}: not measured ({exc.stderr.strip().splitlines()[-1]})")
    print(f"{'figure (ms)':<28}" + "".join(f"{r['backend']:>24}" for r in results))
    for key, label in [
        ("latency", "write -> async for"),
        ("round_trip", "round trip 0x07 -> 0x87"),
        ("jitter", "watchdog jitter"),
    ]:
        for q in ("p50", "p99", "max"):
            cells = "".join(f"{r[key][q]:>24.3f}" for r in results)  # type: ignore[index]
            print(f"{label + ' ' + q:<28}{cells}")
    print(f"({N_FRAMES} frames at 200 Hz, {N_REQUESTS} requests, {N_RESENDS} resends at "
          f"{RESEND * 1e3:.0f} ms; a firmware process on a pty; target p99 <= 2 ms)")  # fmt: skip


if __name__ == "__main__":
    main()
