"""What a bridge publishes under ``{prefix}/{id}/``: its state on ``connection`` (and the
last will that says ``CONNECTIONBROKEN`` for it), the device's identity on ``info`` and
link state on ``link`` (both retained), the latest of each stream on
``telemetry/{stream}`` at most ``rate`` times a second, each event on ``events``, and
what was refused on ``errors`` (the first at once, then at most one summary per
``report_interval``).

:class:`Publisher` is :class:`~chassis_sdk.integrations.mqtt.MqttBridge`'s publishing
side: it reads the bridge's client, topic, device, profile, owner and rate as they are
when it publishes (the bridge remains the one object its owner talks to). See the
module docstring of :mod:`chassis_sdk.integrations.mqtt` for the topics.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections import deque
from typing import TYPE_CHECKING, Any

import aiomqtt
import anyio
from paho.mqtt.properties import Properties

from ..core.firmware import next_slot
from ..core.plain import jsonable, plain
from ..errors import ChassisError
from .inbound import RefusalReport, Refusals

if TYPE_CHECKING:
    from .mqtt import MqttBridge

__all__ = ["Publisher", "connection_will", "epoch_now", "state_payload"]

_log = logging.getLogger("chassis_sdk.integrations.mqtt")


def epoch_now() -> float:
    """This computer's clock, in epoch seconds (what a command's ``timestamp`` is in)."""
    return time.time()


def state_payload(state: str, owner: str | None = None, *, take_over: bool = False) -> bytes:
    """A ``connection`` (or ``link``) payload: the state, when, and whose."""
    body: dict[str, Any] = {"state": state, "timestamp": epoch_now()}
    if owner is not None:
        body["owner"] = owner
    if take_over:
        body["take_over"] = True
    return json.dumps(body).encode()


def connection_will(
    robot_id: str, prefix: str = "robots", owner: str | None = None
) -> aiomqtt.Will:
    """The last will a bridge's client must be made with: the broker publishes
    ``CONNECTIONBROKEN`` (retained) on ``{prefix}/{robot_id}/connection`` if the bridge
    vanishes without a clean stop. One client per bridge, since a will is per
    connection; give the bridge's ``owner`` so the fleet knows whose will it is."""
    return aiomqtt.Will(
        f"{prefix}/{robot_id}/connection",
        state_payload("CONNECTIONBROKEN", owner),
        qos=1,
        retain=True,
    )


