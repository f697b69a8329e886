"""Goals on the simulators through the real transport: one test per way a goal ends
(done, cancel, timeout, block, pre-empt by a source, by a stop, by a newer goal, by the
application's own velocity), each showing the wire; a board's goals; the blocking twins.
The plans' own rules (profile, tolerance, no oscillation) are in ``test_goal_plans.py``."""

from __future__ import annotations

import asyncio
import math
import time

import pytest

from chassis_sdk import (
    Board,
    Chassis,
    MotionBlockedError,
    MovePreemptedError,
    MoveTimeoutError,
    NotConnectedError,
)
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.helpers import until

pytestmark = pytest.mark.integration

#: Watching the wire for a command that must not come: past the deadman (0.5 s).
QUIET = 0.7


def drives_since(sim: ChassisSimulator, since: float) -> list[tuple[float, int, float]]:
    """The velocity commands the chassis read after ``since``: (time, mm/s, rad/s)."""
    return [
        (t, c.linear_mm, c.angular)
        for t, c in sim.firmware.received
        if t >= since and isinstance(c, DriveVelocity)
    ]


def moving(sim: ChassisSimulator) -> bool:
    return any(abs(w) > 0.05 for w in sim.firmware.wheels)


async def test_drive_distance_ends_within_tolerance_and_stopped() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        result = await robot.drive_distance(0.4, 0.3, timeout=10.0)
        assert result.ended == "done"
        assert abs(result.error) <= 0.01
        assert result.pose is not None
        assert result.pose.x == pytest.approx(0.4, abs=0.01)
        assert abs(result.pose.y) < 0.005
        assert 1.0 < result.duration < 5.0
        last = drives_since(sim, 0.0)[-1]
        assert last[1:] == (0, 0.0)  # the last word on the wire is a zero
        assert max(mm for _, mm, _ in drives_since(sim, 0.0)) <= 300
        assert robot.motion.driver is None
        assert [s.name for s in robot.motion.arbiter.sources] == ["api"]  # its source is gone


@pytest.mark.slow
async def test_rotate_and_go_to_end_within_tolerance() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        turned = await robot.rotate(math.radians(90), timeout=10.0)
        assert turned.ended == "done"
        assert abs(math.degrees(turned.error)) <= 1.0
        went = await robot.go_to(0.3, -0.3, 0.0, timeout=15.0)
        assert went.ended == "done"
        assert went.error <= 0.01
        assert abs(math.degrees(went.heading_error)) <= 1.0
        assert went.pose is not None
        assert went.pose.distance_to(0.3, -0.3) <= 0.01
        assert not moving(sim)


async def test_cancelling_the_task_writes_a_zero_at_once_and_nothing_after() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        task = asyncio.create_task(robot.drive_distance(3.0))
        await until(lambda: moving(sim))
        cancelled = time.monotonic()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        await until(lambda: any(mm == 0 for _, mm, _ in drives_since(sim, cancelled)), 1.0)
        zero_at = next(t for t, mm, _ in drives_since(sim, cancelled) if mm == 0)
        assert zero_at - cancelled < 0.025  # within one period
        await asyncio.sleep(QUIET)
        assert [mm for _, mm, _ in drives_since(sim, cancelled)] == [0]
        assert robot.motion.driver is None


async def test_a_timeout_stops_and_raises_with_where_it_got() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        began = time.monotonic()
        with pytest.raises(MoveTimeoutError, match="did not finish in 0.5 s") as caught:
            await robot.drive_distance(3.0, timeout=0.5)
        assert isinstance(caught.value, TimeoutError)
        result = caught.value.result
        assert result.ended == "timeout"
        assert 2.5 < result.error < 3.0
        await until(lambda: drives_since(sim, began)[-1][1] == 0, 1.0)
        ended = time.monotonic()
        await asyncio.sleep(QUIET)
        assert [mm for _, mm, _ in drives_since(sim, ended)] == []


async def test_a_bumper_ends_the_goal_blocked_and_clearing_it_restarts_nothing() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        task = asyncio.create_task(robot.drive_distance(3.0))
        await until(lambda: moving(sim))
        sim.firmware.press_bumper(front=True)
        with pytest.raises(MotionBlockedError, match="FRONT_BUMPER") as caught:
            await task
        assert caught.value.reasons == ("FRONT_BUMPER",)
        await robot.clear_faults()
        await until(lambda: robot.motion.blocks == ())
        cleared = time.monotonic()
        await asyncio.sleep(QUIET)
        assert [mm for _, mm, _ in drives_since(sim, cleared) if mm] == []


async def test_a_goal_does_not_start_while_blocked_or_closed() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.emergency_stop(confirm=True)
        since = time.monotonic()
        with pytest.raises(MotionBlockedError, match="SOFTWARE_ESTOP"):
            await robot.rotate(1.0)
        assert drives_since(sim, since) == []
    with pytest.raises(NotConnectedError):
        await robot.drive_distance(1.0)


