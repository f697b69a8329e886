"""Lifetime hygiene: open/close cycles leak nothing, and cancellation at any await in
the API propagates as a bare ``CancelledError`` and leaves nothing pending."""

from __future__ import annotations

import asyncio
import os
from collections.abc import Awaitable, Callable
from typing import Any

import pytest

from chassis_sdk import Board, Chassis, ConnectionState, PortOpenError
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.standin import BoardStandIn, ChassisStandIn, last_drive_is_zero

pytestmark = pytest.mark.integration

TRANSPORTS = [pytest.param(None, id="pty"), pytest.param(0, id="tcp")]


def open_fds() -> set[tuple[str, str]]:
    """The process's open descriptors, each with what it is (``socket:[inode]``, a
    path): a descriptor number closed by someone else and reused by a leak still shows
    as new, and one merely closed meanwhile (by a collected object of an earlier test)
    is not a leak of this one."""
    found = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            found.add((fd, os.readlink(f"/proc/self/fd/{fd}")))
        except FileNotFoundError:  # the listing's own descriptor, closed by now
            continue
    return found


def ours(fds: set[tuple[str, str]], sim: ChassisSimulator) -> set[tuple[str, str]]:
    """``fds`` without the simulator's own pty: it keeps the slave open, and after a
    replug that is a new node, whose number depends on which ptys other processes hold
    (devpts gives the lowest free one), so it is not a descriptor of the SDK's."""
    node = os.path.realpath(sim.port)
    return {(fd, path) for fd, path in fds if path != node}


def other_tasks() -> set[asyncio.Task[Any]]:
    current = asyncio.current_task()
    return {t for t in asyncio.all_tasks() if t is not current}


async def wait_until(predicate: Callable[[], bool], timeout: float = 2.0) -> None:
    """Wait for a state reached in a callback: checked once per loop iteration."""
    async with asyncio.timeout(timeout):
        while not predicate():
            await asyncio.sleep(0)


# --- leaks ------------------------------------------------------------------------------------


@pytest.mark.parametrize("tcp_port", TRANSPORTS)
async def test_open_close_cycles_leak_no_tasks_and_no_fds(tcp_port: int | None) -> None:
    async with ChassisSimulator(tcp_port=tcp_port) as sim, BoardSimulator() as board_sim:
        # One cycle first, so lazily created loop resources are not counted as leaks.
        async with Chassis(sim.port) as robot:
            await robot.get_firmware_version()
        await wait_until(lambda: not sim.clients)  # the server's end of it, too
        fds, tasks = open_fds(), other_tasks()
        for i in range(25):
            async with Chassis(sim.port, reconnect=bool(i % 2)) as robot:
                await anext(robot.telemetry())
                await robot.set_velocity(0.1, 0.0)
                await robot.get_firmware_version()
            async with Board(board_sim.port) as board:
                await board.get_led()
                async for _ in board.imu():
                    break
            robot2 = Chassis(sim.port)
            await robot2.connect()
            await robot2.close()
            await robot2.close()  # idempotent
        await wait_until(lambda: other_tasks() == tasks and not sim.clients)
        assert open_fds() - fds == set()  # nothing opened that is still open


async def test_failed_opens_and_reconnect_cycles_leak_nothing() -> None:
    async with ChassisSimulator() as sim:
        async with Chassis(sim.port, reconnect=True) as robot:
            await robot.get_firmware_version()
        fds, tasks = ours(open_fds(), sim), other_tasks()
        for _ in range(20):
            with pytest.raises(PortOpenError):
                await Chassis("/dev/does-not-exist").connect()
        async with Chassis(sim.port, reconnect=True) as robot:
            states = robot.connection_states()
            for _ in range(8):
                sim.unplug()
                assert await anext(states) is ConnectionState.RECONNECTING
                await sim.replug()
                assert await anext(states) is ConnectionState.CONNECTED
            assert robot.stats.reconnects == 8
            assert await robot.get_firmware_version() == 103
        await wait_until(lambda: other_tasks() == tasks)
        # (The first snapshot holds the simulator's pty before its eight replugs.)
        assert ours(open_fds(), sim) - fds == set()  # nothing opened that is still open


# --- cancellation -----------------------------------------------------------------------------

_CHASSIS_REQUESTS: list[tuple[str, int, Callable[[Chassis], Awaitable[Any]]]] = [
    ("get_firmware_version", 0x07, lambda r: r.get_firmware_version()),
    ("get_hardware_version", 0x08, lambda r: r.get_hardware_version()),
    ("get_chassis_info", 0x09, lambda r: r.get_chassis_info()),
    ("get_ship_date", 0x0A, lambda r: r.get_ship_date()),
    ("get_driver_status", 0xB0, lambda r: r.get_driver_status()),
]


