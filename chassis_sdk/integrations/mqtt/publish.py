"""What a bridge publishes under ``{prefix}/{id}/``: its state on ``connection`` (and the
last will that says ``CONNECTIONBROKEN`` for it), the device's identity on ``info`` and
link state on ``link`` (both retained), the latest of each stream on
``telemetry/{stream}`` at most ``rate`` times a second (a reading with the pack's
``voltage`` with ``battery_percentage`` and ``battery_level`` beside it, ``null`` while
the state of charge is not known or the device has no ``battery=`` model), each event
on ``events`` (the battery's with their ``percentage``), and
what was refused on ``errors`` (the first at once, then at most one summary per
``report_interval``).

`Publisher` is `MqttBridge`'s publishing
side: it is given a `PublishContext` (the bridge's client, topic, device, profile, owner
and rate; the bridge remains the one object its owner talks to). See the
module docstring of `chassis_sdk.integrations.mqtt` for the topics.

It takes the device's data by callback (`chassis_sdk.core.notifier.Notifier`), not by
a task per stream: each callback runs inside the device's read path and only puts the
message where the one publishing task (`Publisher.run`) finds it. Telemetry is
state: a stream's newest message replaces the one not yet published, so a slow broker
costs readings, never memory or a backlog. Link states and events are published each,
in order (QoS 1), from queues bounded by the device's ``queue_size``, the oldest
dropped and counted (`Publisher.unpublished`) if the broker falls that far behind, as
a subscriber of the device's streams would. One task publishes everything, in this
order: the link states, the events, then, on the rate's schedule, the telemetry; a
broker slow to acknowledge an event holds the telemetry behind it (which then
publishes its newest).

Telemetry (QoS 0) is handed to the client's outgoing queue without waiting for each
message to leave, all of one slot's streams together (`send_latest`): aiomqtt's
``publish`` waits for every message's write (a task, an event, a timer and three
turns of the loop each), which was the larger part of a bridge's work and kept the
loop busy in bursts a command then waited behind. A slot whose previous telemetry has
not left yet (a broker that reads slowly) is skipped and counted
(`Publisher.telemetry_skipped`), its messages kept: the newest is sent at the next
slot, never a backlog. A broker that reads nothing for the client's ``timeout`` ends
the bridge, as a ``publish`` waiting that long did.
"""

from __future__ import annotations

import asyncio
import functools
import json
import logging
import select
import time
import zlib
from collections import deque
from typing import Any

import aiomqtt
import anyio
import paho.mqtt.client as paho_mqtt
from paho.mqtt.properties import Properties

from ...core.charge import battery_fields
from ...core.events import RobotEvent
from ...core.firmware import next_slot
from ...core.notifier import Notifier
from ...core.plain import outbound, plain
from ...core.supervisor import ConnectionState
from ...errors import ChassisError, ConnectionLostError, NotConnectedError
from ..inbound import RefusalReport, Refusals
from .context import PublishContext
from .inbox import PathProbe
from .internals import client_internals

__all__ = [
    "Publisher",
    "connection_will",
    "epoch_now",
    "queued",
    "send_latest",
    "slot_phase",
    "state_payload",
    "unwritten",
]

_log = logging.getLogger("chassis_sdk.integrations.mqtt")


def _not_connected(client: aiomqtt.Client, rc: int) -> aiomqtt.MqttCodeError:
    """What aiomqtt's ``publish`` raises when the client is not connected."""
    error = aiomqtt.MqttCodeError(rc, "Could not publish message")
    lost = client_internals(client).disconnected
    if lost.done() and not lost.cancelled() and lost.exception() is not None:
        error.__cause__ = lost.exception()
    return error


