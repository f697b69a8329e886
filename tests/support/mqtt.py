"""What the MQTT bridge's tests share, on a real mosquitto (``mqtt_broker``): a
dashboard that keeps everything published under ``robots/#`` (:class:`Observer`), a
bridge's client as ``chassis-sdk bridge`` makes it (:func:`bridge_client`), a bridge
running for a block (:func:`bridged`) and one MQTT 5 request/response
(:func:`request`)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
from collections.abc import AsyncIterator, Callable
from typing import Any

import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from chassis_sdk import Board, Chassis
from chassis_sdk.integrations.mqtt import CommandInbox, MqttBridge, connection_will

from .mqtt_broker import Broker

__all__ = ["Observer", "bridge_client", "bridged", "request"]

V5 = aiomqtt.ProtocolVersion.V5


def bridge_client(b: Broker, robot_id: str, **options: Any) -> aiomqtt.Client:
    """A bridge's client on ``b``, with ``queue_type=CommandInbox`` as the docs make it;
    ``options`` go to ``aiomqtt.Client`` as well (``queue_type=None``: aiomqtt's default
    queue, which the bridge replaces)."""
    options.setdefault("queue_type", CommandInbox)
    return aiomqtt.Client(
        "127.0.0.1",
        b.port,
        identifier=f"bridge-{robot_id}",
        protocol=V5,
        will=connection_will(robot_id),
        clean_start=True,
        **options,
    )


class Observer:
    """A dashboard: subscribes under ``robots/#`` and keeps what arrives, in order."""

    count = 0

    def __init__(self, b: Broker, **login: Any) -> None:
        Observer.count += 1
        name = f"observer-{os.getpid()}-{Observer.count}"  # a shared id would evict the other
        self.client = aiomqtt.Client("127.0.0.1", b.port, identifier=name, protocol=V5, **login)
        self.seen: list[tuple[str, Any, bool]] = []
        self._task: asyncio.Task[None] | None = None
        self._arrived = asyncio.Event()

    async def __aenter__(self) -> Observer:
        await self.client.__aenter__()
        await self.client.subscribe("robots/#", qos=1)
        self._task = asyncio.create_task(self._collect())
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._task is not None
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
            await self._task
        with contextlib.suppress(aiomqtt.MqttError):  # the broker may be gone (killed)
            await self.client.__aexit__(None, None, None)

    async def _collect(self) -> None:
        async for m in self.client.messages:
            raw = m.payload if isinstance(m.payload, bytes | bytearray) else b""
            try:
                payload: Any = json.loads(raw) if raw else None
            except ValueError:
                payload = raw
            self.seen.append((str(m.topic), payload, bool(m.retain)))
            self._arrived.set()

    def on(self, topic: str) -> list[Any]:
        return [p for t, p, _ in self.seen if t == topic]

    async def wait(self, predicate: Callable[[], bool], timeout: float = 5.0) -> None:
        async with asyncio.timeout(timeout):
            while not predicate():
                self._arrived.clear()
                await self._arrived.wait()

    async def publish(self, topic: str, payload: Any, **kwargs: Any) -> None:
        data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
        await self.client.publish(topic, data, **kwargs)


@contextlib.asynccontextmanager
async def bridged(
    b: Broker, device: Chassis | Board, robot_id: str = "r1", **options: Any
) -> AsyncIterator[asyncio.Task[None]]:
    """An :class:`MqttBridge` of ``device`` on ``b`` running for the block (its task)."""
    bridge = MqttBridge(device, bridge_client(b, robot_id), robot_id, **options)
    task = asyncio.create_task(bridge.run())
    try:
        yield task
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
            await task


async def request(
    obs: Observer, robot_id: str, name: str, payload: Any = b"", timeout: float = 5.0
) -> Any:
    """One MQTT 5 request/response round trip, matched by correlation data (``payload``:
    bytes, or what JSON makes of it)."""
    reply_to = f"replies/{robot_id}/{name}"
    await obs.client.subscribe(reply_to)
    props = Properties(PacketTypes.PUBLISH)  # type: ignore[no-untyped-call]
    props.ResponseTopic = reply_to
    props.CorrelationData = b"req-42"
    data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
    before = len([1 for t, _, _ in obs.seen if t == reply_to])
    await obs.client.publish(f"robots/{robot_id}/request/{name}", data, properties=props)
    await obs.wait(lambda: len([1 for t, _, _ in obs.seen if t == reply_to]) > before, timeout)
    return [p for t, p, _ in obs.seen if t == reply_to][-1]