class Publisher:
    """A bridge's publishing side: the retained topics, the telemetry, the events and
    the refusals' reports (see the module docstring)."""

    def __init__(self, bridge: MqttBridge, report_interval: float) -> None:
        self._bridge = bridge
        #: What was refused, counted and summarised for ``errors``.
        self.refusals = Refusals(report_interval)
        self._reports: deque[RefusalReport] = deque(maxlen=4)
        # asyncio's event, not anyio's: the reporter clears it in the loop it wakes
        # (anyio's cannot be cleared).
        self._report_wanted = asyncio.Event()

    async def publish(
        self,
        sub: str,
        payload: bytes,
        *,
        qos: int = 0,
        retain: bool = False,
        properties: Properties | None = None,
    ) -> None:
        """Publish ``payload`` on ``{prefix}/{id}/{sub}``."""
        bridge = self._bridge
        await bridge.client.publish(
            f"{bridge.topic}/{sub}", payload, qos=qos, retain=retain, properties=properties
        )

    async def info(self) -> None:
        """The device's identity, retained on ``info``."""
        bridge = self._bridge
        info: dict[str, Any] = {
            "device": bridge.profile.name,
            "summary": bridge.profile.summary,
            "port": bridge.device.port,
            "features": dict(bridge.profile.remote.features),
            "owner": bridge.owner,
        }
        for name in bridge.profile.remote.identity:
            try:
                value = await getattr(bridge.device, name)()
            except ChassisError as exc:
                value = {"error": str(exc)}
            info[name.removeprefix("get_")] = plain(value)
        await self.publish("info", json.dumps(info).encode(), qos=1, retain=True)

    async def offline(self) -> None:
        """Say ``OFFLINE`` (a clean stop), bounded: a broker that does not acknowledge
        within two seconds does not hold the stop up (its last will then tells)."""
        if not self._bridge.online:
            return  # not the owner (or not yet): the connection topic is not ours
        await self.bounded_state("OFFLINE")

    async def bounded_state(self, state: str) -> None:
        """Publish this bridge's ``state`` on ``connection``, waiting two seconds at
        most; a failure is logged, not raised."""
        payload = state_payload(state, self._bridge.owner)
        with anyio.move_on_after(2.0):
            try:
                await self.publish("connection", payload, qos=1, retain=True)
            except Exception as exc:
                _log.info("%s: could not publish its state: %r", self._bridge.topic, exc)

    # --- the loops (each in a task of the bridge's group) --------------------------------

    async def telemetry(self, stream: str) -> None:
        """The latest message of ``stream``, at most ``rate`` times a second."""
        bridge = self._bridge
        latest: list[Any] = []

        async def follow() -> None:
            try:
                async for message in getattr(bridge.device, stream)():
                    latest[:] = [message]
            except Exception as exc:  # the stream ended with an error: nothing new comes
                _log.debug("%s: the %s stream ended: %r", bridge.topic, stream, exc)

        async with anyio.create_task_group() as tg:
            tg.start_soon(follow, name=f"bridge follow {stream}:{bridge.topic}")
            period = 1.0 / bridge.rate
            due = anyio.current_time()
            while True:
                # An absolute schedule: publishing takes time, and must not slow the rate.
                due = next_slot(due, period, anyio.current_time())
                await anyio.sleep(due - anyio.current_time())
                if latest:
                    message = latest.pop()
                    payload = json.dumps({"type": type(message).__name__, **jsonable(message)})
                    await self.publish(f"telemetry/{stream}", payload.encode())

    async def link_states(self) -> None:
        """The device's link state, retained on ``link``, as it changes."""
        device = self._bridge.device
        await self.publish("link", state_payload(device.connection_state.value), qos=1, retain=True)
        async for state in device.connection_states():
            await self.publish("link", state_payload(state.value), qos=1, retain=True)

    async def events(self) -> None:
        """Each of the device's events on ``events`` (QoS 1)."""
        async for event in self._bridge.device.events():
            payload = {**jsonable(event), "kind": event.kind.value}
            await self.publish("events", json.dumps(payload).encode(), qos=1)

    # --- what was refused ----------------------------------------------------------------

    def refuse(self, where: str, why: str) -> None:
        """Count a refusal; wake the reporter when a report is due (never waits)."""
        report = self.refusals.add(where, why)
        if report is not None:
            self._reports.append(report)
            self._report_wanted.set()

    async def reporter(self) -> None:
        """Publish what was refused: the first at once, then at most one summary per
        ``report_interval``, in a task of its own (a refusal never waits for it)."""
        interval = self.refusals.interval
        while True:
            with anyio.move_on_after(interval):
                await self._report_wanted.wait()
            self._report_wanted.clear()
            report = self.refusals.due()
            if report is not None:
                self._reports.append(report)
            while self._reports:
                report = self._reports.popleft()
                _log.info("%s: refused %s", self._bridge.topic, report.summary())
                body: dict[str, Any] = {
                    "topic": report.where,
                    "error": report.why,
                    "timestamp": epoch_now(),
                    "count": report.count,
                    "total": report.total,
                }
                if report.count > 1:
                    body["reasons"] = report.reasons
                # Refusals whose reasons did not fit in ``reasons`` (at most eight).
                body["unlisted"] = report.unlisted
                await self.publish("errors", json.dumps(body).encode(), qos=1)