def unwritten(client: aiomqtt.Client) -> bool:
    """True while packets queued on ``client``'s connection wait for room in its socket
    (the broker reads slowly, or the link is congested). Packets queued while the
    socket has room are not (see `queued`): the loop writes them at its next turn.

    Raises:
        aiomqtt.MqttCodeError: The client is not connected (what ``publish`` raises; paho
            keeps the unwritten packets of a lost connection until it reconnects).
    """
    paho = client_internals(client).paho
    sock = paho.socket()
    if sock is None:
        raise _not_connected(client, paho_mqtt.MQTT_ERR_NO_CONN)
    return paho.want_write() and not _writable(sock)


def queued(client: aiomqtt.Client) -> bool:
    """True while packets queued on ``client``'s connection are not all written yet,
    whether they wait for room in its socket (`unwritten`) or only for the loop's
    next turn: aiomqtt adds its writer a turn after a packet is queued, then writes
    when the loop sees the socket writable."""
    return client_internals(client).paho.want_write()


def _writable(sock: Any) -> bool:
    """True if the loop would find ``sock`` writable now (room in its send buffer);
    never waits."""
    poller = select.poll()
    poller.register(sock, select.POLLOUT)
    return bool(poller.poll(0))


#: The instants in each telemetry period the bridges' slots are spread over (`slot_phase`).
PHASES = 8


def slot_phase(topic: str, period: float) -> float:
    """Where in each ``period`` the bridge of ``topic`` publishes its telemetry (s):
    one of `PHASES` evenly spaced instants, chosen by the topic.

    Bridges started together (many robots in one process, or a fleet's processes after
    a broker restart) would otherwise publish in the same instant, every period: one
    burst of all their messages, which a command arriving then waits behind (50 robots
    in one process: p99 command -> wire 6-11 ms). Spread over a few instants, a command
    waits behind a few bridges at most, while the bridges of one instant still share
    one wake-up of the process (each instant more costs a wake-up per period). The
    phase comes from the topic, so a bridge keeps its place across restarts.
    """
    return zlib.crc32(topic.encode()) % PHASES / PHASES * period


