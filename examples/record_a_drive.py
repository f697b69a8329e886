"""Record a short drive to an MCAP file you can open in Foxglove (File > Open local file).

    pip install -e ".[foxglove]"
    python examples/record_a_drive.py [PORT] [FILE.mcap]

`record=` records the whole session, both ways: the raw bytes with their receive times,
every stream decoded (telemetry, odometry, events, ...), every command this program and
the watchdog wrote (decoded), the pose and /tf for Foxglove's 3D panel, and metadata.
Attach the file to a bug report: it is everything that happened on the wire.
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
import tempfile
import time
from pathlib import Path

import chassis_sdk
from chassis_sdk import Chassis
from chassis_sdk.recording import capture
from chassis_sdk.sim import ChassisSimulator


async def main(port: str | None, path: Path) -> None:
    async with contextlib.AsyncExitStack() as stack:
        if port is None:
            port = (await stack.enter_async_context(ChassisSimulator())).port
        robot = await stack.enter_async_context(Chassis(port, record=path))
        await robot.verify()  # the device on the port is a chassis
        print(f"recording to {robot.recording}")
        end = time.monotonic() + 2.0
        while time.monotonic() < end:  # a gentle arc for two seconds, at 10 Hz
            await robot.set_velocity(0.3, 0.4)
            await asyncio.sleep(0.1)
        await robot.stop()
        async for odometry in robot.odometry():
            print(f"stopped at x={odometry.x:+.2f} m, y={odometry.y:+.2f} m")
            break
    # The file is complete once the device is closed; read it back.
    frames = sum(1 for _ in capture.decode_capture(path, "chassis"))
    sent = sum(1 for _ in capture.decode_capture(path, "chassis", commands=True))
    print(f"done: {path} holds {frames} frames from the robot and {sent} commands to it")


if __name__ == "__main__":
    port = sys.argv[1] if len(sys.argv) > 1 else None
    # A directory of this run's own: two runs never write one file, nor a file of another user.
    default = Path(tempfile.mkdtemp(prefix="chassis-drive-")) / "drive.mcap"
    path = Path(sys.argv[2]) if len(sys.argv) > 2 else default
    chassis_sdk.run(main(port, path), one_line_errors=True)
