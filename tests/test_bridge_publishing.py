"""How the MQTT bridge publishes what the device produces, which it takes by callback
(issue 29, item 3): a bridged robot runs no task per stream, every message the bridge
publishes reaches the broker in the order the device produced it, a stalled broker
makes it skip and count rather than queue (and end after its timeout), and a device
lost for good still ends the bridge with its last will. A real mosquitto on loopback
and the simulators on ptys, as in tests/test_bridge.py."""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import signal
import socket
import time
from typing import Any

import aiomqtt
import pytest

from chassis_sdk import Board, Chassis, ConnectionLostError, RobotEvent, Telemetry
from chassis_sdk.core.notifier import Notifier
from chassis_sdk.integrations.mqtt import MqttBridge
from chassis_sdk.integrations.mqtt import publish as mqtt_publish
from chassis_sdk.integrations.mqtt.internals import client_internals
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.helpers import until
from .support.mqtt import Observer, bridge_client
from .support.mqtt_broker import Broker, broker

pytestmark = [pytest.mark.integration, pytest.mark.mqtt]

#: The most tasks one bridge may start, whatever the number of streams it publishes:
#: commands, ownership, errors, publishing and two request workers.
BRIDGE_TASKS = 6
#: The most tasks a running bridge may add to the loop in all: its own, its run, what
#: aiomqtt runs for its client, and the short waits of its inbox and client.
MOST_TASKS = 12
#: A bridge socket's send buffer small enough that a broker that stops reading
#: fills it within seconds.
SMALL_SEND_BUFFER = [(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)]


async def tasks_of_a_bridge(b: Broker, device: Chassis | Board, robot_id: str) -> set[str]:
    """The names of the tasks a running, publishing bridge of ``device`` adds."""
    async with Observer(b) as obs:
        await asyncio.sleep(0)
        before = asyncio.all_tasks()
        bridge = MqttBridge(device, bridge_client(b, robot_id), robot_id, rate=20.0)
        task = asyncio.create_task(bridge.run())
        try:
            for stream in bridge.profile.remote.streams:
                topic = f"robots/{robot_id}/telemetry/{stream}"
                await obs.wait(lambda topic=topic: bool(obs.on(topic)))  # type: ignore[misc]
            added = asyncio.all_tasks() - before
            return {t.get_name() for t in added}
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task


async def test_a_bridged_robot_runs_no_task_per_stream() -> None:
    # A chassis publishes three streams, a board four: the same tasks for both, and
    # none of them for a stream.
    async with broker() as b, ChassisSimulator() as csim, BoardSimulator() as bsim:
        async with Chassis(csim.port) as chassis:
            async for _ in chassis.telemetry():
                break  # the simulator is listening now (it drops what comes before)
            await chassis.enable_power_telemetry()  # its third stream
            for_chassis = await tasks_of_a_bridge(b, chassis, "r1")
        async with Board(bsim.port) as board:
            for_board = await tasks_of_a_bridge(b, board, "b1")
    for added in (for_chassis, for_board):
        assert len(added) <= MOST_TASKS, sorted(added)
        assert len(bridge_tasks(added)) <= BRIDGE_TASKS, sorted(added)
    assert len(bridge_tasks(for_board)) == len(bridge_tasks(for_chassis))
    streams = {"telemetry", "power", "odometry", "imu", "velocity", "battery"}
    per_stream = [n for n in for_chassis | for_board if any(s in n.split() for s in streams)]
    assert not per_stream, per_stream


def bridge_tasks(names: set[str]) -> set[str]:
    """The tasks a bridge started itself (each named ``bridge ...:{topic}``)."""
    return {name for name in names if name.startswith("bridge ")}


