"""The board's part of the ``chassis-sdk`` command line: demo, info, monitor, plot."""

from __future__ import annotations

import collections
import json
import math
from typing import TYPE_CHECKING, Any

import anyio

from ..core.charge import battery_fields, battery_level, battery_text
from ..devices import profile
from ..devices.board.device import Board
from ..devices.board.messages import VelocityCommand
from ..errors import RequestTimeoutError
from .common import (
    DEMO_PATTERN,
    battery_line,
    drive_for,
    explain_silence,
    first,
    first_frame,
    out,
    port_lines,
    simulated,
)
from .devices import DeviceCommands
from .info_command import verdict
from .live import LiveView
from .plotting import empty, layout, path_panel, series, velocity_panels

if TYPE_CHECKING:
    from ..recording.columns import Columns

__all__ = ["COMMANDS", "demo", "format_board", "info", "monitor", "plot"]


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


async def info(port: str, baudrate: int, timeout: float, **options: Any) -> None:
    """LED and buzzer states, one IMU sample, the battery and a diagnosis; exit status 4
    on a fault (`verdict`). ``options`` are the `Board` keyword options (the profile's
    ``battery=BatteryModel(...)``)."""
    async with Board(port, baudrate=baudrate, request_timeout=timeout, **options) as board:
        port_lines(port)
        try:
            led = await board.get_led()
        except RequestTimeoutError as exc:
            explain_silence(board, exc)
        out(f"led          {'on' if led else 'off'}")
        out(f"buzzer       {'on' if await board.get_buzzer() else 'off'}")
        imu = await first(board.imu(), timeout, "IMU samples (0x11)")
        out(f"imu          accel z {imu.accel.z:+.2f} g (about +1 at rest)")
        battery = await first(board.battery(), 2.0, "battery readings (0x13, 1 Hz)")
        out(f"battery      {battery_line(battery.voltage, board)}")
        report = await board.diagnose()
        out(str(report))
    verdict(report)


async def monitor(
    port: str, baudrate: int, seconds: float | None, as_json: bool, **options: Any
) -> None:
    """A live view of the board (IMU with units, velocity, battery, link, events, logs)
    that lives through an unplug. A table on a terminal (rich), one line of at most 100
    columns five times a second when piped, one JSON object per message with ``as_json``.

    ``options`` are the [`Board`][chassis_sdk.Board] keyword options (``battery=BatteryModel(...)``
    adds the state of charge beside the voltage)."""
    options = {"reconnect": True, **options}
    async with Board(port, baudrate=baudrate, **options) as board:
        await first_frame(board, 3.0, profile("board").recognised_by)
        view = _View(board, port, as_json)
        await view.run(
            seconds,
            view.follow_imu,
            view.follow_velocity,
            view.follow_battery,
            view.follow_logs,
            lines=view.print_lines,
        )


def format_board(board: Board) -> str:
    """The board's latest readings on one line, with units (at most 100 columns)."""
    vel, imu, battery = board.latest_velocity, board.latest_imu, board.latest_battery
    parts = []
    if vel is not None:
        parts.append(f"v={vel.linear:+.3f} m/s  w={vel.angular:+.3f} rad/s")
    if imu is not None:
        a, g = imu.accel, imu.gyro
        parts.append(f"accel=({a.x:+.2f} {a.y:+.2f} {a.z:+.2f}) g  gyro z={g.z:+6.1f} deg/s")
    if battery is not None:
        parts.append(battery_text(battery.voltage, board))
    return "  ".join(parts) or "no readings yet"


class _View(LiveView):
    """What ``monitor`` shows of a board."""

    def __init__(self, board: Board, port: str, as_json: bool) -> None:
        super().__init__(board, port, as_json)
        self.board = board
        self.logs: collections.deque[str] = collections.deque(maxlen=3)

    async def follow_imu(self) -> None:
        async for sample in self.board.imu():
            if self.as_json:
                self.emit("ImuSample", sample)

    async def follow_velocity(self) -> None:
        async for velocity in self.board.velocity():
            if self.as_json:
                self.emit("VelocityFeedback", velocity)

    async def follow_battery(self) -> None:
        async for reading in self.board.battery():
            if self.as_json:
                self.emit("BatteryReading", reading, **battery_fields(self.board))

    async def follow_logs(self) -> None:
        async for text in self.board.logs():
            if self.as_json:
                out(json.dumps({"type": "log", "text": text}))
            else:
                self.logs.append(text)
                if self.live is None:
                    out(f"log: {text}")

    async def print_lines(self) -> None:
        """Piped: the latest readings five times a second."""
        while True:
            await anyio.sleep(0.2)
            if self.board.latest_imu is not None or self.board.latest_velocity is not None:
                out(format_board(self.board))

    def render(self) -> Any:
        from rich.table import Table

        board = self.board
        table = Table(title=f"board on {self.port}", caption="Ctrl-C to quit", show_header=False)
        state = board.connection_state.value
        table.add_row("link", f"[{'green' if state == 'connected' else 'red'}]{state}[/]")
        vel, imu, battery = board.latest_velocity, board.latest_imu, board.latest_battery
        if vel is not None:
            table.add_row("velocity", f"{vel.linear:+.3f} m/s   {vel.angular:+.3f} rad/s")
        if imu is not None:
            a, g, m = imu.accel, imu.gyro, imu.mag
            table.add_row("accel", f"{a.x:+.3f}  {a.y:+.3f}  {a.z:+.3f} g")
            table.add_row("gyro", f"{g.x:+.1f}  {g.y:+.1f}  {g.z:+.1f} deg/s")
            table.add_row("mag", f"{m.x:+.0f}  {m.y:+.0f}  {m.z:+.0f} (raw counts)")
        if battery is not None:
            level = battery_level(board)
            colour = {"LOW": "yellow", "CRITICAL": "bold red"}.get(level.name if level else "")
            volts = battery_text(battery.voltage, board)
            table.add_row("battery", f"[{colour}]{volts}[/]" if colour else volts)
        table.add_row("logs", "\n".join(self.logs) or "-")
        table.add_row("events", "\n".join(self.recent) or "-")
        table.add_row("counters", self.counters())
        return table


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
COMMANDS = DeviceCommands(monitor=monitor, demo=demo, info=info, plot=plot)
