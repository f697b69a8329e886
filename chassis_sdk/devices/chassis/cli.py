"""The chassis's part of the ``chassis-sdk`` command line: demo, info, monitor, plot."""

from __future__ import annotations

import collections
import time
from typing import Any

import anyio

from ...cli.common import DEMO_PATTERN, drive_for, explain_silence, first, out, simulated
from ...core.diagnosis import Diagnosis
from ...errors import RequestTimeoutError
from .device import Chassis
from .messages import Telemetry

__all__ = ["demo", "format_telemetry", "info", "monitor", "plot"]


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


async def info(port: str, timeout: float) -> None:
    """Versions, geometry, one telemetry frame and a diagnosis."""
    async with Chassis(port, request_timeout=timeout) as robot:
        out(f"port         {port}")
        try:
            await _print_info(robot)
        except RequestTimeoutError as exc:
            explain_silence(robot, exc)
        await first(robot.telemetry(), timeout, "telemetry (0x81)")
        out(str(await robot.diagnose()))


async def monitor(port: str, seconds: float | None) -> None:
    """A live view of the telemetry, faults, events and link (plain lines without rich)."""
    async with Chassis(port) as robot, anyio.create_task_group() as tg:
        recent: collections.deque[str] = collections.deque(maxlen=4)
        report: list[Diagnosis] = []

        async def follow_events() -> None:
            async for event in robot.events():
                recent.append(f"{time.strftime('%H:%M:%S')} {event}")
                if plain:
                    out(f"event: {event}")

        async def check_health() -> None:  # diagnose() reads 0xB0: once a second is plenty
            while True:
                report[:] = [await robot.diagnose()]
                await anyio.sleep(1.0)

        try:
            from rich.live import Live
            from rich.table import Table

            plain = False
        except ImportError:  # plain lines without rich
            plain = True
        tg.start_soon(follow_events)
        tg.start_soon(check_health)
        end = None if seconds is None else time.monotonic() + seconds
        if plain:
            await first(robot.telemetry(), 2.0, "telemetry (0x81)")
            out(str(await robot.diagnose()))
            async for t in robot.telemetry():
                out(format_telemetry(t))
                if end is not None and time.monotonic() >= end:
                    break
            tg.cancel_scope.cancel()
            return

        def render(t: Telemetry) -> Table:
            table = Table(title=f"chassis on {port}", show_header=False)
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
            if report:
                faults = report[0].faults
                table.add_row("faults", "\n".join(faults) if faults else "none")
            table.add_row("events", "\n".join(recent) or "-")
            s = robot.stats
            table.add_row(
                "link",
                f"{s.frames} frames, {s.bytes_dropped} bytes dropped, "
                f"{s.checksum_errors} checksum errors, {s.sequence_gaps} gaps",
            )
            return table

        with Live(auto_refresh=False) as live:
            last = 0.0
            async for t in robot.telemetry():
                if t.timestamp - last >= 0.1:
                    live.update(render(t), refresh=True)
                    last = t.timestamp
                if end is not None and time.monotonic() >= end:
                    break
        tg.cancel_scope.cancel()


def plot(rows: list[tuple[float, object]], axes: Any) -> None:
    """Velocities, wheel speeds and voltage of a decoded capture on three axes."""
    tel = [(t, m) for t, m in rows if isinstance(m, Telemetry)]
    ts = [t for t, _ in tel]
    axes[0].plot(ts, [m.linear for _, m in tel], label="linear (m/s)")
    axes[0].plot(ts, [m.angular for _, m in tel], label="angular (rad/s)")
    axes[0].set_ylabel("velocity")
    for name in ("front_left", "front_right", "rear_left", "rear_right"):
        axes[1].plot(ts, [getattr(m.wheels, name) for _, m in tel], label=name)
    axes[1].set_ylabel("wheel speed (m/s)")
    axes[2].plot(ts, [m.voltage for _, m in tel], label="battery (V)")
    axes[2].set_ylabel("volts")
