"""Latency as an application feels it, over a real pty, against a firmware process.

    python benchmarks/latency.py            # both transports, side by side
    python benchmarks/latency.py --backend pyserial-asyncio --json   # one, as JSON

Three figures, each p50 and p99 (and max):

* **write -> async for**: from the firmware process's ``os.write`` of a 0x81 frame to
  the application's ``async for`` body receiving it (2,000 frames at 200 Hz); and the
  part of it from the moment the read callback had the bytes (``Telemetry.timestamp``;
  the floor's callback reads the clock first too) to the ``async for`` body: what the
  process itself adds, apart from the kernel and the wake-up;
* **round trip**: ``await robot.get_firmware_version()``, 2,000 in a row, and the
  application process's CPU time per call (``time.process_time()``: steadier on a
  shared machine than the wall-clock percentiles);
* **watchdog jitter**: how far each resend of a held ``set_velocity`` arrives from the
  ``resend_interval`` (20 ms here) after the one before, measured where the firmware
  reads it, while 50 Hz telemetry is being consumed (300 intervals).

Both processes read ``time.monotonic()`` (CLOCK_MONOTONIC, one clock per machine).

The **floor** is measured in the same run, against the same firmware process on a pty
of its own: asyncio's ``add_reader`` and one ``os.read`` per wake-up, frames cut at
their known size with no check and no decoding, and a task woken by a future: the
least an asyncio application can do to see a frame in a task, or to send a request and
see its reply. Every SDK figure is printed with its ratio to the floor.
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


class _Firmware:
    """The firmware process (benchmarks/_firmware.py) on the master side of a new pty."""

    def __init__(self) -> None:
        self.proc: asyncio.subprocess.Process | None = None
        self.slave = -1

    async def __aenter__(self) -> _Firmware:
        master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.proc = await asyncio.create_subprocess_exec(
            sys.executable, str(FIRMWARE), str(master), pass_fds=(master,),
            stdin=subprocess.PIPE, stdout=subprocess.PIPE,
        )  # fmt: skip
        os.close(master)
        return self

    async def ask(self, line: str) -> list[float]:
        assert self.proc is not None
        assert self.proc.stdin is not None
        assert self.proc.stdout is not None
        self.proc.stdin.write(line.encode() + b"\n")
        await self.proc.stdin.drain()
        result: list[float] = json.loads(await self.proc.stdout.readline())
        return result

    async def __aexit__(self, *exc: object) -> None:
        assert self.proc is not None
        assert self.proc.stdin is not None
        self.proc.stdin.write(b"quit\n")
        await self.proc.wait()
        os.close(self.slave)


async def measure_floor() -> dict[str, object]:
    """The same two figures with the least an asyncio application can do (see above)."""
    from chassis_sdk.protocol import ChassisEncoder, Command, CommandId

    loop = asyncio.get_running_loop()
    async with _Firmware() as fw:
        fd = fw.slave
        os.set_blocking(fd, False)
        pending = bytearray()
        seqs: list[int] = []
        waiter: asyncio.Future[None] | None = None

        read_at: dict[int, float] = {}

        def readable() -> None:
            nonlocal waiter
            now = time.monotonic()
            pending.extend(os.read(fd, 4096))
            while (len(pending) >= 12 and pending[4] == 0x87) or len(pending) >= 28:
                size = 12 if pending[4] == 0x87 else 28
                seq = pending[2] | pending[3] << 8
                seqs.append(seq)
                read_at[seq] = now
                del pending[:size]
            if seqs and waiter is not None and not waiter.done():
                waiter.set_result(None)

        loop.add_reader(fd, readable)
        try:
            arrived: dict[int, float] = {}
            written = asyncio.ensure_future(fw.ask(f"stream {N_FRAMES} 0.005"))
            while len(arrived) < N_FRAMES and (N_FRAMES - 1) not in arrived:
                waiter = loop.create_future()
                await waiter
                now = time.monotonic()
                for seq in seqs:
                    arrived[seq] = now
                seqs.clear()
            sent = await written
            latency = [arrived[i] - sent[i] for i in range(N_FRAMES) if i in arrived]
            inside = [arrived[i] - read_at[i] for i in range(N_FRAMES) if i in arrived]
            request = ChassisEncoder().encode(Command(CommandId.FIRMWARE_VERSION))
            rtt = []
            cpu = time.process_time()
            for _ in range(N_REQUESTS):
                t0 = time.perf_counter()
                waiter = loop.create_future()
                os.write(fd, request)
                await waiter
                seqs.clear()
                rtt.append(time.perf_counter() - t0)
            cpu = time.process_time() - cpu
        finally:
            loop.remove_reader(fd)
    return {"backend": "floor", "latency": summary(latency), "inside": summary(inside),
            "round_trip": summary(rtt),
            "round_trip_cpu_us": cpu / N_REQUESTS * 1e6,
            "frames_lost": N_FRAMES - len(latency)}  # fmt: skip


async def measure() -> dict[str, object]:
    from chassis_sdk import Chassis

    async with (
        _Firmware() as fw,
        Chassis(os.ttyname(fw.slave), resend_interval=RESEND) as robot,
    ):
        # 1. firmware write -> async for
        arrived: dict[int, float] = {}
        read_at: dict[int, float] = {}
        sub = robot.telemetry()
        written = asyncio.ensure_future(fw.ask(f"stream {N_FRAMES} 0.005"))
        async for t in sub:
            arrived[t.seq] = time.monotonic()
            read_at[t.seq] = t.timestamp  # taken as the read callback got the bytes
            if t.seq == N_FRAMES - 1:
                break
        sent = await written
        latency = [arrived[i] - sent[i] for i in range(N_FRAMES) if i in arrived]
        inside = [arrived[i] - read_at[i] for i in range(N_FRAMES) if i in arrived]

        # 2. request round trip
        rtt = []
        cpu = time.process_time()
        for _ in range(N_REQUESTS):
            t0 = time.perf_counter()
            await robot.get_firmware_version()
            rtt.append(time.perf_counter() - t0)
        cpu = time.process_time() - cpu

        # 3. watchdog resend jitter, with 50 Hz telemetry being consumed meanwhile
        await fw.ask("drives")
        hold = RESEND * (N_RESENDS + 1) + 0.01
        streaming = asyncio.ensure_future(fw.ask(f"stream {int(hold / 0.02) + 5} 0.02"))

        async def consume() -> None:
            async for _ in robot.telemetry():
                pass

        consumer = asyncio.ensure_future(consume())
        await robot.set_velocity(0.1, 0.0, duration=hold)
        await streaming
        drives = await fw.ask("drives")
        consumer.cancel()
        intervals = [b - a for a, b in itertools.pairwise(drives)][:N_RESENDS]
        jitter = [abs(i - RESEND) for i in intervals]
        backend = robot.transport_backend
        lost = N_FRAMES - len(latency)
    return {
        "backend": backend,
        "latency": summary(latency),
        "inside": summary(inside),
        "frames_lost": lost,
        "round_trip": summary(rtt),
        "round_trip_cpu_us": cpu / N_REQUESTS * 1e6,
        "jitter": summary(jitter),
    }


def run_one(backend: str, loop: str) -> dict[str, object]:
    env = dict(os.environ, CHASSIS_SDK_BACKEND=backend if backend != "floor" else "")
    out = subprocess.run(
        [sys.executable, __file__, "--backend", backend, "--loop", loop, "--json", *QUICK],
        env=env, check=True, capture_output=True, text=True,
    )  # fmt: skip
    result: dict[str, object] = json.loads(out.stdout)
    result["loop"] = loop
    return result


def main() -> None:
    from chassis_sdk.core.run import loop_factory

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--backend", choices=["floor", *BACKENDS])
    parser.add_argument("--loop", choices=["asyncio", "uvloop"], help="default: both")
    parser.add_argument("--json", action="store_true", help="print one backend's figures as JSON")
    parser.add_argument("--json-file", metavar="FILE", help="also write every figure to FILE")
    parser.add_argument("--quick", action="store_true", help="fewer samples (for CI)")
    args = parser.parse_args()
    if args.quick:
        global N_FRAMES, N_REQUESTS, N_RESENDS
        QUICK.append("--quick")
        N_FRAMES, N_REQUESTS, N_RESENDS = 300, 300, 50
    if args.json:
        if args.backend and args.backend != "floor":
            os.environ["CHASSIS_SDK_BACKEND"] = args.backend
        job = measure_floor() if args.backend == "floor" else measure()
        with asyncio.Runner(loop_factory=loop_factory(args.loop == "uvloop")) as runner:
            print(json.dumps(runner.run(job)))
        return
    backends = [args.backend] if args.backend else BACKENDS
    loops = [args.loop] if args.loop else ["asyncio"] + (["uvloop"] if loop_factory() else [])
    report: dict[str, object] = {}
    for loop in loops:
        floor = run_one("floor", loop)
        results = []
        for backend in backends:
            try:
                results.append(run_one(backend, loop))
            except subprocess.CalledProcessError as exc:
                print(f"{backend}: not measured ({exc.stderr.strip().splitlines()[-1]})")
        report[loop] = {"floor": floor, "sdk": results}
        print(f"\n{loop} loop: ms, and each SDK figure's ratio to the floor")
        print(f"{'figure (ms)':<28}{'floor':>10}" + "".join(f"{r['backend']:>24}" for r in results))
        for key, label in [
            ("latency", "write -> async for"),
            ("inside", "  read -> async for"),
            ("round_trip", "round trip 0x07 -> 0x87"),
            ("jitter", "watchdog jitter"),
        ]:
            for q in ("p50", "p99") if key == "inside" else ("p50", "p99", "max"):
                base = floor.get(key)
                cells = f"{base[q]:>10.3f}" if isinstance(base, dict) else f"{'':>10}"
                for r in results:
                    value = r[key][q]  # type: ignore[index]
                    ratio = f" ({value / base[q]:.2f}x)" if isinstance(base, dict) else ""
                    cells += f"{f'{value:.3f}{ratio}':>24}"
                print(f"{label + ' ' + q:<28}{cells}")
            if key == "round_trip":
                base_cpu = float(floor["round_trip_cpu_us"])  # type: ignore[arg-type]
                cells = f"{base_cpu / 1e3:>10.3f}"
                for r in results:
                    value = float(r["round_trip_cpu_us"]) / 1e3  # type: ignore[arg-type]
                    cells += f"{f'{value:.3f} ({value * 1e3 / base_cpu:.2f}x)':>24}"
                print(f"{label + ' CPU':<28}{cells}")
    print(f"({N_FRAMES} frames at 200 Hz, {N_REQUESTS} requests, {N_RESENDS} resends at "
          f"{RESEND * 1e3:.0f} ms; a firmware process on a pty; floor: add_reader + os.read, "
          "frames cut by size, a future per wake-up; target p99 <= 2 ms)")  # fmt: skip
    if args.json_file:
        Path(args.json_file).write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
