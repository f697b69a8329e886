"""A fleet on a real mosquitto: N simulated chassis, each bridged, all bridges in one
process.

    python benchmarks/mqtt_fleet.py [--quick]      # N = 1, 10, 50 (quick: 1, 10)

For each N, the simulators run in this process and the bridges in a child process
(``_bridges.py``), with mosquitto on loopback between them. Printed per N:

* telemetry delivered: ``telemetry/telemetry`` messages per second an observer receives,
  against the expected ``N x rate`` (the bridge sends the latest at most ``rate`` times
  a second per stream, never a backlog);
* command to wire: from publishing ``cmd/velocity`` to the simulator reading the 0x02
  frame on its pty (both clocks in this process), p50 / p99 / max in ms;
* the bridge process's CPU (100 % = one core), from /proc over the window.

The floor beside them: the same observer's round trip through mosquitto alone (publish
and receive on loopback), p50 / p99 in ms.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

import aiomqtt

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator
from tests.support.mqtt_broker import Mosquitto

BRIDGES = Path(__file__).with_name("_bridges.py")
RATE = 10.0


def cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, round(q * (len(ordered) - 1)))]


async def floor(port: int, n: int) -> tuple[float, float]:
    """Round trip through the broker alone: publish, receive, on one client."""
    async with aiomqtt.Client("127.0.0.1", port, identifier="floor") as client:
        await client.subscribe("floor/echo")
        times = []
        for _ in range(n):
            sent = time.monotonic()
            await client.publish("floor/echo", b"x")
            await anext(client.messages)
            times.append((time.monotonic() - sent) * 1000)
    return statistics.median(times), percentile(times, 0.99)


async def measure(port: int, n: int, window: float, commands: int) -> dict[str, float]:
    sims = [ChassisSimulator() for _ in range(n)]
    async with contextlib.AsyncExitStack() as stack:
        for sim in sims:
            await stack.enter_async_context(sim)
        child = subprocess.Popen(  # noqa: ASYNC220 (started, then killed)
            [sys.executable, str(BRIDGES), str(port), str(RATE), *(s.port for s in sims)],
            stdout=subprocess.PIPE,
        )
        stack.callback(child.wait)
        stack.callback(child.kill)
        assert child.stdout is not None
        ready = await asyncio.to_thread(child.stdout.readline)
        assert ready.strip() == b"ready", ready
        async with aiomqtt.Client("127.0.0.1", port, identifier="observer") as obs:
            await obs.subscribe("robots/+/telemetry/telemetry")
            received = 0

            async def count() -> None:
                nonlocal received
                async for _ in obs.messages:
                    received += 1

            counter = asyncio.create_task(count())
            await asyncio.sleep(1.0)  # warm-up
            received, cpu0, t0 = 0, cpu_seconds(child.pid), time.monotonic()
            await asyncio.sleep(window)
            elapsed = time.monotonic() - t0
            delivered, cpu = received / elapsed, (cpu_seconds(child.pid) - cpu0) / elapsed
            counter.cancel()
            latencies = []
            for i in range(commands):
                k = i % n
                mm = 100 + i % 200  # a value the previous command did not have
                frames = sims[k].firmware.received
                sent = time.monotonic()
                body = json.dumps({"linear": mm / 1000, "angular": 0.0}).encode()
                await obs.publish(f"robots/r{k}/cmd/velocity", body)
                while True:
                    hit = [
                        t
                        for t, c in frames
                        if isinstance(c, DriveVelocity) and c.linear_mm == mm and t >= sent
                    ]
                    if hit:
                        latencies.append((hit[0] - sent) * 1000)
                        break
                    await asyncio.sleep(0.0005)
                await asyncio.sleep(0.02)
    return {
        "n": n,
        "delivered": delivered,
        "expected": n * RATE,
        "cpu": cpu * 100,
        "p50": statistics.median(latencies),
        "p99": percentile(latencies, 0.99),
        "max": max(latencies),
    }


async def main(quick: bool) -> None:
    counts = [1, 10] if quick else [1, 10, 50]
    window = 3.0 if quick else 10.0
    commands = 30 if quick else 200
    broker = Mosquitto()
    await broker.start()
    try:
        f50, f99 = await floor(broker.port, commands)
        cores = len(os.sched_getaffinity(0))
        print(f"machine: {platform.machine()}, {cores} cores; rate {RATE:g}/s per robot")
        print(f"{'robots':>6}  {'telemetry/s':>11}  {'expected':>8}  {'ratio':>6}  "
              f"{'cmd->wire p50':>13}  {'p99':>6}  {'max':>6}  {'bridge CPU %':>12}")  # fmt: skip
        for n in counts:
            r = await measure(broker.port, n, window, commands)
            print(f"{r['n']:>6.0f}  {r['delivered']:>11.1f}  {r['expected']:>8.0f}  "
                  f"{r['delivered'] / r['expected']:>6.2f}  {r['p50']:>10.2f} ms  "
                  f"{r['p99']:>6.2f}  {r['max']:>6.2f}  {r['cpu']:>12.1f}")  # fmt: skip
        print(f"floor: a publish and its delivery through mosquitto alone: p50 {f50:.2f} ms, "
              f"p99 {f99:.2f} ms")  # fmt: skip
    finally:
        broker.cleanup()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 1, 10; shorter windows")
    asyncio.run(main(parser.parse_args().quick))
