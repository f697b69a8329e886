"""Print the chassis's versions and geometry, then a second of live telemetry.

    python examples/chassis_info_and_telemetry.py [PORT]

PORT is a device path (/dev/ttyUSB0), a pty path or socket://host:port; without it the
example starts the built-in simulator.
"""

from __future__ import annotations

import contextlib
import sys

import chassis_sdk
from chassis_sdk import Chassis
from chassis_sdk.sim import ChassisSimulator


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            port = (await stack.enter_async_context(ChassisSimulator())).port
        robot = await stack.enter_async_context(Chassis(port))
        await robot.verify()  # the device on the port is a chassis

        print("firmware:", await robot.get_firmware_version())
        print("hardware:", await robot.get_hardware_version())
        print("geometry:", await robot.get_chassis_info())
        print("shipped: ", await robot.get_ship_date())

        n = 0
        async for t in robot.telemetry():  # 50 Hz
            print(f"{t.seq:5d}  {t.voltage:4.1f} V  v={t.linear:+.3f} m/s  "
                  f"w={t.angular:+.3f} rad/s  {t.status}")  # fmt: skip
            n += 1
            if n == 50:
                break  # breaking out unsubscribes
        print("link:", robot.stats)


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
