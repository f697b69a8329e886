"""The chassis's part of the ``chassis-sdk`` command line: demo, info, monitor, plot."""

from __future__ import annotations

import collections
import json
import math
import sys
import time
from typing import TYPE_CHECKING, Any

import anyio

from ..devices.chassis.device import Chassis
from ..devices.chassis.messages import DriveVelocity, Telemetry
from ..errors import ChassisError, RequestTimeoutError
from .common import (
    DEMO_PATTERN,
    drive_for,
    explain_silence,
    first,
    first_frame,
    jsonable,
    out,
    simulated,
)
from .devices import DeviceCommands
from .plotting import layout, path_panel, series, velocity_panels

if TYPE_CHECKING:
    from ..recording.columns import Columns

__all__ = ["COMMANDS", "demo", "format_telemetry", "info", "monitor", "plot"]


def _status_names(t: Telemetry) -> str:
    """The set status bits by name (single bits only, not the group aliases)."""
    return "|".join(
        str(m.name) for m in type(t.status) if m.value.bit_count() == 1 and m in t.status
    )


def format_telemetry(t: Telemetry) -> str:
    """One line of telemetry for a terminal."""
    status = _status_names(t) or "ok"
    w = t.wheels
    return (
        f"  v={t.linear:+.3f} m/s  w={t.angular:+.3f} rad/s  "
        f"wheels=[{w.front_left:+.2f} {w.front_right:+.2f} {w.rear_left:+.2f} "
        f"{w.rear_right:+.2f}]  {t.voltage:.1f} V  docking={t.docking.name}  status={status}"
    )


async def _print_info(robot: Chassis) -> None:
    firmware = await robot.get_firmware_version()
    hardware = await robot.get_hardware_version()
    info = await robot.get_chassis_info()
    shipped = await robot.get_ship_date()
    out(f"firmware     {firmware}")
    out(f"hardware     {hardware}")
    out(
        f"geometry     track {info.track_width:.3f} m, wheelbase {info.wheelbase:.3f} m, "
        f"wheel {info.wheel_diameter:.3f} m, gear {info.gear_ratio}:1, "
        f"encoder {info.encoder_resolution} lines"
    )
    out(f"ship date    {shipped.isoformat()}")


async def demo() -> None:
    """Drive the chassis simulator through the real serial stack, narrating."""
    async with simulated("chassis", Chassis) as robot:
        await _print_info(robot)
        await anext(robot.telemetry())

        def show() -> None:
            t = robot.latest_telemetry
            if t is not None:
                out(format_telemetry(t))

        for name, v, w, seconds in DEMO_PATTERN:
            out(f"drive: {name} (v={v} m/s, w={w} rad/s) for {seconds} s")
            await drive_for(robot, v, w, seconds, show)
        out("stop")
        await robot.stop()
        async for t in robot.telemetry():
            if t.linear == 0 and t.angular == 0:
                out(format_telemetry(t))
                break
        out("software e-stop on, then off")
        await robot.emergency_stop()
        async for t in robot.telemetry():
            if t.emergency_stopped:
                out(format_telemetry(t))
                break
        await robot.release_emergency_stop()
        stats = robot.stats
        out(
            f"link         {stats.frames} frames in, {stats.frames_sent} out, "
            f"{stats.resends} watchdog resends, {stats.bytes_dropped} bytes dropped"
        )
    out("done: the robot stopped and the port is closed.")


async def info(port: str, baudrate: int, timeout: float) -> None:
    """Versions, geometry, one telemetry frame and a diagnosis."""
    async with Chassis(port, baudrate=baudrate, request_timeout=timeout) as robot:
        out(f"port         {port}")
        try:
            await _print_info(robot)
        except RequestTimeoutError as exc:
            explain_silence(robot, exc)
        await first(robot.telemetry(), timeout, "telemetry (0x81)")
        out(str(await robot.diagnose()))


async def monitor(port: str, baudrate: int, seconds: float | None, as_json: bool) -> None:
    """A live view of the telemetry, the link, faults and events that lives through an
    unplug (it reconnects and says so). Plain lines when piped (rich on a terminal);
    ``as_json``: one JSON object per telemetry frame, state change and event."""
    async with Chassis(port, baudrate=baudrate, reconnect=True) as robot:
        # A silent port, or another device's, is a one-line error, not an empty screen.
        await first_frame(robot, 3.0, "0x81 chassis telemetry")
        view = _View(robot, port, as_json)
        async with anyio.create_task_group() as tg:
            tg.start_soon(view.follow_telemetry)
            tg.start_soon(view.follow_states)
            tg.start_soon(view.follow_events)
            tg.start_soon(view.check_health)
            if view.live is not None:
                tg.start_soon(view.render_loop)
            elif not as_json:
                print("Ctrl-C to quit", file=sys.stderr)
            with anyio.move_on_after(math.inf if seconds is None else seconds):
                await anyio.sleep_forever()
            tg.cancel_scope.cancel()
        view.close()


