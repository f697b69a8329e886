"""The board's part of the ``chassis-sdk`` command line: demo, info, plot."""

from __future__ import annotations

from typing import Any

from ...cli.common import DEMO_PATTERN, drive_for, explain_silence, first, out, simulated
from ...errors import RequestTimeoutError
from .device import Board
from .messages import BatteryReading, ImuSample, VelocityFeedback

__all__ = ["demo", "info", "plot"]


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


def plot(rows: list[tuple[float, object]], axes: Any) -> None:
    """Velocity feedback, gyro rate and battery of a decoded capture on three axes."""
    vel = [(t, m) for t, m in rows if isinstance(m, VelocityFeedback)]
    imu = [(t, m) for t, m in rows if isinstance(m, ImuSample)]
    bat = [(t, m) for t, m in rows if isinstance(m, BatteryReading)]
    axes[0].plot([t for t, _ in vel], [m.linear for _, m in vel], label="linear (m/s)")
    axes[0].plot([t for t, _ in vel], [m.angular for _, m in vel], label="angular (rad/s)")
    axes[0].set_ylabel("velocity")
    axes[1].plot([t for t, _ in imu], [m.gyro.z for _, m in imu], label="gyro z (deg/s)")
    axes[2].plot([t for t, _ in bat], [m.voltage for _, m in bat], label="battery (V)")
    axes[2].set_ylabel("volts")
