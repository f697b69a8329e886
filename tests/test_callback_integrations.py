"""The web dashboard and the ROS 2 bridge take their data by callback (issue 29, item 3):
a fixed number of tasks each, whatever the device's streams (a chassis has three, a
board four), and what reaches a page or a DDS reader still comes in order. The ROS 2
tests join DDS, each in a network namespace of its own (the ``netns`` marker)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import os
import time
import tty
from collections.abc import AsyncIterator, Iterator
from pathlib import Path
from typing import Any

import anyio
import pytest

from chassis_sdk import Board, Chassis, EventKind
from chassis_sdk.errors import ConnectionLostError
from chassis_sdk.protocol import BoardEncoder, ImuSample
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.helpers import until

pytestmark = pytest.mark.timeout(60)

DOMAIN = 29
INTEGRATIONS = Path(__file__).resolve().parent.parent / "chassis_sdk" / "integrations"


def tasks_of(module: str) -> list[str]:
    """The running tasks that run a function of ``integrations/<module>`` (the first
    such function of each, through anyio's wrapper), by the function's name."""
    path = str(INTEGRATIONS / module)
    found = []
    for task in asyncio.all_tasks():
        coro: Any = task.get_coro()
        while coro is not None and hasattr(coro, "cr_code"):
            if coro.cr_code.co_filename == path:
                found.append(coro.cr_code.co_name)
                break
            coro = coro.cr_await
    return sorted(found)


@contextlib.asynccontextmanager
async def device_on_simulator(board: bool) -> AsyncIterator[tuple[Any, Any]]:
    simulator = BoardSimulator() if board else ChassisSimulator()
    device = Board if board else Chassis
    async with simulator as sim, device(sim.port) as robot:
        yield sim, robot


# --- the dashboard -------------------------------------------------------------------------


@pytest.mark.parametrize("board", [False, True], ids=["chassis", "board"])
async def test_the_dashboard_has_no_task_per_stream_and_pages_get_states_in_order(
    board: bool,
) -> None:
    pytest.importorskip("aiohttp", reason="the dashboard's extra: pip install '.[web]'")
    import websockets

    from chassis_sdk.integrations.web import WebDashboard

    async with (
        device_on_simulator(board) as (_sim, robot),
        WebDashboard(robot, port=0, rate=50) as web,
        websockets.connect(f"ws://127.0.0.1:{web.port}/ws") as ws,
    ):
        hello = json.loads(await ws.recv())
        assert hello["type"] == "hello"
        states = [json.loads(await ws.recv()) for _ in range(15)]
        # Its own task, the velocity writer, the state broadcast, and this page's two
        # (its handler, its sender): before, also one for the events and one per stream
        # (9 for a chassis, 10 for a board).
        tasks = ["_guarded", "_guarded", "_run_tasks", "_send", "_socket"]
        assert tasks_of("web.py") == tasks
        events: list[dict[str, Any]] = []
        if not board:
            await robot.emergency_stop(confirm=True)
            await robot.release_emergency_stop(confirm=True)
            async with asyncio.timeout(5.0):
                while len(events) < 2:
                    state = json.loads(await ws.recv())
                    states.append(state)
                    events += [e for e in state.get("events", []) if "ESTOP" in e["kind"]]
    assert all(s["type"] == "state" for s in states)
    times = [s["time"] for s in states]
    assert times == sorted(times)
    stamps = [s["odometry"]["timestamp"] for s in states if s["odometry"] is not None]
    assert len(stamps) >= 10
    # The newest kept each time, never an older one (each state converts the reading's
    # monotonic time to wall time afresh: the same reading differs by microseconds).
    assert all(later > earlier - 0.001 for earlier, later in itertools.pairwise(stamps))
    assert len({round(t, 3) for t in stamps}) >= 3  # and newer ones come
    if not board:
        kinds = [e["kind"] for e in events]
        assert kinds[:2] == [EventKind.ESTOP_ENGAGED.name, EventKind.ESTOP_RELEASED.name]


# --- the ROS 2 bridge ------------------------------------------------------------------------


def _graph_reader(name: str, tp: type) -> Any:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    dp = DomainParticipant(DOMAIN)
    qos = Qos(
        Policy.Reliability.Reliable(0),
        Policy.Durability.Volatile,
        Policy.History.KeepLast(1000),
    )
    return DataReader(dp, Topic(dp, name, tp), qos)


def _samples(reader: Any) -> list[Any]:
    return [s for s in reader.take(N=1000) if hasattr(s, "__idl_typename__")]


def _seconds(stamp: Any) -> float:
    return float(stamp.sec) + float(stamp.nanosec) * 1e-9


@contextlib.asynccontextmanager
async def bridged(device: Any, **options: Any) -> AsyncIterator[Any]:
    from chassis_sdk.integrations.ros2 import Ros2Bridge
    from chassis_sdk.integrations.ros2_dds import Discovery

    bridge = Ros2Bridge(device, discovery=Discovery(domain_id=DOMAIN), **options)
    async with anyio.create_task_group() as tg:
        tg.start_soon(bridge.run)
        await bridge.started.wait()
        yield bridge
        tg.cancel_scope.cancel()


@pytest.mark.netns
@pytest.mark.parametrize("board", [False, True], ids=["chassis", "board"])
async def test_the_ros2_bridge_has_no_task_per_stream_and_odometry_comes_in_order(
    board: bool,
) -> None:
    pytest.importorskip("cyclonedds", reason="the ros2 extra: pip install '.[ros2]'")
    from chassis_sdk.recording import ros2_types as m

    async with device_on_simulator(board) as (_sim, robot), bridged(robot) as bridge:
        odom = _graph_reader("rt/odom", m.Odometry)
        got: list[Any] = []

        def enough() -> bool:
            got.extend(_samples(odom))
            return len(got) >= 40

        await until(enough, 10.0)
        # run() itself, and one task each for the readings, /diagnostics, cmd_vel and
        # emergency_stop: before, one per stream instead of "_publish" (a chassis's
        # odometry and telemetry, a board's odometry, imu and battery).
        assert tasks_of("ros2.py") == ["_commands", "_diagnostics", "_estops", "_publish", "run"]
        published = bridge.odometry_published
    stamps = [_seconds(o.header.stamp) for o in got]
    assert stamps == sorted(stamps)
    assert len(set(stamps)) == len(stamps)
    assert published >= len(got)
    assert bridge.dropped_readings == 0


@pytest.mark.netns
async def test_a_link_lost_for_good_ends_the_bridge_with_connection_lost() -> None:
    pytest.importorskip("cyclonedds", reason="the ros2 extra: pip install '.[ros2]'")
    from chassis_sdk.integrations.ros2 import Ros2Bridge
    from chassis_sdk.integrations.ros2_dds import Discovery

    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:  # no reconnect
        bridge = Ros2Bridge(robot, discovery=Discovery(domain_id=DOMAIN))
        ended: list[BaseException] = []

        async def run() -> None:
            try:
                await bridge.run()
            except* ConnectionLostError as group:
                ended.extend(group.exceptions)

        async with anyio.create_task_group() as tg:
            tg.start_soon(run)
            await bridge.started.wait()
            await until(lambda: bridge.odometry_published > 5, 5.0)
            sim.unplug()
            with anyio.fail_after(5.0):
                while not ended:
                    await asyncio.sleep(0.01)
        assert ended  # (before: one for each stream's task)
        assert all(sim.port in str(error) for error in ended)


@contextlib.contextmanager
def raw_pty() -> Iterator[tuple[int, str]]:
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        yield master, os.ttyname(slave)
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.netns
async def test_a_burst_keeps_the_newest_queue_size_readings_and_counts_the_rest() -> None:
    pytest.importorskip("cyclonedds", reason="the ros2 extra: pip install '.[ros2]'")
    from chassis_sdk.protocol import Vector3
    from chassis_sdk.recording import ros2_types as m

    encoder = BoardEncoder()
    zero = Vector3(0.0, 0.0, 0.0)
    # Accelerations of k / 164 g (exact on the wire: 164 counts a g).
    burst = b"".join(
        encoder.encode(ImuSample(accel=Vector3(k / 164, 0.0, 0.0), gyro=zero, mag=zero))
        for k in range(1, 21)
    )
    with raw_pty() as (master, path):
        async with Board(path, queue_size=4) as board, bridged(board, read_only=True) as bridge:
            imu = _graph_reader("rt/imu/data_raw", m.Imu)
            probe = encoder.encode(ImuSample(accel=Vector3(1.0, 0.0, 0.0), gyro=zero, mag=zero))
            seen: list[Any] = []

            def matched() -> bool:  # the reader sees the bridge's writer
                os.write(master, probe)
                seen.extend(_samples(imu))
                return bool(seen)

            await until(matched, 10.0)
            dropped = bridge.dropped_readings
            os.write(master, burst)  # one read, 20 readings before the publisher runs
            got: list[Any] = []

            def arrived() -> bool:
                got.extend(_samples(imu))
                return any(round(s.linear_acceleration.x / 9.80665 * 164) == 20 for s in got)

            start = time.monotonic()
            await until(arrived, 5.0)
            assert time.monotonic() - start < 5.0
    ks = [round(s.linear_acceleration.x / 9.80665 * 164) for s in got]
    ks = [k for k in ks if k != 164]  # the probes still in flight
    assert ks == [17, 18, 19, 20]  # the newest queue_size, in order
    # The 16 older ones of the burst (and any probe read with it) dropped and counted.
    assert bridge.dropped_readings - dropped >= 16