async def test_every_telemetry_message_published_reaches_the_broker_in_order() -> None:
    # Above the stream's 50 Hz, the bridge publishes nearly every frame: what it
    # publishes is the device's frames in the device's order, and the broker delivers
    # exactly that, in that order.
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        Observer(b) as obs,
    ):
        produced: list[float] = []
        notifier = Notifier(robot)
        notifier.listen("telemetry", lambda t: produced.append(t.timestamp))
        bridge = MqttBridge(robot, bridge_client(b, "r1"), "r1", rate=100.0)
        published: list[bytes] = []
        # Telemetry is handed to paho's client directly (``send_latest``): recorded
        # where it enters the connection.
        paho: Any = client_internals(bridge.client).paho
        publish = paho.publish

        def recording(topic: str, payload: bytes, *args: Any, **kwargs: Any) -> Any:
            if topic == "robots/r1/telemetry/telemetry":
                published.append(payload)
            return publish(topic, payload, *args, **kwargs)

        paho.publish = recording
        task = asyncio.create_task(bridge.run())
        try:
            await obs.wait(lambda: len(published) >= 75)  # 1.5 s of a 50 Hz stream
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task
            notifier.close()
        topic = "robots/r1/telemetry/telemetry"
        await obs.wait(lambda: len(obs.on(topic)) >= len(published))
    sent = [json.loads(p) for p in published]
    assert obs.on(topic) == sent  # each one, once, in the order published
    stamps = [m["monotonic"] for m in sent]
    assert stamps == sorted(set(stamps))  # the device's order, no repeat
    assert set(stamps) <= set(produced)  # each a frame the device produced
    first, last = produced.index(stamps[0]), produced.index(stamps[-1])
    # A frame is skipped only when a newer one came before the bridge's next slot
    # (latest-value, never a backlog): at 100/s for a 50 Hz stream, rarely.
    assert len(stamps) >= 0.8 * (last - first + 1), (len(stamps), last - first + 1)
    assert all(m["type"] == Telemetry.__name__ for m in sent)


async def test_a_device_lost_for_good_ends_the_bridge_with_its_last_will() -> None:
    # A device that does not reconnect ends its streams when its link is lost, and
    # the bridge with them: its last link state and the LINK_LOST event are
    # published first, then the broker publishes the last will.
    async with broker() as b, ChassisSimulator() as sim, Observer(b) as obs:
        async with Chassis(sim.port, reconnect=False) as robot:
            bridge = MqttBridge(robot, bridge_client(b, "r1"), "r1")
            task = asyncio.create_task(bridge.run())
            await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
            sim.unplug()
            with pytest.raises(ConnectionLostError):
                await asyncio.wait_for(task, 10)
        await obs.wait(lambda: obs.on("robots/r1/connection")[-1]["state"] == "CONNECTIONBROKEN")
        assert obs.on("robots/r1/link")[-1]["state"] == "lost"
        assert "LINK_LOST" in [e["kind"] for e in obs.on("robots/r1/events")]


@pytest.mark.slow
async def test_telemetry_behind_a_stalled_broker_is_skipped_not_queued() -> None:
    # The broker stops reading (SIGSTOP) while the bridge publishes every stream at
    # 100 a second through a small send buffer: once the socket is full, the bridge
    # skips its slots and counts them instead of queueing messages, so its outgoing
    # queue holds at most one slot's messages; once the broker is back, the newest
    # readings go out again.
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        Observer(b) as obs,
    ):
        assert b.proc is not None
        # A long timeout: the skipping is under test, not the end of the bridge (below).
        client = bridge_client(b, "r1", socket_options=SMALL_SEND_BUFFER, timeout=60.0)
        bridge = MqttBridge(robot, client, "r1", rate=100.0)
        streams = len(bridge.profile.remote.streams)
        paho: Any = client_internals(client).paho
        task = asyncio.create_task(bridge.run())
        topic = "robots/r1/telemetry/telemetry"
        try:
            await obs.wait(lambda: bool(obs.on(topic)))
            os.kill(b.proc.pid, signal.SIGSTOP)
            try:
                most = 0

                def skipped() -> bool:
                    nonlocal most
                    most = max(most, len(paho._out_packet))
                    return bridge.telemetry_skipped >= 20

                await until(skipped, timeout=30.0)
                assert most <= streams, (most, streams)
            finally:
                os.kill(b.proc.pid, signal.SIGCONT)
                resumed = time.monotonic()
            # A reading newer than the broker's return arrives: the bridge went on.
            await obs.wait(
                lambda: any(m["monotonic"] > resumed for m in obs.on(topic)), timeout=15.0
            )
            assert not task.done()
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task


@pytest.mark.slow
@pytest.mark.timing
async def test_a_broker_that_reads_nothing_for_the_timeout_ends_the_bridge() -> None:
    # As a publish waiting for the client's ``timeout`` did: once the socket is full
    # and the slots have been skipped for that long, the bridge ends ("broker lost";
    # `chassis-sdk bridge` then connects again), not later on the keepalive.
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        Observer(b) as obs,
    ):
        assert b.proc is not None
        client = bridge_client(b, "r1", socket_options=SMALL_SEND_BUFFER, timeout=1.0)
        bridge = MqttBridge(robot, client, "r1", rate=100.0)
        task = asyncio.create_task(bridge.run())
        try:
            # Up (its claim and retained topics acknowledged) and publishing.
            await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
            os.kill(b.proc.pid, signal.SIGSTOP)
            try:
                await until(lambda: bridge.telemetry_skipped > 0, timeout=30.0)
                first_skip = time.monotonic()
                # (Its disconnect then times out too, and that is the error raised.)
                with pytest.raises(aiomqtt.MqttError):
                    async with asyncio.timeout(10.0):
                        await task
                waited = time.monotonic() - first_skip
                assert 0.9 <= waited <= 4.0, waited  # 1 s, then the disconnect's 1 s
            finally:
                os.kill(b.proc.pid, signal.SIGCONT)
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task


