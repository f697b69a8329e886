"""Drive a square (four 1 m sides, four 90° turns) with a simple control loop.

    python examples/drive_square.py [PORT]

The loop calls set_velocity() at 10 Hz, as a ROS cmd_vel node would: if this program
hangs or dies, the SDK's deadman zeroes the command after command_timeout (0.5 s) and
the firmware's own timeout stops the wheels. Leaving the `async with` always writes zero.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import sys
import time

import chassis_sdk
from chassis_sdk import Chassis
from chassis_sdk.sim import ChassisSimulator

SIDE = 1.0  # m
SPEED = 0.4  # m/s
TURN_RATE = 0.8  # rad/s


async def hold(robot: Chassis, linear: float, angular: float, seconds: float) -> None:
    """Keep a velocity command alive for `seconds` (10 Hz control loop)."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        await robot.set_velocity(linear, angular)
        await asyncio.sleep(0.1)


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            port = (await stack.enter_async_context(ChassisSimulator())).port
        robot = await stack.enter_async_context(Chassis(port))
        await robot.verify()  # the device on the port is a chassis
        for side in range(4):
            print(f"side {side + 1}: forward {SIDE} m")
            await hold(robot, SPEED, 0.0, SIDE / SPEED)
            print(f"side {side + 1}: turn 90 degrees")
            await hold(robot, 0.0, TURN_RATE, (math.pi / 2) / TURN_RATE)
        await robot.stop()
        # Report the robot at rest: wait for telemetry that shows the stop.
        t = await robot.wait_for(lambda t: t.linear == 0 and t.angular == 0, timeout=2.0)
        print(f"done: stopped (v={t.linear:+.2f} m/s, w={t.angular:+.2f} rad/s, {t.status})")


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
