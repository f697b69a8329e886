"""Print IMU samples and the battery voltage from the controller board.

python examples/board_imu_and_battery.py [PORT]
"""

from __future__ import annotations

import contextlib
import sys

import chassis_sdk
from chassis_sdk import Board
from chassis_sdk.sim import BoardSimulator


async def main(port: str | None) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            port = (await stack.enter_async_context(BoardSimulator())).port
        board = await stack.enter_async_context(Board(port))
        await board.verify()  # the device on the port is a board

        battery = await anext(board.battery())  # 1 Hz
        print(f"battery: {battery.voltage:.2f} V")
        n = 0
        async for s in board.imu():  # 100 Hz
            if n % 10 == 0:
                print(f"accel {s.accel.x:+.3f} {s.accel.y:+.3f} {s.accel.z:+.3f} g   "
                      f"gyro {s.gyro.x:+6.1f} {s.gyro.y:+6.1f} {s.gyro.z:+6.1f} deg/s   "
                      f"mag {s.mag.x:+5.0f} {s.mag.y:+5.0f} {s.mag.z:+5.0f}")  # fmt: skip
            n += 1
            if n == 100:
                break


if __name__ == "__main__":
    chassis_sdk.run(main(sys.argv[1] if len(sys.argv) > 1 else None), one_line_errors=True)
