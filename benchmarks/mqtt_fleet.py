"""A fleet on a real mosquitto: N simulated chassis, each bridged, all bridges in one
process.

    python benchmarks/mqtt_fleet.py [--quick] [--json FILE]   # N = 1, 10, 50 (quick: 10, 50)

Three processes and the broker, as on a robot's computer: the N simulators (50 Hz
telemetry each, ``_fleet_simulators.py``), the bridges (``_bridges.py``: one
``MqttBridge`` per robot, all in one process, each forwarding its telemetry at up to
``--rate`` messages a second per stream: by default the bridge's own default, 10; 50
forwards every frame), and this process, the observer, with mosquitto on loopback
between them. Printed per N:

* telemetry delivered: ``telemetry/telemetry`` messages per second the observer
  receives, against the expected ``N x rate`` (the bridge sends the latest at most
  ``rate`` times a second per stream, never a backlog);
* command to wire: from this process publishing ``cmd/velocity`` to the simulator
  reading the 0x02 frame off its pty (CLOCK_MONOTONIC, one clock for the machine),
  p50 / p99 / max in ms;
* the bridge process's CPU (100 % = one core), from /proc over the window: the bridges
  alone, not the simulators, the observer or the broker.

The floor beside them: the observer's round trip through mosquitto alone (publish and
receive on loopback), p50 / p99 in ms.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import aiomqtt

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from tests.support.mqtt_broker import Mosquitto

BRIDGES = Path(__file__).with_name("_bridges.py")
SIMULATORS = Path(__file__).with_name("_fleet_simulators.py")
#: The observer sends its commands at once, as docs/mqtt.md asks of a fleet's clients:
#: with Nagle's algorithm on its socket a command waits for the broker's delayed ACK of
#: the one before (up to 40 ms), which is the publisher's latency, not the bridge's.
NODELAY = [(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)]
#: Telemetry messages a second per stream each bridge forwards (the robots send 50): the
#: bridge's default.
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
    async with aiomqtt.Client(
        "127.0.0.1", port, identifier="floor", socket_options=NODELAY
    ) as client:
        await client.subscribe("floor/echo")
        times = []
        for _ in range(n):
            sent = time.monotonic()
            await client.publish("floor/echo", b"x")
            await anext(client.messages)
            times.append((time.monotonic() - sent) * 1000)
    return statistics.median(times), percentile(times, 0.99)


async def measure(port: int, n: int, window: float, commands: int) -> dict[str, float]:
    sims = await asyncio.create_subprocess_exec(
        sys.executable, str(SIMULATORS), str(n), stdin=subprocess.PIPE, stdout=subprocess.PIPE
    )
    assert sims.stdin is not None
    assert sims.stdout is not None
    try:
        ports = json.loads(await sims.stdout.readline())
        child = subprocess.Popen(  # noqa: ASYNC220 (started, then killed)
            [sys.executable, str(BRIDGES), str(port), str(RATE), *ports],
            stdout=subprocess.PIPE,
        )
        try:
            assert child.stdout is not None
            ready = await asyncio.to_thread(child.stdout.readline)
            assert ready.strip() == b"ready", ready
            observer = aiomqtt.Client(
                "127.0.0.1", port, identifier="observer", socket_options=NODELAY
            )
            async with observer as obs:
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
                latencies = []
                for i in range(commands):
                    k = i % n
                    mm = 100 + i % 200  # a value the previous command did not have
                    sent = time.monotonic()
                    sims.stdin.write(f"{k} {mm} {sent!r}\n".encode())
                    body = json.dumps({"linear": mm / 1000, "angular": 0.0}).encode()
                    await obs.publish(f"robots/r{k}/cmd/velocity", body)
                    latencies.append(float(await sims.stdout.readline()))
                    await asyncio.sleep(0.02)
                counter.cancel()
        finally:
            child.kill()
            await asyncio.to_thread(child.wait)
    finally:
        sims.stdin.close()
        await sims.wait()
    lost = sum(1 for ms in latencies if ms == float("inf"))
    arrived = [ms for ms in latencies if ms != float("inf")] or [float("nan")]
    return {
        "n": n,
        "rate": RATE,
        "delivered": delivered,
        "expected": n * RATE,
        "cpu": cpu * 100,
        "p50": statistics.median(arrived),
        "p99": percentile(arrived, 0.99),
        "max": max(arrived),
        "commands": commands,
        "commands_lost": lost,
    }


async def main(quick: bool) -> dict[str, object]:
    counts = [10, 50] if quick else [1, 10, 50]
    window = 3.0 if quick else 10.0
    commands = 50 if quick else 300
    broker = Mosquitto()
    await broker.start()
    try:
        f50, f99 = await floor(broker.port, commands)
        cores = len(os.sched_getaffinity(0))
        print(f"machine: {platform.machine()}, {cores} cores; robots at 50 Hz, bridged at "
              f"{RATE:g}/s per stream")  # fmt: skip
        print(f"{'robots':>6}  {'telemetry/s':>11}  {'expected':>8}  {'ratio':>6}  "
              f"{'cmd->wire p50':>13}  {'p99':>6}  {'max':>6}  {'bridge CPU %':>12}")  # fmt: skip
        rows = []
        for n in counts:
            r = await measure(broker.port, n, window, commands)
            rows.append(r)
            print(f"{r['n']:>6.0f}  {r['delivered']:>11.1f}  {r['expected']:>8.0f}  "
                  f"{r['delivered'] / r['expected']:>6.2f}  {r['p50']:>10.2f} ms  "
                  f"{r['p99']:>6.2f}  {r['max']:>6.2f}  {r['cpu']:>12.1f}")  # fmt: skip
        print(f"floor: a publish and its delivery through mosquitto alone: p50 {f50:.2f} ms, "
              f"p99 {f99:.2f} ms")  # fmt: skip
        if lost := sum(r["commands_lost"] for r in rows):
            print(f"{lost} commands never reached the wire within 5 s (left out of the figures)")
        return {"fleets": rows, "floor": {"p50": f50, "p99": f99}, "window_s": window}
    finally:
        broker.cleanup()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="N = 10, 50; shorter windows")
    parser.add_argument("--json", metavar="FILE", help="also write the figures to FILE")
    parser.add_argument("--rate", type=float, default=RATE, help="bridged messages/s per stream")
    args = parser.parse_args()
    RATE = args.rate
    report = asyncio.run(main(args.quick))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