@pytest.mark.parametrize(
    ("call", "error"),
    [
        (lambda r: r.drive_distance(math.nan), ValueError),
        (lambda r: r.drive_distance("1"), TypeError),
        (lambda r: r.drive_distance(1.0, -0.2), ValueError),
        (lambda r: r.drive_distance(1.0, tolerance=0.0), ValueError),
        (lambda r: r.rotate(1.0, timeout=-1.0), ValueError),
        (lambda r: r.go_to(1.0, math.inf), ValueError),
        (lambda r: r.go_to(1.0, 0.0, heading="north"), TypeError),
    ],
)
async def test_bad_arguments_raise_before_anything_is_written(call: object, error: type) -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        since = time.monotonic()
        with pytest.raises(error):
            await call(robot)  # type: ignore[operator]
        assert drives_since(sim, since) == []


@pytest.mark.parametrize(
    "by", ["a dashboard page", "a stop", "the application's velocity", "a newer goal"]
)
async def test_another_source_preempts_the_goal_and_keeps_the_robot(by: str) -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        task = asyncio.create_task(robot.drive_distance(3.0))
        await until(lambda: moving(sim))
        newer = None
        if by == "a dashboard page":
            page = robot.motion.source("web page", kind="web")
            assert page.set_velocity(-0.1, 0.0) is None
            expect, want = "taken by web page", -100
        elif by == "a stop":
            await robot.stop()
            expect, want = "stopped by api", 0
        elif by == "the application's velocity":
            await robot.set_velocity(0.05, 0.0, duration=0.3)
            expect, want = "taken by api", 50
        else:
            newer = asyncio.create_task(robot.rotate(0.5))
            expect, want = "taken by rotate", None
        with pytest.raises(MovePreemptedError, match=expect) as caught:
            await task
        assert caught.value.result.ended == "preempted"
        if want is not None:  # the one who took over drives (its frame may be on its way)
            await until(lambda: drives_since(sim, 0.0)[-1][1] == want, 1.0)
        if newer is not None:
            result = await newer
            assert result.ended == "done"
            assert all(mm == 0 for _, mm, _ in drives_since(sim, time.monotonic() - 0.3))


async def test_a_board_drives_a_distance_and_turns() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        moved = await robot.drive_distance(0.3, timeout=10.0)
        assert moved.ended == "done"
        assert abs(moved.error) <= 0.01
        turned = await robot.rotate(-math.pi / 2, timeout=10.0)
        assert abs(math.degrees(turned.error)) <= 1.0


@pytest.mark.slow
def test_the_blocking_twins() -> None:
    from chassis_sdk import sync

    with sync.Simulator("chassis") as sim, sync.Chassis(sim.port) as robot:
        for _ in robot.odometry(timeout=5.0):
            break
        assert robot.drive_distance(0.2, timeout=10.0).ended == "done"
        assert robot.rotate(0.5, timeout=10.0).ended == "done"
        assert robot.go_to(0.0, 0.0, timeout=15.0).error <= 0.01
        with pytest.raises(MoveTimeoutError):
            robot.drive_distance(2.0, timeout=0.2)


async def test_a_stall_ends_the_goal_with_the_reflexs_block() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        task = asyncio.create_task(robot.drive_distance(3.0))
        await until(lambda: moving(sim))
        stalled = time.monotonic()
        assert sim.command("stall 3").startswith("ok")
        with pytest.raises(MotionBlockedError, match="REFLEX_STALL") as caught:
            await task
        assert caught.value.reasons == ("REFLEX_STALL",)
        await until(lambda: drives_since(sim, stalled)[-1][1] == 0, 1.0)


async def test_a_goal_into_a_wall_of_the_world_ends_at_the_bumper() -> None:
    from chassis_sdk.sim import World

    async with ChassisSimulator(world=World.arena(2.0, 2.0)) as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        with pytest.raises(MotionBlockedError, match="FRONT_BUMPER"):
            await robot.drive_distance(3.0, 0.3, timeout=15.0)
        x, _, _ = sim.firmware.true_pose
        length, _ = sim.firmware.footprint
        assert x + length / 2 == pytest.approx(1.0, abs=0.05)  # its front at the wall (x = 1)
        await until(lambda: all(abs(w) < 1e-3 for w in sim.firmware.wheels))
        await robot.clear_faults(confirm=True)
        await until(lambda: robot.motion.blocks == ())
        back = await robot.drive_distance(-0.3, timeout=10.0)  # backing away is free
        assert back.ended == "done"


async def test_a_stop_before_the_goals_first_sample_ends_it_unstarted() -> None:
    # The goal was called, then a stop came before its first odometry sample (an MQTT
    # request then a stop within a period): it must not drive afterwards.
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        since = time.monotonic()
        task = asyncio.create_task(robot.drive_distance(1.0))
        await asyncio.sleep(0)  # it runs up to its first sample
        await robot.stop()
        with pytest.raises(MovePreemptedError, match="stopped"):
            await task
        await asyncio.sleep(QUIET)
        assert [mm for _, mm, _ in drives_since(sim, since) if mm] == []


async def test_a_goal_already_there_stops_nobody_else() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await until(lambda: robot.latest_odometry is not None)
        page = robot.motion.source("web page", kind="web")
        assert page.set_velocity(0.0, 0.5, duration=2.0) is None  # a page turns it
        result = await robot.rotate(0.0)  # there already: done, and it stops nothing
        assert result.ended == "done"
        assert page.driving
        assert drives_since(sim, 0.0)[-1][2] == pytest.approx(0.5)
