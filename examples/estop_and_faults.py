"""Engage the software e-stop, watch the status bits, release it, clear faults.

python examples/estop_and_faults.py [PORT]

Without PORT it starts the built-in simulator and presses the simulator's front bumper
first (and says so), so that there is a latched fault for ``clear_faults()`` to clear.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys

import chassis_sdk
from chassis_sdk import Chassis, ChassisStatus, Telemetry
from chassis_sdk.sim import ChassisSimulator


async def wait_for_status(robot: Chassis, test: str, check: object) -> Telemetry:
    async with asyncio.timeout(2.0):
        async for t in robot.telemetry():
            if check(t):  # type: ignore[operator]
                print(f"{test}: status = {t.status}")
                return t
    raise AssertionError("unreachable")


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            sim = await stack.enter_async_context(ChassisSimulator())
            port = sim.port
            # Something for clear_faults() to clear, said so: a real robot's is pressed by hand.
            sim.firmware.press_bumper(front=True)
            print("simulator: pressing its front bumper (a fault for clear_faults() to clear)")
        robot = await stack.enter_async_context(Chassis(port))
        await robot.verify()  # the device on the port is a chassis

        await robot.emergency_stop()
        await wait_for_status(robot, "e-stop engaged", lambda t: t.emergency_stopped)
        await robot.release_emergency_stop()
        await wait_for_status(robot, "e-stop released", lambda t: not t.emergency_stopped)

        t = robot.latest_telemetry
        if t is not None and t.status & (ChassisStatus.BUMPER | ChassisStatus.DRIVER_FAULT):
            print("faults latched:", t.status & (ChassisStatus.BUMPER | ChassisStatus.DRIVER_FAULT))
        await robot.clear_faults()
        await wait_for_status(
            robot,
            "faults cleared",
            lambda t: not t.status & (ChassisStatus.BUMPER | ChassisStatus.DRIVER_FAULT),
        )
        status = await robot.get_driver_status()
        for name, driver in zip(("FL", "FR", "RL", "RR"), status.wheels, strict=True):
            print(f"driver {name}: errors={driver.errors}  motor={driver.motor}")


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
