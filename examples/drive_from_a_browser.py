"""Serve the web dashboard of a chassis from your own program, beside your own logic.

    pip install -e ".[web]"
    python examples/drive_from_a_browser.py [PORT] [SECONDS]

Open the address it prints in a browser to watch the robot and drive it (joystick,
keyboard, gamepad), every command under the deadman. Meanwhile this program says once a
second how many pages are open and what the robot was last told. Without PORT it runs
against the built-in simulator for SECONDS (default 3; with a PORT, until Ctrl-C).
Leaving the block stops the robot if a page was driving it.
"""

from __future__ import annotations

import contextlib
import sys

import anyio

import chassis_sdk
from chassis_sdk import Chassis, MotionLimits
from chassis_sdk.integrations.web import WebDashboard
from chassis_sdk.sim import ChassisSimulator


async def main(port: str | None, seconds: float | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            port = (await stack.enter_async_context(ChassisSimulator())).port
        # The limits are the joystick's full deflection; more is refused.
        limits = MotionLimits(max_linear=0.5, max_angular=1.0)
        robot = await stack.enter_async_context(Chassis(port, limits=limits))
        await robot.verify()  # the device on the port is a chassis
        web = await stack.enter_async_context(WebDashboard(robot, port=0))
        print(f"open {web.login_url}")
        with anyio.move_on_after(seconds):  # None: until Ctrl-C or SIGTERM
            while True:
                commanded = robot.commanded_velocity or (0.0, 0.0)
                print(
                    f"{web.clients} page(s) open, {web.commands} commands, "
                    f"{web.refused} refused; last told v={commanded[0]:+.2f} m/s, "
                    f"w={commanded[1]:+.2f} rad/s"
                )
                await anyio.sleep(1.0)
    print("done: the robot is stopped")


if __name__ == "__main__":
    port = sys.argv[1] if len(sys.argv) > 1 else None
    seconds = float(sys.argv[2]) if len(sys.argv) > 2 else (3.0 if port is None else None)
    chassis_sdk.run(main(port, seconds), one_line_errors=True)
