"""Reflexes on the simulators, through the real transport: per hazard, the fault
injected as ``chassis-sdk sim`` takes it (``sim.command``), the event, and the wire.
The rules themselves are in ``test_reflex_rules.py``."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import AsyncIterator
from typing import Any

import pytest

from chassis_sdk import (
    Board,
    Chassis,
    EventKind,
    Geofence,
    MotionBlockedError,
    Reflex,
    RobotEvent,
    SafetyPolicy,
)
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import BoardSimulator, ChassisSimulator

from .support.helpers import until

pytestmark = pytest.mark.integration


def drives_since(sim: ChassisSimulator, since: float) -> list[tuple[float, int]]:
    """The velocity commands the chassis read after ``since``: (time, mm/s)."""
    return [
        (t, c.linear_mm)
        for t, c in sim.firmware.received
        if t >= since and isinstance(c, DriveVelocity)
    ]


@contextlib.asynccontextmanager
async def watching(robot: Any) -> AsyncIterator[list[RobotEvent]]:
    """The device's events, collected while the block runs."""
    seen: list[RobotEvent] = []

    async def collect() -> None:
        async for event in robot.events():
            seen.append(event)

    task = asyncio.create_task(collect())
    await asyncio.sleep(0)
    try:
        yield seen
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def reflexes(seen: list[RobotEvent]) -> list[tuple[str, str | None]]:
    return [(e.source, e.action) for e in seen if e.kind is EventKind.REFLEX]


async def driving(robot: Chassis, sim: ChassisSimulator, speed: float = 0.3) -> None:
    await robot.set_velocity(speed, 0.0, duration=5.0)
    await until(lambda: abs(sim.firmware.wheels[0]) > abs(speed) / 2)


async def test_a_bumper_hit_is_a_reflex_event_and_the_zero_follows_its_frame() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot, watching(robot) as seen:
        await driving(robot, sim)
        hit = time.monotonic()
        assert sim.command("bumper front").startswith("ok")
        await until(lambda: bool(reflexes(seen)))
        assert reflexes(seen) == [("front_bumper", "stop")]
        await until(lambda: any(mm == 0 for t, mm in drives_since(sim, hit)))
        zero = next(t for t, mm in drives_since(sim, hit) if mm == 0)
        assert zero - hit < 0.1  # a telemetry period, the read path, the pty
        with pytest.raises(MotionBlockedError, match="FRONT_BUMPER"):
            await robot.set_velocity(0.3, 0.0)


async def test_back_off_clears_the_latch_drives_away_and_stops() -> None:
    policy = SafetyPolicy(bumper=Reflex("back_off", distance=0.1, speed=0.1))
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, safety=policy) as robot,
        watching(robot) as seen,
    ):
        await driving(robot, sim, 0.2)
        sim.command("bumper front")
        await until(lambda: bool(reflexes(seen)))
        assert reflexes(seen) == [("front_bumper", "back_off")]
        await until(lambda: robot.latest_odometry is not None and robot.motion.blocks == ())
        start = robot.latest_odometry
        assert start is not None
        await until(lambda: any(mm < 0 for _, mm in drives_since(sim, 0.0)), 3.0)
        await until(lambda: drives_since(sim, 0.0)[-1][1] == 0 and robot.motion.driver is None, 8.0)
        end = robot.latest_odometry
        assert end is not None
        assert start.x - end.x == pytest.approx(0.1, abs=0.03)  # 0.1 m away, backwards
        assert min(mm for _, mm in drives_since(sim, 0.0)) >= -100  # at its speed


async def test_a_stall_stops_the_robot_and_a_new_command_drives() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot, watching(robot) as seen:
        await driving(robot, sim)
        stalled = time.monotonic()
        assert sim.command("stall 3").startswith("ok")
        await until(lambda: bool(reflexes(seen)), 3.0)
        assert reflexes(seen) == [("stall", "stop")]
        await until(lambda: any(mm == 0 for _, mm in drives_since(sim, stalled)))
        assert robot.commanded_velocity is None
        assert robot.motion.blocks == ()  # drive it clear
        await robot.set_velocity(-0.1, 0.0, duration=0.2)


async def test_a_geofence_stops_the_robot_at_its_edge() -> None:
    policy = SafetyPolicy(fence=Geofence.rectangle(0.6, 0.6))
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, safety=policy) as robot,
        watching(robot) as seen,
    ):
        await until(lambda: robot.latest_odometry is not None)
        with pytest.raises(MotionBlockedError, match="REFLEX_GEOFENCE"):
            await robot.drive_distance(1.0, 0.2, timeout=10.0)
        await until(lambda: reflexes(seen) == [("geofence", "stop")])
        await until(lambda: all(abs(w) < 1e-3 for w in sim.firmware.wheels))
        pose = robot.latest_odometry
        assert pose is not None
        assert 0.3 < pose.x < 0.35  # just past the edge: the reflex, then the stop
        result = await robot.drive_distance(-0.2, 0.2, timeout=10.0)  # back inside
        assert result.ended == "done"


async def test_a_critical_battery_blocks_until_it_recovers() -> None:
    policy = SafetyPolicy(battery_critical=22.0)
    async with (
        ChassisSimulator() as sim,
        Chassis(sim.port, safety=policy) as robot,
        watching(robot) as seen,
    ):
        await driving(robot, sim)
        assert sim.command("battery 21.0").startswith("ok")
        await until(lambda: robot.motion.blocks == ("REFLEX_BATTERY",))
        assert reflexes(seen) == [("battery", "stop")]
        with pytest.raises(MotionBlockedError, match="REFLEX_BATTERY"):
            await robot.set_velocity(0.3, 0.0)
        sim.command("battery 25.0")
        await until(lambda: robot.motion.blocks == ())


async def test_a_silent_link_while_moving_stops_within_the_silence() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot, watching(robot) as seen:
        await driving(robot, sim)
        sim.reset_firmware(downtime=1.0)  # silent and deaf for a second
        await until(lambda: bool(reflexes(seen)), 2.0)
        assert reflexes(seen) == [("link", "stop")]
        assert robot.commanded_velocity is None
        assert robot.motion.blocks == ()  # only while moving: a new command, once back
        await until(lambda: robot.last_frame_age is not None and robot.last_frame_age < 0.1, 5.0)
        await driving(robot, sim, 0.1)


async def test_a_board_tilted_past_its_angle_stops() -> None:
    async with BoardSimulator() as sim, Board(sim.port) as robot, watching(robot) as seen:
        samples = 0
        async for _ in robot.imu():  # the level: gravity over its first 0.5 s (100 Hz)
            samples += 1
            if samples >= 60:
                break
        await robot.set_velocity(0.2, 0.0, duration=5.0)
        assert sim.command("tilt 30").startswith("ok")
        await until(lambda: robot.motion.blocks == ("REFLEX_TILT",), 3.0)
        assert [s for s, _ in reflexes(seen)] == ["tilt"]
        assert robot.commanded_velocity is None
        sim.command("tilt 0")
        await until(lambda: robot.motion.blocks == (), 5.0)


@pytest.mark.parametrize("hazard", ["bumper", "stall", "tilt", "geofence", "battery", "link"])
def test_ignore_is_refused_without_allow_unsafe(hazard: str) -> None:
    ignored: dict[str, Any] = {hazard: Reflex("ignore")}
    with pytest.raises(ValueError, match="allow_unsafe"):
        SafetyPolicy(**ignored)
    assert math.isfinite(SafetyPolicy(**ignored, allow_unsafe=True).stall_time)
