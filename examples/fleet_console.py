"""List every robot bridged under a prefix, with its state and battery; stop them all.

    python examples/fleet_console.py [--broker mqtt://HOST:PORT] [--prefix robots]
                                     [--seconds 2] [--stop-all]

Each robot runs `chassis-sdk bridge PORT --robot-id ID` (see docs/mqtt.md). The console
listens for `--seconds` (the retained connection, link and info topics arrive at once,
telemetry within a tenth of a second), prints one line per robot, and with
`--stop-all` sends every robot `cmd/stop`. A robot whose bridge is not ONLINE shows its
link as `unknown`: the retained link message is the last thing the bridge said.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import sys
import urllib.parse
from dataclasses import dataclass

import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

import chassis_sdk


@dataclass
class Robot:
    connection: str = "-"
    link: str = "-"
    battery: float | None = None
    charge: float | None = None  # percent, when the bridge's device has a battery model
    device: str = "-"

    @property
    def link_now(self) -> str:
        """The link as the bridge last said, while the bridge is ONLINE; once it is not,
        its retained link message is history, not news: ``unknown``."""
        return self.link if self.connection == "ONLINE" else "unknown"


COLUMNS = f"{'robot':<8}{'device':<9}{'connection':<18}{'link':<14}battery"


def row(robot_id: str, r: Robot) -> str:
    """One robot's line, under :data:`COLUMNS`."""
    battery = "-" if r.battery is None else f"{r.battery:.1f} V"
    if r.battery is not None and r.charge is not None:
        battery += f"  {r.charge:.0f} %"
    return f"{robot_id:<8}{r.device:<9}{r.connection:<18}{r.link_now:<14}{battery}".rstrip()


async def listen(client: aiomqtt.Client, prefix: str, seconds: float) -> dict[str, Robot]:
    robots: dict[str, Robot] = {}
    for sub in ("connection", "link", "info", "telemetry/telemetry", "telemetry/battery"):
        await client.subscribe(f"{prefix}/+/{sub}")
    with_deadline = asyncio.timeout(seconds)
    try:
        async with with_deadline:
            async for message in client.messages:
                _, robot_id, *kind = str(message.topic).split("/")
                raw = message.payload if isinstance(message.payload, bytes | bytearray) else b""
                try:
                    payload = json.loads(raw)
                except ValueError:
                    continue  # a cleared retained topic, or not ours
                robot = robots.setdefault(robot_id, Robot())
                if kind == ["connection"]:
                    robot.connection = payload.get("state", "?")
                elif kind == ["link"]:
                    robot.link = payload.get("state", "?")
                elif kind == ["info"]:
                    robot.device = payload.get("device", "?")
                elif "voltage" in payload:  # chassis telemetry or board battery
                    robot.battery = payload["voltage"]
                    robot.charge = payload.get("battery_percentage")
    except TimeoutError:
        pass
    return robots


async def stop_all(client: aiomqtt.Client, prefix: str, robots: dict[str, Robot]) -> None:
    expiry = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
    expiry.MessageExpiryInterval = 1  # a stop that cannot arrive in a second is moot
    for robot_id in robots:
        await client.publish(f"{prefix}/{robot_id}/cmd/stop", b"{}", properties=expiry)


async def main(broker: str, prefix: str, seconds: float, stop: bool) -> None:
    url = urllib.parse.urlsplit(broker)
    if url.scheme != "mqtt" or not url.hostname:
        raise chassis_sdk.ChassisError(f"--broker must be mqtt://HOST:PORT, got {broker!r}")
    try:
        client = aiomqtt.Client(
            url.hostname, url.port or 1883, protocol=aiomqtt.ProtocolVersion.V5, timeout=5.0
        )
        async with client:
            robots = await listen(client, prefix, seconds)
            print(COLUMNS)
            for robot_id, r in sorted(robots.items()):
                print(row(robot_id, r))
            if not robots:
                print(f"(no robot under {prefix}/ on {broker})")
            if stop and robots:
                await stop_all(client, prefix, robots)
                print(f"sent cmd/stop to {len(robots)} robot(s)")
    except aiomqtt.MqttError as exc:
        raise chassis_sdk.ChassisError(f"broker {broker}: {exc}") from None


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--broker", default=os.environ.get("CHASSIS_SDK_BROKER") or "mqtt://127.0.0.1:1883"
    )
    parser.add_argument("--prefix", default="robots")
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--stop-all", action="store_true", help="send every robot cmd/stop")
    args = parser.parse_args()
    sys.exit(
        chassis_sdk.run(
            main(args.broker, args.prefix, args.seconds, args.stop_all), one_line_errors=True
        )
    )
