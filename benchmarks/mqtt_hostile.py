"""The MQTT bridge under a flood (issue 23): how long the robot keeps moving after a
velocity flood ends, how late an e-stop behind a junk flood reaches the wire, and how
much memory the bridge takes meanwhile.

    python benchmarks/mqtt_hostile.py [--seconds 5] [--rate 10000]
    PYTHONPATH=/tmp/old-main python benchmarks/mqtt_hostile.py   # another checkout

The bridge is the real ``chassis-sdk bridge`` in a process of its own, of whichever
``chassis_sdk`` ``PYTHONPATH`` names (this checkout by default), on a simulated chassis
on a pty in this process, with mosquitto on loopback. The flood comes from
``tests/support/mqtt_flood.py`` in a third process (raw MQTT 5 PUBLISH packets at QoS 0,
127.0.0.1 only, bounded in count and time). Printed, each beside its floor and goal:

* velocity flood (``rate``/s valid ``cmd/velocity`` for ``seconds``): from the last
  command the flood published to the zero frame on the wire (floor: the deadman,
  ``command_timeout`` 0.5 s; goal: + 0.2 s); telemetry/s an observer gets meanwhile
  (goal 10); request round trips meanwhile (goal: each under 1 s);
* junk flood (``rate``/s malformed ``cmd/velocity``): from publishing ``cmd/estop``
  half-way through to the e-stop frame on the wire (floor: the same with no flood;
  goal 50 ms), with the broker's ``set_tcp_nodelay true`` (as docs/mqtt.md advises) and
  with mosquitto's defaults (its Nagle algorithm can hold a message 40 ms);
* the bridge's peak RSS (VmHWM) before and after each flood (goal: grows < 15 MB).

An old bridge may never catch up: each wait is bounded (``--bound``), and the figure
then reads "> bound".
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import importlib.util
import json
import os
import platform
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any

import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

ROOT = Path(__file__).resolve().parent.parent
if importlib.util.find_spec("chassis_sdk") is None:
    sys.path.append(str(ROOT))  # after PYTHONPATH: another checkout there wins
from _support import support  # noqa: E402

import chassis_sdk  # noqa: E402
from chassis_sdk.protocol import CommandId, DriveVelocity  # noqa: E402
from chassis_sdk.sim import ChassisSimulator  # noqa: E402

Mosquitto = support("mqtt_broker").Mosquitto  # this checkout's tests/support
FLOOD = ROOT / "tests" / "support" / "mqtt_flood.py"
DEADMAN = 0.5
#: The checkout this process imported: the bridge runs the same one.
CHECKOUT = Path(chassis_sdk.__file__).resolve().parent.parent


def peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Watch:
    """A dashboard that watches what the bridge publishes (not the commands)."""

    def __init__(self, port: int) -> None:
        self.client = aiomqtt.Client(
            "127.0.0.1",
            port,
            identifier=f"watch-{os.getpid()}",
            protocol=aiomqtt.ProtocolVersion.V5,
            # A dashboard's e-stop leaves at once, not after the previous packet's ACK.
            socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)],
        )
        self.seen: list[tuple[float, str, bytes]] = []
        self._task: asyncio.Task[None] | None = None

    async def __aenter__(self) -> Watch:
        await self.client.__aenter__()
        for topic in ("robots/+/connection", "robots/+/errors", "robots/+/telemetry/telemetry"):
            await self.client.subscribe(topic, qos=1)
        await self.client.subscribe("replies/#")
        self._task = asyncio.create_task(self._collect())
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._task is not None
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
            await self._task
        with contextlib.suppress(aiomqtt.MqttError):
            await self.client.__aexit__(None, None, None)

    async def _collect(self) -> None:
        async for m in self.client.messages:
            raw = m.payload if isinstance(m.payload, bytes) else b""
            self.seen.append((time.monotonic(), str(m.topic), raw))

    def count(self, topic: str, since: float = 0.0) -> int:
        return sum(1 for t, top, _ in self.seen if top == topic and t >= since)

    async def until(self, predicate: Any, bound: float) -> bool:
        deadline = time.monotonic() + bound
        while not predicate():
            if time.monotonic() > deadline:
                return False
            await asyncio.sleep(0.002)
        return True

    async def request(self, n: int, bound: float) -> float | None:
        """One request round trip (seconds), or None when unanswered within bound."""
        props = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
        props.ResponseTopic = f"replies/bench/{n}"
        asked = time.monotonic()
        await self.client.publish("robots/r1/request/get_firmware_version", b"", properties=props)
        ok = await self.until(lambda: self.count(f"replies/bench/{n}") > 0, bound)
        return time.monotonic() - asked if ok else None


async def bridge_process(port: int, sim_port: str) -> asyncio.subprocess.Process:
    # The checkout this process imported, also for the bridge (``-m`` puts the
    # working directory first on its path).
    env = {**os.environ, "PYTHONPATH": str(CHECKOUT)}
    return await asyncio.create_subprocess_exec(
        sys.executable, "-m", "chassis_sdk.cli", "bridge", sim_port,
        "--broker", f"mqtt://127.0.0.1:{port}", "--robot-id", "r1",
        env=env, cwd=CHECKOUT, stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL,
    )  # fmt: skip


async def start_flood(
    port: int, kind: str, rate: float, seconds: float
) -> asyncio.subprocess.Process:
    return await asyncio.create_subprocess_exec(
        sys.executable, str(FLOOD), str(port), "robots/r1/cmd/velocity",
        "--rate", str(rate), "--seconds", str(seconds), "--kind", kind,
        stdout=asyncio.subprocess.PIPE,
    )  # fmt: skip


@contextlib.asynccontextmanager
async def stand(broker: Any) -> Any:
    async with ChassisSimulator() as sim, Watch(broker.port) as watch:
        proc = await bridge_process(broker.port, sim.port)
        try:
            ok = await watch.until(lambda: watch.count("robots/r1/telemetry/telemetry") > 0, 30)
            if not ok:
                raise SystemExit("the bridge did not come up")
            yield sim, watch, proc
        finally:
            with contextlib.suppress(ProcessLookupError):
                proc.send_signal(signal.SIGKILL)
            await proc.wait()


def fmt(value: float | None, unit: str = "s", bound: float | None = None) -> str:
    if value is None:
        return f"> {bound:g} {unit}" if bound is not None else "-"
    return f"{value * 1000:.0f} ms" if unit == "ms" else f"{value:.2f} {unit}"


async def velocity_flood(rate: float, seconds: float, bound: float) -> dict[str, Any]:
    broker = Mosquitto()
    await broker.start()
    try:
        async with stand(broker) as (sim, watch, proc):
            rss0 = peak_rss_mb(proc.pid)
            flood = await start_flood(broker.port, "velocity", rate, seconds)
            started = time.monotonic()
            rounds: list[float | None] = []
            while flood.returncode is None and time.monotonic() - started < seconds + 6:
                rounds.append(await watch.request(len(rounds), 1.0))
                await asyncio.sleep(0.25)
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(flood.wait(), 0.01)
            span = time.monotonic() - started
            telemetry = watch.count("robots/r1/telemetry/telemetry", started) / span
            out, _ = await flood.communicate()
            sent = json.loads(out)
            zero = DriveVelocity(0, 0.0)

            def stopped() -> bool:
                drives = [c for _, c in sim.firmware.received if isinstance(c, DriveVelocity)]
                return bool(drives) and drives[-1] == zero

            moving: float | None = None
            if await watch.until(stopped, bound):
                zero_at = next(t for t, c in reversed(sim.firmware.received) if c == zero)
                moving = zero_at - sent["last_monotonic"]
            return {
                "sent": sent["sent"],
                "moving_after_end": moving,
                "telemetry_per_s": telemetry,
                "requests": rounds,
                "rss_before": rss0,
                "rss_peak": peak_rss_mb(proc.pid),
            }
    finally:
        broker.cleanup()


def estop_times(sim: Any) -> list[float]:
    return [
        t
        for t, c in sim.firmware.received
        if getattr(c, "id", None) == CommandId.EMERGENCY_STOP and getattr(c, "value", 0) == 1
    ]


async def estop_latency(watch: Any, sim: Any, bound: float) -> float | None:
    before = len(estop_times(sim))
    published = time.monotonic()
    await watch.client.publish("robots/r1/cmd/estop", b'{"engaged": true}')
    if not await watch.until(lambda: len(estop_times(sim)) > before, bound):
        return None
    return estop_times(sim)[before] - published


async def junk_flood(rate: float, seconds: float, bound: float, nodelay: bool) -> dict[str, Any]:
    broker = Mosquitto(nodelay=nodelay)
    await broker.start()
    try:
        async with stand(broker) as (sim, watch, proc):
            idle = []
            for _ in range(5):  # the floor: an e-stop with nothing in the way
                idle.append(await estop_latency(watch, sim, 2.0))
                await watch.client.publish("robots/r1/cmd/estop", b'{"engaged": false}')
                await asyncio.sleep(0.1)
            rss0 = peak_rss_mb(proc.pid)
            flood = await start_flood(broker.port, "junk", rate, seconds)
            await asyncio.sleep(seconds / 2)
            latency = await estop_latency(watch, sim, bound)
            out, _ = await flood.communicate()
            sent = json.loads(out)
            await asyncio.sleep(1.5)
            errors = [json.loads(raw) for _, top, raw in watch.seen if top == "robots/r1/errors"]
            return {
                "sent": sent["sent"],
                "estop_idle": sorted(x for x in idle if x is not None)[len(idle) // 2],
                "estop_in_flood": latency,
                "error_reports": len(errors),
                "rss_before": rss0,
                "rss_peak": peak_rss_mb(proc.pid),
            }
    finally:
        broker.cleanup()


async def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=10_000.0)
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--bound", type=float, default=30.0, help="longest wait for a figure")
    parser.add_argument("--quick", action="store_true", help="floods of 1 s (as in CI)")
    args = parser.parse_args()
    if args.quick:
        args.seconds = min(args.seconds, 1.0)
    load_before = os.getloadavg()
    print(f"chassis_sdk from {Path(chassis_sdk.__file__).parent}")
    print(
        f"{platform.node()}, {os.cpu_count()} cores, Python {platform.python_version()}, "
        f"load {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}"
    )
    rate, seconds, bound = args.rate, args.seconds, args.bound
    v = await velocity_flood(rate, seconds, bound)
    answered = [r for r in v["requests"] if r is not None]
    print(f"\nvelocity flood: {v['sent']:,} valid cmd/velocity, {rate:,.0f}/s for {seconds:g} s")
    print(
        f"  robot moving after the flood's last command: "
        f"{fmt(v['moving_after_end'], bound=bound)}   (floor {DEADMAN:g} s: the deadman; "
        f"goal <= {DEADMAN + 0.2:g} s)"
    )
    print(f"  telemetry during the flood: {v['telemetry_per_s']:.1f}/s   (goal 10/s)")
    worst = max(answered) if answered else None
    print(
        f"  requests during the flood: {len(answered)} of {len(v['requests'])} answered "
        f"within 1 s, slowest {fmt(worst, 'ms')}   (goal: all)"
    )
    print(
        f"  bridge peak RSS: {v['rss_before']:.0f} -> {v['rss_peak']:.0f} MB   "
        "(goal: grows < 15 MB)"
    )
    for nodelay in (True, False):
        j = await junk_flood(rate, seconds, bound, nodelay)
        broker = "set_tcp_nodelay true" if nodelay else "mosquitto's defaults (Nagle)"
        print(
            f"\njunk flood, broker with {broker}: {j['sent']:,} malformed cmd/velocity, "
            f"{rate:,.0f}/s for {seconds:g} s"
        )
        print(
            f"  e-stop to the wire, half-way through: {fmt(j['estop_in_flood'], 'ms', bound)}"
            f"   (floor {fmt(j['estop_idle'], 'ms')} with no flood; goal <= 50 ms)"
        )
        print(f"  reports on errors: {j['error_reports']}   (summarised: about one a second)")
        print(
            f"  bridge peak RSS: {j['rss_before']:.0f} -> {j['rss_peak']:.0f} MB   "
            "(goal: grows < 15 MB)"
        )
    load_after = os.getloadavg()
    print(f"\nload after: {load_after[0]:.2f} {load_after[1]:.2f} {load_after[2]:.2f}")


if __name__ == "__main__":
    asyncio.run(main())
