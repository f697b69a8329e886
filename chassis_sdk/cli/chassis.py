"""The chassis's part of the ``chassis-sdk`` command line: demo, info, monitor, plot."""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

import anyio

from ..core.charge import HasBattery, battery_fields, battery_level, battery_text
from ..devices.chassis.device import Chassis
from ..devices.chassis.health import explain_drivers, explain_status
from ..devices.chassis.messages import DriveVelocity, Telemetry
from ..errors import ChassisError, RequestTimeoutError
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
from .plotting import layout, path_panel, series, velocity_panels

if TYPE_CHECKING:
    from ..recording.columns import Columns

__all__ = ["COMMANDS", "demo", "format_telemetry", "info", "monitor", "plot"]


def _status_names(t: Telemetry) -> str:
    """The set status bits by name (single bits only, not the group aliases)."""
    return "|".join(
        str(m.name) for m in type(t.status) if m.value.bit_count() == 1 and m in t.status
    )


def format_telemetry(t: Telemetry, battery: HasBattery | None = None) -> str:
    """One line of telemetry for a terminal; with ``battery`` (the device), the state of
    charge beside the voltage (``24.6 V  63 %``, ``--`` while not known)."""
    status = _status_names(t) or "ok"
    w = t.wheels
    volts = f"{t.voltage:.1f} V" if battery is None else battery_text(t.voltage, battery)
    return (
        f"  v={t.linear:+.3f} m/s  w={t.angular:+.3f} rad/s  "
        f"wheels=[{w.front_left:+.2f} {w.front_right:+.2f} {w.rear_left:+.2f} "
        f"{w.rear_right:+.2f}]  {volts}  docking={t.docking.name}  status={status}"
    )


def firmware_text(version: int) -> str:
    """The 0x87 firmware number as the vendor writes versions, with the number itself:
    ``103`` is ``"v1.0.3 (103)"`` (hundreds, tens, units: major, minor, patch)."""
    return f"v{version // 100}.{version // 10 % 10}.{version % 10} ({version})"


def status_sentences(status: int) -> list[str]:
    """One sentence per set status bit, for the first place a status is shown
    (``status REMOTE_OFFLINE: the remote control is off ...: normal under host control``)."""
    return [f"status {flag.name}: {flag.meaning}" for flag in explain_status(status)]


async def _print_info(robot: Chassis) -> list[str]:
    """Print each of the chassis's answers; a request it does not answer is marked and
    the others still asked. Returns what went unanswered.

    Raises:
        RequestTimeoutError: Nothing answered at all (so nothing was printed).
    """
    missing: list[str] = []
    lines: list[str] = []
    silence: list[RequestTimeoutError] = []

    async def ask(label: str, request: Any, show: Any) -> None:
        try:
            value = await request()
        except RequestTimeoutError as exc:
            if not robot.stats.frames:  # not a frame yet: a silent port, or another device
                raise
            missing.append(label)
            silence.append(exc)
            lines.append(f"{label:<13}(no reply: {exc})")
        else:
            lines.append(f"{label:<13}{show(value)}")

    await ask("firmware", robot.get_firmware_version, firmware_text)
    await ask("hardware", robot.get_hardware_version, str)
    await ask(
        "geometry",
        robot.get_chassis_info,
        lambda info: (
            f"track {info.track_width:.3f} m, wheelbase {info.wheelbase:.3f} m, "
            f"wheel {info.wheel_diameter:.3f} m, gear {info.gear_ratio}:1, "
            f"encoder {info.encoder_resolution} lines"
        ),
    )
    await ask("ship date", robot.get_ship_date, lambda date: date.isoformat())
    if len(silence) == len(lines):  # nothing answered: a silent port, or another device
        raise silence[0]
    for line in lines:
        out(line)
    return missing


async def demo() -> None:
    """Drive the chassis simulator through the real serial stack, narrating."""
    async with simulated("chassis", Chassis) as robot:
        await _print_info(robot)
        first_frame = await anext(robot.telemetry())
        out(format_telemetry(first_frame))
        for sentence in status_sentences(first_frame.status):
            out(f"  ({sentence})")

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


async def info(port: str, baudrate: int, timeout: float, **options: Any) -> None:
    """Versions, geometry, one telemetry frame, the battery, what each set status flag
    means and a diagnosis; exit status 4 on a fault (`verdict`). ``options`` are the
    `Chassis` keyword options (the profile's ``battery=BatteryModel(...)``)."""
    async with Chassis(port, baudrate=baudrate, request_timeout=timeout, **options) as robot:
        port_lines(port)
        try:
            missing = await _print_info(robot)
        except RequestTimeoutError as exc:
            explain_silence(robot, exc)
        t = await first(robot.telemetry(), timeout, "telemetry (0x81)")
        out(f"battery      {battery_line(t.voltage, robot)}")
        report = await robot.diagnose()
        flags = explain_status(report.status or 0)
        flags += () if report.drivers is None else explain_drivers(report.drivers)
        for i, flag in enumerate(flags):
            out(f"{'flags' if i == 0 else '':<13}{flag}")
        if not flags:
            out("flags        none")
        out(str(report))
    verdict(report, missing)


async def monitor(
    port: str, baudrate: int, seconds: float | None, as_json: bool, **options: Any
) -> None:
    """A live view of the telemetry, the link, faults and events that lives through an
    unplug (it reconnects and says so). Plain lines when piped (rich on a terminal);
    ``as_json``: one JSON object per telemetry frame, state change and event.

    ``options`` are the `Chassis` keyword options (``battery=BatteryModel(...)``
    adds the state of charge beside the voltage: ``battery_percentage`` and
    ``battery_level`` in each JSON frame, ``null`` while not known)."""
    options = {"reconnect": True, **options}
    async with Chassis(port, baudrate=baudrate, **options) as robot:
        # A silent port, or another device's, is a one-line error, not an empty screen.
        await first_frame(robot, 3.0, "0x81 chassis telemetry")
        view = _View(robot, port, as_json)
        await view.run(seconds, view.follow_telemetry, view.check_health)


class _View(LiveView):
    """What ``monitor`` shows, in whichever of its three forms."""

    def __init__(self, robot: Chassis, port: str, as_json: bool) -> None:
        super().__init__(robot, port, as_json)
        self.robot = robot
        self.faults: tuple[str, ...] | None = None
        self._last_line = 0.0
        self._explained: set[str] = set()

    async def follow_telemetry(self) -> None:
        async for t in self.robot.telemetry():
            if self.as_json:
                self.emit("Telemetry", t, **battery_fields(self.robot))
            elif self.live is None and t.timestamp - self._last_line >= 0.2:
                out(format_telemetry(t, self.robot))
                self._last_line = t.timestamp
                for flag in explain_status(t.status):  # said once, where it first shows
                    if flag.name not in self._explained:
                        self._explained.add(flag.name)
                        out(f"  (status {flag.name}: {flag.meaning})")

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
            level = battery_level(robot)
            colour = {"LOW": "yellow", "CRITICAL": "bold red"}.get(level.name if level else "")
            volts = battery_text(t.voltage, robot)
            table.add_row("battery", f"[{colour}]{volts}[/]" if colour else volts)
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
        table.add_row("counters", self.counters())
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
