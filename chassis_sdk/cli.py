"""The ``chassis-sdk`` command line, built on the public API only.

Every command prints one clear line and exits non-zero on the everyday failures (no
such port, permission denied, nothing answering) instead of a traceback.
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import dataclasses
import datetime
import enum
import json
import logging
import sys
import time
from collections.abc import AsyncIterator, Callable, Coroutine, Sequence
from typing import Any

import anyio

from . import (
    BatteryReading,
    Board,
    Chassis,
    ChassisError,
    Diagnosis,
    ImuSample,
    RequestTimeoutError,
    Telemetry,
    VelocityFeedback,
    __version__,
    capture,
    run,
)
from .sim import BoardSimulator, ChassisSimulator, LineFaults

__all__ = ["main"]

_DEMO_PATTERN: list[tuple[str, float, float, float]] = [
    ("forward", 0.4, 0.0, 1.5),
    ("turn left", 0.2, 0.8, 1.5),
    ("backward", -0.3, 0.0, 1.0),
    ("spin right", 0.0, -1.0, 1.0),
]


def _out(text: str = "") -> None:
    print(text, flush=True)


def _status_names(t: Telemetry) -> str:
    """The set status bits by name (single bits only, not the group aliases)."""
    return "|".join(
        str(m.name) for m in type(t.status) if m.value.bit_count() == 1 and m in t.status
    )


def _format_telemetry(t: Telemetry) -> str:
    status = _status_names(t) or "ok"
    w = t.wheels
    return (
        f"  v={t.linear:+.3f} m/s  w={t.angular:+.3f} rad/s  "
        f"wheels=[{w.front_left:+.2f} {w.front_right:+.2f} {w.rear_left:+.2f} "
        f"{w.rear_right:+.2f}]  {t.voltage:.1f} V  docking={t.docking.name}  status={status}"
    )


async def _print_chassis_info(robot: Chassis) -> None:
    firmware = await robot.get_firmware_version()
    hardware = await robot.get_hardware_version()
    info = await robot.get_chassis_info()
    shipped = await robot.get_ship_date()
    _out(f"firmware     {firmware}")
    _out(f"hardware     {hardware}")
    _out(
        f"geometry     track {info.track_width:.3f} m, wheelbase {info.wheelbase:.3f} m, "
        f"wheel {info.wheel_diameter:.3f} m, gear {info.gear_ratio}:1, "
        f"encoder {info.encoder_resolution} lines"
    )
    _out(f"ship date    {shipped.isoformat()}")


async def _drive_for(
    robot: Chassis | Board, linear: float, angular: float, seconds: float, show: Callable[[], None]
) -> None:
    """Keep a velocity command alive for ``seconds`` (as a control loop would), showing
    live data at 5 Hz."""
    end = time.monotonic() + seconds
    next_show = 0.0
    while (now := time.monotonic()) < end:
        await robot.set_velocity(linear, angular)
        if now >= next_show:
            show()
            next_show = now + 0.2
        await asyncio.sleep(0.1)


async def _demo_chassis() -> None:
    _out("Starting the chassis simulator on a pseudo-terminal ...")
    async with ChassisSimulator() as sim:
        _out(f"simulator    {sim.port}")
        async with Chassis(sim.port) as robot:
            _out(f"connected    via {robot.transport_backend}")
            await _print_chassis_info(robot)
            await anext(robot.telemetry())

            def show() -> None:
                t = robot.latest_telemetry
                if t is not None:
                    _out(_format_telemetry(t))

            for name, v, w, seconds in _DEMO_PATTERN:
                _out(f"drive: {name} (v={v} m/s, w={w} rad/s) for {seconds} s")
                await _drive_for(robot, v, w, seconds, show)
            _out("stop")
            await robot.stop()
            async for t in robot.telemetry():
                if t.linear == 0 and t.angular == 0:
                    _out(_format_telemetry(t))
                    break
            _out("software e-stop on, then off")
            await robot.emergency_stop()
            async for t in robot.telemetry():
                if t.emergency_stopped:
                    _out(_format_telemetry(t))
                    break
            await robot.release_emergency_stop()
            stats = robot.stats
            _out(
                f"link         {stats.frames} frames in, {stats.frames_sent} out, "
                f"{stats.resends} watchdog resends, {stats.bytes_dropped} bytes dropped"
            )
    _out("done: the robot stopped and the port is closed.")


async def _demo_board() -> None:
    _out("Starting the board simulator on a pseudo-terminal ...")
    async with BoardSimulator() as sim:
        _out(f"simulator    {sim.port}")
        async with Board(sim.port) as board:
            _out(f"connected    via {board.transport_backend}")
            _out(f"led          {await board.set_led(True)} (reported by the board)")
            _out(
                f"buzzer       {await board.set_buzzer(True)} then {await board.set_buzzer(False)}"
            )
            await board.set_servo(1, 45.0)
            battery = await anext(board.battery())
            _out(f"battery      {battery.voltage:.2f} V")

            def show() -> None:
                imu, vel = board.latest_imu, board.latest_velocity
                if imu is not None and vel is not None:
                    _out(
                        f"  v={vel.linear:+.3f} m/s  w={vel.angular:+.3f} rad/s  "
                        f"accel=({imu.accel.x:+.2f}, {imu.accel.y:+.2f}, {imu.accel.z:+.2f}) g  "
                        f"gyro z={imu.gyro.z:+6.1f} deg/s"
                    )

            for name, v, w, seconds in _DEMO_PATTERN[:2]:
                _out(f"drive: {name} (v={v} m/s, w={w} rad/s) for {seconds} s")
                await _drive_for(board, v, w, seconds, show)
            await board.stop()
            await board.set_led(False)
    _out("done: the board stopped and the port is closed.")


async def _sim(kind: str, tcp: int | None, faults: LineFaults) -> None:
    server = (
        ChassisSimulator(tcp_port=tcp, faults=faults)
        if kind == "chassis"
        else BoardSimulator(tcp_port=tcp, faults=faults)
    )
    async with server:
        _out(server.port)
        _out(f"{kind} simulator running; connect to the line above. Ctrl-C stops it.")
        await asyncio.Event().wait()


async def _info(port: str, protocol: str, timeout: float) -> None:
    if protocol == "chassis":
        async with Chassis(port, request_timeout=timeout) as robot:
            _out(f"port         {port}")
            try:
                await _print_chassis_info(robot)
            except RequestTimeoutError as exc:
                _explain_silence(robot, exc, "chassis")
            await _first(robot.telemetry(), timeout, "telemetry (0x81)")
            _out(str(await robot.diagnose()))
    else:
        async with Board(port, request_timeout=timeout) as board:
            _out(f"port         {port}")
            try:
                led = await board.get_led()
            except RequestTimeoutError as exc:
                _explain_silence(board, exc, "board")
            _out(f"led          {'on' if led else 'off'}")
            _out(f"buzzer       {'on' if await board.get_buzzer() else 'off'}")
            imu = await _first(board.imu(), timeout, "IMU samples (0x11)")
            _out(f"imu          accel z {imu.accel.z:+.2f} g (about +1 at rest)")
            battery = await _first(board.battery(), 2.0, "battery readings (0x13, 1 Hz)")
            _out(f"battery      {battery.voltage:.2f} V")
            _out(str(await board.diagnose()))


class WrongProtocolError(ChassisError):
    """Bytes arrive, but none of them forms a frame of the expected protocol."""


def _explain_silence(device: Chassis | Board, exc: RequestTimeoutError, expected: str) -> None:
    stats = device.stats
    if stats.bytes_received and not stats.frames:
        other = "board" if expected == "chassis" else "chassis"
        raise WrongProtocolError(
            f"{stats.bytes_received} bytes arrived on {device.port} but none is a {expected} "
            f"frame: is it a {other}? Try --protocol {other}, or `chassis-sdk detect`"
        ) from exc
    raise exc


async def _first(stream: AsyncIterator[Any], timeout: float, what: str) -> Any:
    try:
        async with asyncio.timeout(timeout):
            return await anext(stream)
    except TimeoutError:
        raise RequestTimeoutError(f"no {what} within {timeout:g} s") from None


async def _drive(port: str, protocol: str, linear: float, angular: float, seconds: float) -> None:
    device: Chassis | Board = Chassis(port) if protocol == "chassis" else Board(port)
    async with device:
        _out(f"driving v={linear} m/s, w={angular} rad/s for {seconds} s")
        await device.set_velocity(linear, angular, duration=seconds)
        await asyncio.sleep(seconds)
        await device.stop()
    _out("stopped")


async def _monitor(port: str, seconds: float | None) -> None:
    async with Chassis(port) as robot, anyio.create_task_group() as tg:
        recent: collections.deque[str] = collections.deque(maxlen=4)
        report: list[Diagnosis] = []

        async def follow_events() -> None:
            async for event in robot.events():
                recent.append(f"{time.strftime('%H:%M:%S')} {event}")
                if plain:
                    _out(f"event: {event}")

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
            await _first(robot.telemetry(), 2.0, "telemetry (0x81)")
            _out(str(await robot.diagnose()))
            async for t in robot.telemetry():
                _out(_format_telemetry(t))
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
            bits = [
                m.name
                for m in type(t.status)
                if m in t.status and m.name and m.value.bit_count() == 1
            ]
            table.add_row("status", ", ".join(str(b) for b in bits) or "ok")
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


async def _record(port: str, path: str, seconds: float) -> None:
    def progress(n_bytes: int, elapsed: float) -> None:
        print(f"\rrecording {path}: {n_bytes:,} bytes, {elapsed:4.1f}/{seconds:g} s", end="")
        sys.stdout.flush()

    cap = await capture.record(port, path, seconds=seconds, progress=progress)
    _out(
        f"\rrecorded {cap.bytes:,} bytes in {cap.chunks} chunks over {cap.seconds:.1f} s to {path}"
    )


def _replay(path: str, protocol: str | None, as_json: bool) -> None:
    proto = protocol or _detect_file(path)
    for t, msg in capture.decode_capture(path, proto):  # type: ignore[arg-type]
        if as_json:
            _out(json.dumps({"t": t, "type": type(msg).__name__, **_jsonable(msg)}))
        else:
            _out(f"{t:10.6f}  {msg}")


def _detect_file(path: str) -> str:
    data = b"".join(chunk for _, chunk in capture.read_capture(path))
    found = capture.detect_in(data)
    if found is None:
        raise ChassisError(f"no frames of either protocol in {path}")
    return found


def _jsonable(msg: object) -> dict[str, Any]:
    def convert(value: object) -> Any:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            return {f.name: convert(getattr(value, f.name)) for f in dataclasses.fields(value)}
        if isinstance(value, enum.Enum):
            return value.name if value.name else int(value.value)
        if isinstance(value, tuple) and hasattr(value, "_asdict"):
            return {k: convert(v) for k, v in value._asdict().items()}
        if isinstance(value, datetime.date):
            return value.isoformat()
        return value

    result = convert(msg)
    return result if isinstance(result, dict) else {"value": result}


def _plot(path: str, output: str, protocol: str | None) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ChassisError("plot needs matplotlib: pip install 'chassis-sdk[plot]'") from None
    proto = protocol or _detect_file(path)
    rows = list(capture.decode_capture(path, proto))  # type: ignore[arg-type]
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(10, 8))
    if proto == "chassis":
        tel = [(t, m) for t, m in rows if isinstance(m, Telemetry)]
        ts = [t for t, _ in tel]
        axes[0].plot(ts, [m.linear for _, m in tel], label="linear (m/s)")
        axes[0].plot(ts, [m.angular for _, m in tel], label="angular (rad/s)")
        for name in ("front_left", "front_right", "rear_left", "rear_right"):
            axes[1].plot(ts, [getattr(m.wheels, name) for _, m in tel], label=name)
        axes[1].set_ylabel("wheel speed (m/s)")
        axes[2].plot(ts, [m.voltage for _, m in tel], label="battery (V)")
    else:
        vel = [(t, m) for t, m in rows if isinstance(m, VelocityFeedback)]
        imu = [(t, m) for t, m in rows if isinstance(m, ImuSample)]
        bat = [(t, m) for t, m in rows if isinstance(m, BatteryReading)]
        axes[0].plot([t for t, _ in vel], [m.linear for _, m in vel], label="linear (m/s)")
        axes[0].plot([t for t, _ in vel], [m.angular for _, m in vel], label="angular (rad/s)")
        axes[1].plot([t for t, _ in imu], [m.gyro.z for _, m in imu], label="gyro z (deg/s)")
        axes[2].plot([t for t, _ in bat], [m.voltage for _, m in bat], label="battery (V)")
    axes[0].set_ylabel("velocity")
    axes[2].set_ylabel("volts")
    axes[2].set_xlabel("time since start of capture (s)")
    for ax in axes:
        ax.legend(loc="upper right")
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"{proto} capture {path}")
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    _out(f"wrote {output} ({len(rows)} messages)")


async def _detect(port: str, seconds: float) -> None:
    found = await capture.detect_protocol(port, seconds=seconds)
    if found is None:
        raise ChassisError(
            f"nothing recognisable on {port} within {seconds:g} s "
            "(expected 0x81 chassis telemetry or 0x11 board IMU frames)"
        )
    _out(found)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="chassis-sdk",
        description="Talk to robot chassis and controller boards, or simulate them.",
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="DEBUG logs with frame hex dumps")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    d = sub.add_parser("demo", help="drive the built-in simulator through the real serial stack")
    d.add_argument("--board", action="store_true", help="demo the controller board instead")

    s = sub.add_parser("sim", help="run a simulator until Ctrl-C; prints the port to use")
    s.add_argument("kind", choices=["chassis", "board"])
    s.add_argument("--tcp", type=int, metavar="PORT", help="serve on TCP instead of a pty")
    s.add_argument(
        "--noise",
        type=float,
        default=0.0,
        metavar="RATE",
        help="insert a random byte before a sent byte with this chance",
    )
    s.add_argument(
        "--bit-flips",
        type=float,
        default=0.0,
        metavar="RATE",
        help="flip one bit of a sent byte with this chance",
    )
    s.add_argument(
        "--drop", type=float, default=0.0, metavar="RATE", help="lose a sent byte with this chance"
    )
    s.add_argument(
        "--reply-delay",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="hold every reply back this long",
    )

    i = sub.add_parser("info", help="print versions and geometry (chassis) or a self-check (board)")
    i.add_argument("port", help="device path, pty path or socket://host:port")
    i.add_argument("--protocol", choices=["chassis", "board"], default="chassis")
    i.add_argument("--timeout", type=float, default=1.0, help="seconds per request")

    m = sub.add_parser("monitor", help="live view of the chassis telemetry")
    m.add_argument("port")
    m.add_argument("--seconds", type=float, help="stop after this long")

    dr = sub.add_parser("drive", help="drive for a while, then stop")
    dr.add_argument("port")
    dr.add_argument("--protocol", choices=["chassis", "board"], default="chassis")
    dr.add_argument("--linear", type=float, default=0.0, help="m/s")
    dr.add_argument("--angular", type=float, default=0.0, help="rad/s")
    dr.add_argument("--duration", type=float, default=1.0, help="seconds")
    r = sub.add_parser("record", help="capture timestamped raw bytes from a port")
    r.add_argument("port")
    r.add_argument("file")
    r.add_argument("--seconds", type=float, default=10.0)

    rp = sub.add_parser("replay", help="decode a capture and print its messages")
    rp.add_argument("file")
    rp.add_argument("--protocol", choices=["chassis", "board"], help="default: detected")
    rp.add_argument("--json", action="store_true", help="one JSON object per line")

    pl = sub.add_parser("plot", help="plot velocities, wheel speeds and voltage from a capture")
    pl.add_argument("file")
    pl.add_argument("-o", "--output", default="capture.png")
    pl.add_argument("--protocol", choices=["chassis", "board"], help="default: detected")

    de = sub.add_parser("detect", help="listen briefly and say which protocol is on a port")
    de.add_argument("port")
    de.add_argument("--seconds", type=float, default=1.5)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``chassis-sdk`` console script."""
    args = _parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    job: Coroutine[Any, Any, None]
    if args.command in ("replay", "plot"):
        try:
            if args.command == "replay":
                _replay(args.file, args.protocol, args.json)
            else:
                _plot(args.file, args.output, args.protocol)
        except BrokenPipeError:  # `| head`
            return 0
        except (ChassisError, ValueError, OSError) as exc:
            print(f"chassis-sdk: {exc}", file=sys.stderr)
            return 1
        return 0
    if args.command == "record":
        job = _record(args.port, args.file, args.seconds)
    elif args.command == "detect":
        job = _detect(args.port, args.seconds)
    elif args.command == "demo":
        job = _demo_board() if args.board else _demo_chassis()
    elif args.command == "sim":
        try:
            faults = LineFaults(
                noise_rate=args.noise,
                bit_flip_rate=args.bit_flips,
                drop_rate=args.drop,
                reply_delay=args.reply_delay,
            )
        except ValueError as exc:
            print(f"chassis-sdk: {exc}", file=sys.stderr)
            return 1
        job = _sim(args.kind, args.tcp, faults)
    elif args.command == "info":
        job = _info(args.port, args.protocol, args.timeout)
    elif args.command == "monitor":
        job = _monitor(args.port, args.seconds)
    else:
        job = _drive(args.port, args.protocol, args.linear, args.angular, args.duration)
    try:
        run(job)  # SIGTERM and SIGHUP unwind like Ctrl-C: the robot is stopped first
    except KeyboardInterrupt:
        return 130
    except RequestTimeoutError as exc:
        print(
            f"chassis-sdk: {exc} (is the device powered, and is it a {_kind(args)}?)",
            file=sys.stderr,
        )
        return 2
    except (ChassisError, ValueError) as exc:
        print(f"chassis-sdk: {exc}", file=sys.stderr)
        return 1
    return 0


def _kind(args: argparse.Namespace) -> str:
    return "controller board" if getattr(args, "protocol", "chassis") == "board" else "chassis"


if __name__ == "__main__":  # pragma: no cover
    with contextlib.suppress(KeyboardInterrupt):
        sys.exit(main())