def send_latest(client: aiomqtt.Client, messages: list[tuple[str, bytes]]) -> None:
    """Queue ``(topic, payload)`` messages (QoS 0, not retained) on ``client``'s
    connection, without waiting for them to be written.

    They are written when the loop next finds the socket writable, all in that one
    wake-up, as aiomqtt's ``publish`` writes (less its wait for each message). It uses
    aiomqtt's paho client (`client_internals`), as `install_batched_reads` does; call
    `unwritten` first not to queue behind packets the broker has not read.

    Raises:
        aiomqtt.MqttCodeError: The client is not connected (what ``publish`` raises).
    """
    paho = client_internals(client).paho
    for topic, payload in messages:
        info = paho.publish(topic, payload)
        if info.rc != paho_mqtt.MQTT_ERR_SUCCESS:
            raise _not_connected(client, info.rc)


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

    def __init__(self, context: PublishContext, report_interval: float) -> None:
        self._ctx = context
        #: What was refused, counted and summarised for ``errors``.
        self.refusals = Refusals(report_interval)
        self._reports: deque[RefusalReport] = deque(maxlen=4)
        # asyncio's event, not anyio's: the reporter clears it in the loop it wakes
        # (anyio's cannot be cleared).
        self._report_wanted = asyncio.Event()
        # What the device's callbacks hand to `run` (see there).
        self._latest: dict[str, Any] = {}
        self._events: deque[RobotEvent] = deque()
        self._states: deque[ConnectionState] = deque()
        self._wake = asyncio.Event()
        #: Events and link states dropped unpublished, the oldest first, because the
        #: broker fell more than the device's ``queue_size`` behind (telemetry is the
        #: latest by design: a message replaced by a newer one is not counted).
        self.unpublished = 0
        #: Telemetry slots skipped because the previous slot's messages had not left
        #: for the broker yet (it reads slowly or the link is congested).
        self.telemetry_skipped = 0
        # When the slots began to be skipped (None: the last slot was sent).
        self._stalled_since: float | None = None
        #: The probe of the broker -> bridge path whose probes `run` sends (``None``:
        #: none, a read-only bridge).
        self.probe: PathProbe | None = None

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
        ctx = self._ctx
        await ctx.client.publish(
            f"{ctx.topic}/{sub}", payload, qos=qos, retain=retain, properties=properties
        )

    async def info(self) -> None:
        """The device's identity, retained on ``info``."""
        ctx = self._ctx
        info: dict[str, Any] = {
            "device": ctx.profile.name,
            "summary": ctx.profile.summary,
            "port": ctx.device.port,
            "features": dict(ctx.profile.remote.features),
            "owner": ctx.owner,
        }
        for name in ctx.profile.remote.identity:
            try:
                value = await getattr(ctx.device, name)()
            except ChassisError as exc:
                value = {"error": str(exc)}
            info[name.removeprefix("get_")] = plain(value)
        await self.publish("info", json.dumps(info).encode(), qos=1, retain=True)

    async def offline(self) -> None:
        """Say ``OFFLINE`` (a clean stop), bounded: a broker that does not acknowledge
        within two seconds does not hold the stop up (its last will then tells). Only
        the robot id's owner may (the bridge checks)."""
        await self.bounded_state("OFFLINE")

    async def bounded_state(self, state: str) -> None:
        """Publish this bridge's ``state`` on ``connection``, waiting two seconds at
        most; a failure is logged, not raised."""
        payload = state_payload(state, self._ctx.owner)
        with anyio.move_on_after(2.0):
            try:
                await self.publish("connection", payload, qos=1, retain=True)
            except Exception as exc:
                _log.info("%s: could not publish its state: %r", self._ctx.topic, exc)

    # --- what the device hands over, and the one loop that publishes it ------------------
    #
    # The device calls these (and, for telemetry, a dict store: see `run`) inside its
    # read path, as Notifier's listeners: each only puts the message where the
    # publishing loop finds it, never waits and never raises, and only what is
    # published at once (events, link states) wakes the loop. The loop is one task per
    # bridge, whatever the number of streams: a bridged robot costs its bare read path
    # plus a dict store per frame of a published stream.

    def _event(self, event: RobotEvent) -> None:
        """An event: queued in order, the oldest dropped (and counted) past the bound."""
        events = self._events
        if len(events) == events.maxlen:
            self.unpublished += 1
        events.append(event)
        self._wake.set()

    def _state(self, state: ConnectionState) -> None:
        """A link state change: queued in order like an event."""
        states = self._states
        if len(states) == states.maxlen:
            self.unpublished += 1
        states.append(state)
        self._wake.set()

    async def run(self) -> None:
        """Publish, in one task, until cancelled: the link state (retained on ``link``,
        then each change), each event on ``events`` (QoS 1), and the latest message of
        each stream on ``telemetry/{stream}`` at most ``rate`` times a second.

        Raises:
            NotConnectedError: The device was not connected when the bridge started.
            ConnectionLostError: The device's link was lost and it does not reconnect
                (after its last state and events are published).
        """
        ctx = self._ctx
        device = ctx.device
        if device.connection_state is ConnectionState.DISCONNECTED:
            raise NotConnectedError(f"{device.port} is not connected; use `async with` first")
        # Bounded as a subscriber of the device's streams is: its ``queue_size``.
        self._events = deque(maxlen=device.queue_size)
        self._states = deque(maxlen=device.queue_size)
        self._latest.clear()
        with Notifier(device) as notifier:
            for stream in ctx.profile.remote.streams:
                # ``latest[stream] = message``, with no Python frame: the newest
                # replaces the one not yet published.
                notifier.listen(stream, functools.partial(self._latest.__setitem__, stream))
            notifier.listen("events", self._event)
            notifier.listen_states(self._state)
            # Listening first: a change while this is published is queued, not missed.
            state = device.connection_state.value
            await self.publish("link", state_payload(state), qos=1, retain=True)
            period = 1.0 / ctx.rate
            due = anyio.current_time() + slot_phase(ctx.topic, period)
            probe = self.probe
            if probe is not None:
                probe.start()
            while True:
                # Cleared before the queues are read: whatever arrives from here on
                # (also while publishing) wakes the wait below.
                self._wake.clear()
                await self._publish_queued()
                now = anyio.current_time()
                if now >= due:
                    # An absolute schedule: publishing takes time, and must not slow
                    # the rate; a broker that held the loop up skips the slots missed.
                    due = next_slot(due, period, now)
                    self._publish_latest()
                    continue
                wait = due - now
                if probe is not None:
                    # Between two telemetry slots, so that the slot after it finds the
                    # probe written (a slot finding packets unwritten is skipped).
                    wait = min(wait, self._send_probe(probe))
                with anyio.move_on_after(wait):
                    await self._wake.wait()

    async def _publish_queued(self) -> None:
        """The link states, then the events, that came since the last call, in order;
        if the device is lost for good, end as its streams did."""
        device = self._ctx.device
        states, events = self._states, self._events
        lost = False
        while states:
            state = states.popleft()
            lost = state is ConnectionState.LOST
            await self.publish("link", state_payload(state.value), qos=1, retain=True)
        while events:
            event = events.popleft()
            # The recording's JSON of it (kind by name), in wall time.
            await self.publish("events", json.dumps(outbound(event)).encode(), qos=1)
        if lost and device.connection_state is ConnectionState.LOST:
            # LOST is final (``reconnect`` off, or the device's own tasks failed): its
            # streams have ended with the loss, and so does the bridge (an error of its
            # own: the robot is stopped and the last will tells the fleet).
            raise ConnectionLostError(f"{device.port} was lost and does not reconnect")

    def _publish_latest(self) -> None:
        """Each stream's newest message not yet published, if any, handed to the
        client together (`send_latest`). While the connection still holds unwritten
        packets the slot is skipped, its messages kept for the next one (a newer one
        of a stream replaces its own).

        Raises:
            aiomqtt.MqttError: The client is not connected, or the broker has read
                nothing for the client's ``timeout`` (as a ``publish`` waiting that long
                raises).
        """
        ctx = self._ctx
        client = ctx.client
        if unwritten(client):
            self.telemetry_skipped += 1
            now = anyio.current_time()
            if self._stalled_since is None:
                self._stalled_since = now
            elif now - self._stalled_since > client.timeout:
                raise aiomqtt.MqttError(
                    f"the broker has read nothing for {client.timeout:g} s (telemetry held)"
                )
            return
        self._stalled_since = None
        if queued(client):
            # The socket has room: what is queued (the probe sent just before this
            # slot, or the last slot's if the loop was held up) waits only for the
            # loop's next turn, not for the broker. Neither a skip nor a stall: this
            # slot's messages go at the next, so that at most one slot's are queued.
            return
        latest = self._latest
        messages = []
        for stream in ctx.profile.remote.streams:
            message = latest.pop(stream, None)
            if message is None:
                continue
            body = {"type": type(message).__name__, **outbound(message)}
            if "voltage" in body:  # the pack's voltage: its state of charge beside
                body.update(battery_fields(ctx.device))
            messages.append((f"{ctx.topic}/telemetry/{stream}", json.dumps(body).encode()))
        send_latest(client, messages)

    def _send_probe(self, probe: PathProbe) -> float:
        """Send the probe to the bridge itself if it is due (QoS 0, not retained, handed
        to the client as telemetry is); return the seconds until the next is due."""
        due = probe.due()
        left = 0.0 if due is None else due - time.monotonic()
        if left > 0:
            return left
        ctx = self._ctx
        payload = json.dumps({"owner": ctx.owner, "probe": probe.send()}).encode()
        send_latest(ctx.client, [(f"{ctx.topic}/probe", payload)])
        return probe.period

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
                _log.info("%s: refused %s", self._ctx.topic, report.summary())
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
