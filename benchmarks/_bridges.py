"""Child process of ``mqtt_fleet.py``: one bridge per port, all in this one process.

    python benchmarks/_bridges.py BROKER_PORT RATE PORT [PORT ...]

Robot ``rK`` is the K-th port. Prints ``ready`` once every bridge is up, then runs
until killed.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import sys

import aiomqtt

from chassis_sdk import Chassis
from chassis_sdk.integrations.mqtt import MqttBridge, connection_will


async def one(broker_port: int, rate: float, port: str, robot_id: str, up: asyncio.Event) -> None:
    async with Chassis(port) as robot:
        client = aiomqtt.Client(
            "127.0.0.1",
            broker_port,
            identifier=f"bench-{robot_id}",
            protocol=aiomqtt.ProtocolVersion.V5,
            will=connection_will(robot_id),
            clean_start=True,
            max_queued_outgoing_messages=1000,
            socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)],  # as the CLI's
        )
        up.set()
        await MqttBridge(robot, client, robot_id, rate=rate).run()


async def main(broker_port: int, rate: float, ports: list[str]) -> None:
    ups = [asyncio.Event() for _ in ports]
    async with asyncio.TaskGroup() as tg:
        for k, (port, up) in enumerate(zip(ports, ups, strict=True)):
            tg.create_task(one(broker_port, rate, port, f"r{k}", up))
        for up in ups:
            await up.wait()
        print("ready", flush=True)


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        asyncio.run(main(int(sys.argv[1]), float(sys.argv[2]), sys.argv[3:]))
