"""An e-stop or a hazard ends the command, and clearing it restarts nothing (ISO 13850),
through the real transport against the simulated chassis: what the issue found with the
API, each a test that failed before the motion core.

Each test ends by watching the wire for longer than the deadman and the longest command
given (``QUIET``): that nothing moves is seen over a time, not at an instant.
"""

from __future__ import annotations

import asyncio
import time

import pytest

from chassis_sdk import Chassis, MotionBlockedError
from chassis_sdk.protocol import DriveVelocity
from chassis_sdk.sim import ChassisSimulator

from .support.helpers import drives, until

pytestmark = pytest.mark.integration

#: How long the wire is watched for a restart that must not come (s): past the
#: deadman (0.5 s) and past the resend a command in force would make.
QUIET = 0.7


def moving_since(sim: ChassisSimulator, since: float) -> list[int]:
    """The non-zero velocity commands the chassis read after ``since`` (monotonic)."""
    return [
        c.linear_mm
        for t, c in sim.firmware.received
        if t >= since and isinstance(c, DriveVelocity) and (c.linear_mm or c.angular)
    ]


def still(sim: ChassisSimulator) -> bool:
    return all(abs(w) < 1e-3 for w in sim.firmware.wheels)


async def test_a_velocity_during_a_software_estop_raises_and_its_release_moves_nothing() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.emergency_stop(confirm=True)
        engaged = time.monotonic()
        with pytest.raises(MotionBlockedError, match="SOFTWARE_ESTOP") as caught:
            await robot.set_velocity(0.3, 0.0, duration=3.0)
        assert caught.value.reasons == ("SOFTWARE_ESTOP",)
        assert robot.commanded_velocity is None
        await robot.release_emergency_stop(confirm=True)
        await asyncio.sleep(QUIET)
        assert moving_since(sim, engaged) == []
        assert still(sim)


async def test_a_velocity_while_the_hardware_button_is_pressed_raises_and_release_moves_nothing() -> (
    None
):
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        sim.firmware.set_hardware_estop(True)
        await until(lambda: robot.motion.blocks == ("HARDWARE_ESTOP",))
        pressed = time.monotonic()
        with pytest.raises(MotionBlockedError) as caught:
            await robot.set_velocity(0.3, 0.0)
        assert caught.value.reasons == ("HARDWARE_ESTOP",)
        sim.firmware.set_hardware_estop(False)
        await until(lambda: robot.motion.blocks == ())
        await asyncio.sleep(QUIET)
        assert moving_since(sim, pressed) == []
        assert still(sim)


@pytest.mark.parametrize("hazard", ["hardware e-stop", "remote e-stop", "front bumper"])
async def test_a_command_in_force_when_a_hazard_comes_is_ended_and_not_resumed(hazard: str) -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.set_velocity(0.3, 0.0, duration=5.0)
        await until(lambda: all(w > 0.2 for w in sim.firmware.wheels))
        firmware = sim.firmware
        if hazard == "hardware e-stop":
            firmware.set_hardware_estop(True)
        elif hazard == "remote e-stop":
            firmware.set_remote_estop(True)
        else:
            firmware.press_bumper(front=True)
        await until(lambda: robot.motion.blocks != ())
        blocked = time.monotonic()
        assert robot.commanded_velocity is None  # the block ended the command
        if hazard == "hardware e-stop":
            firmware.set_hardware_estop(False)
        elif hazard == "remote e-stop":
            firmware.set_remote_estop(False)
        else:
            await robot.clear_faults(confirm=True)
        await until(lambda: robot.motion.blocks == ())
        await asyncio.sleep(QUIET)
        # What the host wrote before it saw the block may still arrive; nothing after.
        assert moving_since(sim, blocked + 0.05) == []
        assert still(sim)


async def test_after_a_release_a_new_command_drives_at_once() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        await robot.emergency_stop(confirm=True)
        await robot.release_emergency_stop()  # not confirmed: telemetry may lag a frame
        await robot.set_velocity(0.3, 0.0)  # a frame still showing the e-stop refuses nothing
        await until(lambda: all(w > 0.2 for w in sim.firmware.wheels))
        assert robot.commanded_velocity == (0.3, 0.0)


async def test_the_api_is_refused_while_a_source_of_higher_priority_drives() -> None:
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        with robot.motion.source("web page", kind="web") as page:
            assert page.set_velocity(0.2, 0.0) is None
            with pytest.raises(MotionBlockedError, match="driven by web page") as caught:
                await robot.set_velocity(-0.2, 0.0)
            assert caught.value.reasons == ("DRIVEN",)
            assert robot.motion.driver == "web page"
            await until(lambda: any(d.linear_mm == 200 for d in drives(sim)))
        # The page went away while driving: the robot is stopped, and the API drives.
        await until(lambda: drives(sim)[-1].linear_mm == 0)
        await robot.set_velocity(0.1, 0.0)
        assert robot.motion.driver == "api"


@pytest.mark.parametrize("drove", [False, True], ids=["never-drove", "drove"])
async def test_zero_on_close_off_writes_the_zero_only_after_a_velocity(drove: bool) -> None:
    # A read-only dashboard's device: its pages may stop the robot, so it is writable,
    # but it writes nothing a page did not ask for, not even the zero at close.
    async with ChassisSimulator() as sim:
        async with Chassis(sim.port) as robot:
            robot.motion.zero_on_close = False
            if drove:
                await robot.stop()
            before = robot.stats.frames_sent
        assert robot.stats.frames_sent == before + (1 if drove else 0)
        if drove:  # the stop, then the zero at close
            await until(lambda: [d.linear_mm for d in drives(sim)] == [0, 0])
        else:
            assert drives(sim) == []


async def test_a_release_right_after_the_estop_is_not_undone_by_a_frame_in_flight() -> None:
    # The chassis may send a frame showing SOFTWARE_ESTOP after the host has released
    # it (sent between the two commands), even after a frame without it. That frame is
    # not a new e-stop: a command given after the release drives. Released at various
    # moments after the e-stop, before and after telemetry shows it (3 of 60 refused
    # before: the late frame began a block that ended the new command).
    async with ChassisSimulator() as sim, Chassis(sim.port) as robot:
        page = robot.motion.source("page", kind="web")
        refused = []
        for i in range(40):
            await robot.emergency_stop()
            page.stop()  # the page's neutral, as its E-STOP button sends
            await asyncio.sleep(0.001 * (i % 15))
            await robot.release_emergency_stop()
            await asyncio.sleep(0.001 * (i % 7))
            refusal = page.set_velocity(0.2, 0.0)
            await asyncio.sleep(0.06)  # three telemetry frames
            if refusal is not None or robot.motion.driver != "page":
                refused.append((i, refusal))
            page.stop()
        assert refused == []
        await until(lambda: drives(sim)[-1].linear_mm == 0)