async def test_a_skipped_slot_keeps_its_readings_for_the_next(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A slot skipped (the connection still holding unwritten packets) leaves each
    # stream's newest message where it was: the last reading before the device falls
    # silent still goes out once the connection has room, not lost with the slot.
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port) as robot,
        Observer(b) as obs,
    ):
        bridge = MqttBridge(robot, bridge_client(b, "r1"), "r1", rate=5.0)
        topic = "robots/r1/telemetry/telemetry"
        produced: list[float] = []
        notifier = Notifier(robot)
        notifier.listen("telemetry", lambda t: produced.append(t.timestamp))
        task = asyncio.create_task(bridge.run())
        try:
            await obs.wait(lambda: bool(obs.on(topic)))
            monkeypatch.setattr(mqtt_publish, "unwritten", lambda client: True)
            skipped = bridge.telemetry_skipped
            sim.faults.drop_rate = 1.0  # the device falls silent
            await asyncio.sleep(0.05)  # what was on its way is read
            last = produced[-1]
            # Two slots (of 200 ms) skipped after the last reading.
            await until(lambda: bridge.telemetry_skipped >= skipped + 2)
            assert produced[-1] == last
            monkeypatch.undo()
            await obs.wait(lambda: any(m["monotonic"] == last for m in obs.on(topic)))
        finally:
            notifier.close()
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task


async def test_events_behind_a_stalled_broker_keep_the_newest_and_count_the_rest() -> None:
    # The broker stops (SIGSTOP) while the device produces ten events: the bridge waits
    # for the first one's acknowledgement, keeps the newest ``queue_size`` (4) behind
    # it and counts the five it dropped; once the broker is back they go out in order.
    async with (
        broker() as b,
        ChassisSimulator() as sim,
        Chassis(sim.port, queue_size=4) as robot,
        Observer(b) as obs,
    ):
        assert b.proc is not None
        bridge = MqttBridge(robot, bridge_client(b, "r1"), "r1")
        task = asyncio.create_task(bridge.run())
        try:
            await obs.wait(lambda: bool(obs.on("robots/r1/telemetry/telemetry")))
            produced: list[RobotEvent] = []
            notifier = Notifier(robot)
            notifier.listen("events", produced.append)
            os.kill(b.proc.pid, signal.SIGSTOP)
            try:
                for k in range(10):
                    sim.firmware.set_remote_estop(k % 2 == 0)
                    await until(lambda k=k: len(produced) > k)  # type: ignore[misc]
            finally:
                os.kill(b.proc.pid, signal.SIGCONT)
                notifier.close()
            assert [e.kind.value for e in produced] == ["estop_engaged", "estop_released"] * 5
            await obs.wait(lambda: len(obs.on("robots/r1/events")) >= 5)
            await asyncio.sleep(0.3)  # nothing more comes
            assert bridge.unpublished == 5
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, aiomqtt.MqttError):
                await task
    stamps = [e["monotonic"] for e in obs.on("robots/r1/events")]
    assert stamps == [e.timestamp for e in (produced[0], *produced[-4:])]


async def test_packets_queued_while_the_socket_has_room_are_no_stall() -> None:
    # paho queues a packet at once and aiomqtt writes it a turn or two of the loop
    # later: a telemetry slot that came in between counted a skip and started the
    # stall clock (before: `unwritten` was paho's want_write), so a bridge under load
    # could be judged stalled by the broker it was writing to without trouble.
    async with broker() as b:
        client = bridge_client(b, "r1")
        async with client:
            paho = client_internals(client).paho
            paho.publish("robots/r1/x", b"queued")  # queued, not written yet
            assert paho.want_write()
            assert not mqtt_publish.unwritten(client)  # the socket has room: no stall
            assert mqtt_publish.queued(client)
            await until(lambda: not mqtt_publish.queued(client))  # the loop wrote it