class _View:
    """What ``monitor`` shows, in whichever of its three forms."""

    def __init__(self, robot: Chassis, port: str, as_json: bool) -> None:
        self.robot = robot
        self.port = port
        self.as_json = as_json
        self.recent: collections.deque[str] = collections.deque(maxlen=4)
        self.faults: tuple[str, ...] | None = None
        self.live: Any = None
        self._last_line = 0.0
        if not as_json and sys.stdout.isatty():
            try:
                from rich.live import Live

                self.live = Live(auto_refresh=False)
                self.live.start()
            except ImportError:
                pass

    def close(self) -> None:
        if self.live is not None:
            self.live.stop()

    async def follow_telemetry(self) -> None:
        async for t in self.robot.telemetry():
            if self.as_json:
                out(json.dumps({"type": "Telemetry", **jsonable(t)}))
            elif self.live is None and t.timestamp - self._last_line >= 0.2:
                out(format_telemetry(t))
                self._last_line = t.timestamp

    async def follow_states(self) -> None:
        async for state in self.robot.connection_states():
            if self.as_json:
                out(json.dumps({"type": "link", "state": state.value}))
            else:
                self.recent.append(f"{time.strftime('%H:%M:%S')} link {state.value}")
                if self.live is None:
                    out(f"link: {state.value}")

    async def follow_events(self) -> None:
        async for event in self.robot.events():
            if event.kind.value.startswith("link_"):
                continue  # follow_states tells these
            if self.as_json:
                out(json.dumps({"type": "event", **jsonable(event)}))
            else:
                self.recent.append(f"{time.strftime('%H:%M:%S')} {event}")
                if self.live is None:
                    out(f"event: {event}")

    async def check_health(self) -> None:  # diagnose() reads 0xB0: once a second is plenty
        while True:
            if self.robot.is_connected:
                try:
                    report = await self.robot.diagnose()
                except ChassisError:  # the link went away meanwhile: the states say so
                    report = None
                if report is not None and report.faults != self.faults:
                    self.faults = report.faults
                    if self.as_json:
                        out(json.dumps({"type": "faults", "faults": list(report.faults)}))
                    elif self.live is None:
                        out("faults: " + (", ".join(report.faults) or "none"))
            await anyio.sleep(1.0)

    async def render_loop(self) -> None:
        while True:
            self.live.update(self.render(), refresh=True)
            await anyio.sleep(0.1)

    def render(self) -> Any:
        from rich.table import Table

        robot = self.robot
        table = Table(title=f"chassis on {self.port}", caption="Ctrl-C to quit", show_header=False)
        age = robot.telemetry_age
        state = robot.connection_state.value
        fresh = "no telemetry yet" if age is None else f"last telemetry {age:.1f} s ago"
        style = "green" if state == "connected" and age is not None and age < 0.5 else "red"
        table.add_row("link", f"[{style}]{state}[/], {fresh}")
        t = robot.latest_telemetry
        if t is not None:
            table.add_row("voltage", f"{t.voltage:.1f} V")
            table.add_row("velocity", f"{t.linear:+.3f} m/s   {t.angular:+.3f} rad/s")
            w = t.wheels
            table.add_row(
                "wheels",
                f"FL {w.front_left:+.2f}  FR {w.front_right:+.2f}  "
                f"RL {w.rear_left:+.2f}  RR {w.rear_right:+.2f} m/s",
            )
            table.add_row("status", _status_names(t).replace("|", ", ") or "ok")
            table.add_row("docking", t.docking.name)
        if self.faults is not None:
            table.add_row("faults", "\n".join(self.faults) or "none")
        table.add_row("events", "\n".join(self.recent) or "-")
        s = robot.stats
        table.add_row(
            "counters",
            f"{s.frames} frames, {s.bytes_dropped} bytes dropped, "
            f"{s.checksum_errors} checksum errors, {s.sequence_gaps} gaps, "
            f"{s.reconnects} reconnects",
        )
        return table


def plot(data: Columns, commands: Columns, fig: Any) -> None:
    """Linear and angular velocity (each with what was commanded, if the capture holds
    it), the four wheels (left blue, right orange; front solid, rear dashed), the
    battery, and the path from odometry."""
    (linear, angular, wheels, volts), path = layout(fig, 4)
    t, v, w = velocity_panels(
        linear, angular, data, "Telemetry", commands, DriveVelocity,
        lambda c: (c.linear_mm / 1000, c.angular),
    )  # fmt: skip
    for name, color, style in (
        ("front_left", "tab:blue", "-"),
        ("rear_left", "tab:blue", "--"),
        ("front_right", "tab:orange", "-"),
        ("rear_right", "tab:orange", "--"),
    ):
        wheels.plot(*series(data, "Telemetry", f"wheels.{name}"), style, color=color, label=name)
    wheels.set_ylabel("wheels (m/s)")
    wheels.legend(loc="upper right", fontsize=8, ncol=2)
    volts.plot(*series(data, "Telemetry", "voltage"), color="tab:green")
    volts.set_ylabel("battery (V)")
    path_panel(path, t, v, w)


#: The chassis's part of ``chassis-sdk`` (found by :func:`chassis_sdk.cli.devices.commands`).
COMMANDS = DeviceCommands(demo=demo, info=info, monitor=monitor, plot=plot)