@pytest.mark.parametrize(
    ("kind", "call"), [pytest.param(k, c, id=n) for n, k, c in _CHASSIS_REQUESTS]
)
async def test_cancelling_a_chassis_request_leaves_nothing_pending(
    kind: int, call: Callable[[Chassis], Awaitable[Any]]
) -> None:
    silent = {0x07, 0x08, 0x09, 0x0A, 0xB0}
    async with (
        ChassisStandIn(silent_ids=silent) as dev,
        Chassis(dev.port, request_timeout=1.0) as robot,
    ):
        task = asyncio.ensure_future(call(robot))
        await dev.wait_for(lambda fs: bool(dev.of_kind(kind)))
        assert len(robot._requests) == 1
        task.cancel()
        with pytest.raises(asyncio.CancelledError) as info:
            await task
        assert type(info.value) is asyncio.CancelledError  # never wrapped
        assert len(robot._requests) == 0
        dev.silent_ids.clear()
        # Still usable: the next request of that kind waits for the cancelled one's
        # reply or, as here where it never comes, a request_timeout's quarantine.
        await call(robot)
        assert robot.stats.unmatched_replies == 0


_BOARD_REQUESTS: list[tuple[str, Callable[[Board], Awaitable[Any]]]] = [
    ("get_led", lambda b: b.get_led()),
    ("set_led", lambda b: b.set_led(True)),
    ("get_buzzer", lambda b: b.get_buzzer()),
    ("set_buzzer", lambda b: b.set_buzzer(False)),
]


@pytest.mark.parametrize("call", [pytest.param(c, id=n) for n, c in _BOARD_REQUESTS])
async def test_cancelling_a_board_request_releases_its_id(
    call: Callable[[Board], Awaitable[Any]],
) -> None:
    async with BoardStandIn(silent=True) as dev, Board(dev.port, request_timeout=5.0) as board:
        tasks = [asyncio.ensure_future(call(board)) for _ in range(3)]
        await dev.wait_for(lambda fs: len([f for f in fs if f.kind in (1, 2)]) >= 3)
        for t in tasks:
            t.cancel()
        results = await asyncio.gather(*tasks, return_exceptions=True)
        assert all(type(r) is asyncio.CancelledError for r in results)
        assert len(board._requests) == 0
        # Their requests went out, so their ids are retired until the replies come or
        # the quarantine passes: the next request takes a fresh one and succeeds.
        used = [f.payload[1] for f in dev.frames if f.kind in (1, 2)]
        assert not any(board._id_free(rid) for rid in used)
        dev.silent = False
        await call(board)
        assert dev.frames[-1].payload[1] not in used


async def test_cancelling_stream_reads_and_waits_leaves_them_usable() -> None:
    async with ChassisStandIn() as dev, Chassis(dev.port, reconnect=True) as robot:
        sub = robot.telemetry()
        await anext(sub)
        reader = asyncio.ensure_future(anext(sub))
        await asyncio.sleep(0)
        reader.cancel()
        with pytest.raises(asyncio.CancelledError):
            await reader
        assert sub._waiter is None
        await anext(sub)  # still subscribed, still delivered
        waiter = asyncio.ensure_future(anext(robot.connection_states()))
        await asyncio.sleep(0)
        waiter.cancel()
        with pytest.raises(asyncio.CancelledError):
            await waiter
        await robot.wait_connected(0.5)
        # The cancellations left the link alone: never dropped, nothing sent.
        assert robot.stats.reconnects == 0
        assert dev.frames == []


async def test_cancelling_connect_leaves_the_device_closed_and_reusable() -> None:
    async with ChassisSimulator(tcp_port=0) as sim:
        fds, tasks = open_fds(), other_tasks()
        robot = Chassis(sim.port)
        task = asyncio.ensure_future(robot.connect())
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert robot.connection_state is ConnectionState.DISCONNECTED
        await wait_until(lambda: other_tasks() == tasks)
        assert open_fds() - fds == set()  # nothing opened that is still open
        async with robot:
            assert await robot.get_firmware_version() == 103


async def test_cancelling_close_still_stops_the_robot_and_closes() -> None:
    async with ChassisStandIn(noise=False) as dev:
        robot = Chassis(dev.port)
        await robot.connect()
        await robot.set_velocity(0.3, 0.0)
        closing = asyncio.ensure_future(robot.close())
        await asyncio.sleep(0)
        closing.cancel()
        with pytest.raises(asyncio.CancelledError) as info:
            await closing
        assert type(info.value) is asyncio.CancelledError
        assert robot.connection_state is ConnectionState.DISCONNECTED
        await dev.wait_for(last_drive_is_zero)


async def test_concurrent_closes_both_wait_until_closed() -> None:
    async with ChassisSimulator() as sim:
        robot = Chassis(sim.port)
        await robot.connect()
        first = asyncio.ensure_future(robot.close())
        await asyncio.sleep(0)
        await robot.close()  # returns only once the first close has finished
        assert robot.connection_state is ConnectionState.DISCONNECTED
        await first
        await robot.connect()  # and it can be opened again
        await robot.close()
