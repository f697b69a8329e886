"""The board's part of the ``chassis-sdk`` command line: demo, info, plot."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from ..devices.board.device import Board
from ..devices.board.messages import VelocityCommand
from ..errors import RequestTimeoutError
from .common import DEMO_PATTERN, drive_for, explain_silence, first, out, simulated
from .devices import DeviceCommands
from .plotting import empty, layout, path_panel, series, velocity_panels

if TYPE_CHECKING:
    from ..recording.columns import Columns

__all__ = ["COMMANDS", "demo", "info", "plot"]


async def demo() -> None:
    """Drive the board simulator through the real serial stack, narrating."""
    async with simulated("board", Board) as board:
        out(f"led          {await board.set_led(True)} (reported by the board)")
        out(f"buzzer       {await board.set_buzzer(True)} then {await board.set_buzzer(False)}")
        await board.set_servo(1, 45.0)
        battery = await anext(board.battery())
        out(f"battery      {battery.voltage:.2f} V")

        def show() -> None:
            imu, vel = board.latest_imu, board.latest_velocity
            if imu is not None and vel is not None:
                out(
                    f"  v={vel.linear:+.3f} m/s  w={vel.angular:+.3f} rad/s  "
                    f"accel=({imu.accel.x:+.2f}, {imu.accel.y:+.2f}, {imu.accel.z:+.2f}) g  "
                    f"gyro z={imu.gyro.z:+6.1f} deg/s"
                )

        for name, v, w, seconds in DEMO_PATTERN[:2]:
            out(f"drive: {name} (v={v} m/s, w={w} rad/s) for {seconds} s")
            await drive_for(board, v, w, seconds, show)
        await board.stop()
        await board.set_led(False)
    out("done: the board stopped and the port is closed.")


async def info(port: str, baudrate: int, timeout: float) -> None:
    """LED and buzzer states, one IMU sample, the battery and a diagnosis."""
    async with Board(port, baudrate=baudrate, request_timeout=timeout) as board:
        out(f"port         {port}")
        try:
            led = await board.get_led()
        except RequestTimeoutError as exc:
            explain_silence(board, exc)
        out(f"led          {'on' if led else 'off'}")
        out(f"buzzer       {'on' if await board.get_buzzer() else 'off'}")
        imu = await first(board.imu(), timeout, "IMU samples (0x11)")
        out(f"imu          accel z {imu.accel.z:+.2f} g (about +1 at rest)")
        battery = await first(board.battery(), 2.0, "battery readings (0x13, 1 Hz)")
        out(f"battery      {battery.voltage:.2f} V")
        out(str(await board.diagnose()))


def plot(data: Columns, commands: Columns, fig: Any) -> None:
    """Linear and angular velocity feedback (each with what was commanded, if the
    capture holds it; the gyro's z rate beside the angular one), the battery, and the
    path from odometry."""
    (linear, angular, volts), path = layout(fig, 3)
    t, v, w = velocity_panels(
        linear, angular, data, "VelocityFeedback", commands, VelocityCommand,
        lambda c: (c.linear_milli / 1000, c.angular_milli / 1000),
    )  # fmt: skip
    gt, gz = series(data, "ImuSample", "gyro.z")
    angular.plot(gt, [math.radians(x) for x in gz], linewidth=0.6, alpha=0.6, label="gyro z")
    angular.legend(loc="upper right", fontsize=8)
    bt, bv = series(data, "BatteryReading", "voltage")
    volts.set_ylabel("battery (V)")
    if len(bt):
        volts.plot(bt, bv, "o-", color="tab:green")
    else:
        empty(volts, "no battery reading (0x13 comes once a second)")
    path_panel(path, t, v, w)


#: The board's part of ``chassis-sdk`` (found by :func:`chassis_sdk.cli.devices.commands`).
COMMANDS = DeviceCommands(demo=demo, info=info, plot=plot)
