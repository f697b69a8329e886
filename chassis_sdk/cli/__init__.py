"""The ``chassis-sdk`` command line, built on the public API and the device registry.

Every command prints one clear line and exits non-zero on the everyday failures (no
such port, permission denied, nothing answering, the wrong device on the port, the
cable pulled) instead of a traceback. Commands loop over
:func:`chassis_sdk.devices.profiles`: a device registered or installed as a package is
simulated, detected, recorded, replayed and driven like the built-in ones, and a
device's own commands (``demo``, ``info``, ``monitor``, ``plot``) come from its
profile.

``CHASSIS_SDK_PORT`` and ``CHASSIS_SDK_PROTOCOL`` give the defaults of the port and of
``--protocol``, so a robot's service file or a shell profile sets them once.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import logging
import os
import sys
import time
from collections.abc import Callable, Coroutine, Sequence
from typing import Any

from ..core.ports import list_serial_ports
from ..core.run import run
from ..core.supervisor import ConnectionState
from ..core.validation import check_int, check_real
from ..core.watchdog import MotionLimits
from ..devices import DeviceProfile, profile, profiles
from ..errors import ChassisError, RequestTimeoutError
from ..recording import capture
from ..sim import simulator
from ..sim.server import LineFaults
from .common import first_frame, jsonable, out, progress_line
from .devices import commands

__all__ = ["ENV_BROKER", "ENV_PORT", "ENV_PROTOCOL", "main"]

#: Environment variables that give defaults to the port and ``--protocol``.
ENV_PORT = "CHASSIS_SDK_PORT"
ENV_PROTOCOL = "CHASSIS_SDK_PROTOCOL"
ENV_BROKER = "CHASSIS_SDK_BROKER"
#: ``drive``'s default limits: slow enough to walk beside.
DRIVE_MAX_LINEAR = 0.5
DRIVE_MAX_ANGULAR = 1.0


# --- commands -----------------------------------------------------------------------------


def _ports(as_json: bool) -> None:
    ports = list_serial_ports()
    if as_json:
        out(json.dumps([p.as_dict() for p in ports]))
        return
    if not ports:
        out("no serial ports found (is the adapter plugged in? see `dmesg | tail`)")
        return
    for p in ports:
        usb = f"  USB {p.vid_pid}" if p.vid_pid else ""
        who = ", ".join(x for x in (p.manufacturer, p.description) if x)
        serial_no = f"  serial {p.serial_number}" if p.serial_number else ""
        out(f"{p.device:<16}{usb}  {who or '-'}{serial_no}  [{p.access}]")


async def _detect_one(port: str, seconds: float, baudrate: int) -> str:
    try:
        found = await capture.detect_protocol(port, seconds=seconds, baudrate=baudrate)
    except ChassisError as exc:
        return str(exc)
    if found is None:
        heard = " or ".join(p.recognised_by for p in profiles().values())
        return f"nothing recognisable within {seconds:g} s (expected {heard})"
    return found


async def _detect(port: str | None, seconds: float, baudrate: int) -> None:
    if port is not None:
        found = await _detect_one(port, seconds, baudrate)
        if found not in profiles():
            raise ChassisError(f"{port}: {found}")
        out(found)
        return
    # Every listed port at once, listening only: nothing is ever written to a port
    # that may be someone else's device.
    ports = [p.device for p in list_serial_ports() if p.access == "ok"]
    if not ports:
        raise ChassisError("no serial port this user can open (see `chassis-sdk ports`)")
    results = await asyncio.gather(*(_detect_one(p, seconds, baudrate) for p in ports))
    for port_name, found in zip(ports, results, strict=True):
        out(f"{port_name}: {found}")
    if not any(found in profiles() for found in results):
        raise ChassisError("no known device answered on any port")


async def _sim(device: DeviceProfile, tcp: int | None, faults: LineFaults) -> None:
    async with simulator(device.name, tcp_port=tcp, faults=faults) as server:
        out(server.port)
        out(f"{device.name} simulator running; connect to the line above. Ctrl-C stops it.")
        await asyncio.Event().wait()


async def _info(device: DeviceProfile, port: str, baudrate: int, timeout: float) -> None:
    own = commands(device.name).info
    if own is not None:
        await own(port, baudrate, timeout)
        return
    async with device.device(port, baudrate=baudrate, request_timeout=timeout) as dev:
        out(f"port         {port}")
        out(f"device       {device.name}: {device.summary}")
        await first_frame(dev, max(timeout, 1.0), device.recognised_by)
        out(f"link         {dev.connection_state.value} via {dev.transport_backend}")
        for key, value in dev.stats.as_dict().items():
            if value:
                out(f"  {key:<19}{value}")


def _clamp(name: str, value: float, limit: float, flag: str, unit: str) -> float:
    if abs(value) <= limit:
        return value
    clamped = limit if value > 0 else -limit
    out(f"{name} {value:g} {unit} clamped to {clamped:g} {unit} ({flag})")
    return clamped


async def _drive(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    linear = _clamp("linear", args.linear, args.max_linear, "--max-linear", "m/s")
    angular = _clamp("angular", args.angular, args.max_angular, "--max-angular", "rad/s")
    limits = MotionLimits(max_linear=args.max_linear, max_angular=args.max_angular)
    async with device.device(port, baudrate=args.baudrate, limits=limits) as dev:
        # Only a device that answers in its own protocol is driven.
        await first_frame(dev, args.timeout, device.recognised_by)
        states = dev.connection_states()
        out(f"driving v={linear:g} m/s, w={angular:g} rad/s for {args.duration:g} s")
        started = time.monotonic()
        await dev.set_velocity(linear, angular, duration=args.duration)
        try:
            async with asyncio.timeout(args.duration):
                async for state in states:
                    if state in (ConnectionState.LOST, ConnectionState.RECONNECTING):
                        raise ChassisError(
                            f"lost the link to {port} after {time.monotonic() - started:.1f} s "
                            "while driving; the firmware stops the wheels on its own"
                        )
        except TimeoutError:
            pass
        await dev.stop()
    out("stopped")


async def _monitor(
    device: DeviceProfile, port: str, baudrate: int, seconds: float | None, as_json: bool
) -> None:
    own = commands(device.name).monitor
    if own is not None:
        await own(port, baudrate, seconds, as_json)
        return
    # Any other device: its streams (from its profile), link and events, as lines.
    async with device.device(port, baudrate=baudrate, reconnect=True) as dev:
        await first_frame(dev, 3.0, device.recognised_by)
        if not as_json:
            print("Ctrl-C to quit", file=sys.stderr)
        async with asyncio.TaskGroup() as tg:
            tasks = [tg.create_task(_follow(dev, name, as_json)) for name in device.remote.streams]
            tasks.append(tg.create_task(_follow_link(dev, as_json)))
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.Event().wait(), seconds)
            for task in tasks:
                task.cancel()


def _brief(value: object) -> str:
    """A message's fields on one line, numbers to three decimals."""
    if isinstance(value, dict):
        return " ".join(f"{k}={_brief(v)}" for k, v in value.items() if k != "timestamp")
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


async def _follow(dev: Any, stream: str, as_json: bool) -> None:
    last = 0.0
    async for message in getattr(dev, stream)():
        if as_json:
            out(json.dumps({"type": type(message).__name__, **jsonable(message)}))
        elif time.monotonic() - last >= 0.2:  # five lines a second per stream at most
            out(f"{stream}: {_brief(jsonable(message))}")
            last = time.monotonic()


async def _follow_link(dev: Any, as_json: bool) -> None:
    async for state in dev.connection_states():
        out(
            json.dumps({"type": "link", "state": state.value})
            if as_json
            else f"link: {state.value}"
        )


async def _record(
    port: str, path: str, seconds: float, baudrate: int, protocol: str | None
) -> None:
    show = progress_line(f"recording {path}")

    def progress(n_bytes: int, elapsed: float, up: bool) -> None:
        link = "" if up else "  LINK LOST, reconnecting"
        show(f"{n_bytes:,} bytes, {elapsed:4.1f}/{seconds:g} s{link}", not up)

    cap = await capture.record(
        port, path, seconds=seconds, baudrate=baudrate, progress=progress, protocol=protocol
    )
    show.done(
        f"recorded {cap.bytes:,} bytes in {cap.chunks} chunks over {cap.seconds:.1f} s "
        f"to {path}" + (f"; the link dropped {cap.disconnects} time(s)" if cap.disconnects else "")
    )
    if not cap.connected:
        raise ChassisError(f"the link to {port} was lost and not restored before the end")


def _replay(path: str, protocol: str | None, as_json: bool) -> None:
    proto = protocol or _detect_file(path)
    count = 0
    lines: list[str] = []
    # Streamed: decoded as read, written a thousand lines at a time (a line per write
    # and a flush per line cost more than the decoding).
    for t, msg in capture.decode_capture(path, proto):
        count += 1
        if as_json:
            lines.append(json.dumps({"t": t, "type": type(msg).__name__, **jsonable(msg)}))
        else:
            lines.append(f"{t:10.6f}  {msg}")
        if len(lines) == 1000:
            sys.stdout.write("\n".join(lines) + "\n")
            lines.clear()
    if lines:
        sys.stdout.write("\n".join(lines) + "\n")
    sys.stdout.flush()
    if count == 0:
        _no_messages(path, proto)


async def _replay_as_device(args: argparse.Namespace) -> None:
    from ..sim.server import SimulatorServer

    proto = args.protocol or _detect_file(args.file)
    start_after = 0.0 if args.tcp is not None else args.start_after
    finished = asyncio.Event()
    device = capture.CaptureDevice(
        args.file, proto, speed=args.speed, start_after=start_after, on_done=finished.set
    )
    total = sum(len(data) for _, data in device.chunks)
    if not total:
        raise ChassisError(f"{args.file} holds no bytes to replay")
    async with SimulatorServer(device, tcp_port=args.tcp) as server:
        out(server.port)
        out(f"replaying {total:,} bytes of {proto} capture {args.file} at {args.speed:g}x")
        await finished.wait()
        await asyncio.sleep(0.5)  # the last bytes reach the application before the line goes
    kinds: dict[str, int] = {}
    for command in device.commands:
        kinds[type(command).__name__] = kinds.get(type(command).__name__, 0) + 1
    wrote = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "nothing"
    out(f"replayed {device.bytes_played:,} bytes; the application wrote {wrote}")


def _no_messages(path: str, proto: str) -> None:
    data = _head(path)
    if not data:
        raise ChassisError(f"{path} holds no bytes")
    other = capture.detect_in(data)
    hint = f": it looks like a {other} capture; try --protocol {other}" if other else ""
    raise ChassisError(f"no {proto} frames in {path}{hint}")


def _head(path: str, size: int = 1 << 16) -> bytes:
    """The first ``size`` bytes the device sent in a capture (enough to tell which
    device it is: thousands of frames), without reading the rest."""
    data = bytearray()
    for _, chunk in capture.read_capture(path):
        data += chunk
        if len(data) >= size:
            break
    return bytes(data)


def _detect_file(path: str) -> str:
    if capture.is_mcap(path):
        recorded = capture.mcap_metadata(path).get("device")
        if recorded in profiles():
            return recorded
    found = capture.detect_in(_head(path))
    if found is None:
        raise ChassisError(f"no frames of any known device ({', '.join(profiles())}) in {path}")
    return found


def _plot(path: str, output: str, protocol: str | None) -> None:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ChassisError("plot needs matplotlib: pip install 'chassis-sdk[plot]'") from None
    proto = protocol or _detect_file(path)
    profile(proto)  # an unknown name fails here, naming the known ones
    fig = plt.figure(figsize=(13, 9))
    draw = commands(proto).plot
    if draw is not None:  # from arrays: an hour's frames, no object apiece
        data = capture.capture_columns(path, proto)
        sent_columns = capture.capture_columns(path, proto, commands=True)
        messages, sent = data.frames, sent_columns.frames
        if not messages:
            _no_messages(path, proto)
        draw(data, sent_columns, fig)
    else:  # a generic device: every numeric field of every message, by type
        rows = list(capture.decode_capture(path, proto))
        if not rows:
            _no_messages(path, proto)
        messages = len(rows)
        sent = sum(1 for _ in capture.decode_capture(path, proto, commands=True))
        _plot_fields(rows, fig)
    fig.suptitle(f"{proto} capture {path}")
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    plt.close(fig)
    extra = f" and {sent} commands" if sent else ""
    out(f"wrote {output} ({messages} messages{extra})")


def _plot_fields(rows: list[tuple[float, object]], fig: Any) -> None:
    series: dict[str, tuple[list[float], list[float]]] = {}
    for t, msg in rows:
        for key, value in jsonable(msg).items():
            numeric = isinstance(value, int | float) and not isinstance(value, bool)
            if numeric and key != "timestamp":
                ts, ys = series.setdefault(f"{type(msg).__name__}.{key}", ([], []))
                ts.append(t)
                ys.append(float(value))
    names = sorted(series)[:6]
    axes = fig.subplots(max(len(names), 1), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, names, strict=False):
        ax.plot(*series[name])
        ax.set_ylabel(name, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time since start of capture (s)")


def _export(path: str, directory: str, protocol: str | None) -> None:
    from ..recording.export import export_csv

    proto = protocol or _detect_file(path)
    written = export_csv(path, directory, proto)
    if not written:
        _no_messages(path, proto)
    for name, table in sorted(written.items()):
        out(f"{table.path}: {table.rows:,} rows ({name})")


async def _serve(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .serve_command import serve

    await serve(device, port, args)


async def _bridge(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .bridge_command import bridge

    await bridge(device, port, args)


async def _demo(device: DeviceProfile) -> None:
    demo = commands(device.name).demo
    if demo is None:
        raise ChassisError(f"there is no demo of a {device.name}; try `sim {device.name}`")
    await demo()


# --- arguments ----------------------------------------------------------------------------


def _arg_type(convert: Callable[[str], Any], check: Callable[[Any], Any]) -> Callable[[str], Any]:
    """An argparse type that refuses what the SDK would refuse, before any port opens."""

    def parse(text: str) -> Any:
        try:
            return check(convert(text))
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None

    return parse


def _finite(name: str) -> Callable[[str], Any]:
    return _arg_type(float, lambda v: check_real(v, name))


def _positive(name: str) -> Callable[[str], Any]:
    return _arg_type(float, lambda v: check_real(v, name, low=0, low_open=True))


_BAUD = _arg_type(int, lambda v: check_int(v, "baudrate", low=1))


def _port_args(p: argparse.ArgumentParser, *, required: bool = True) -> None:
    help_text = f"device path, pty path or socket://host:port (default: ${ENV_PORT})"
    if not required:
        help_text = f"the port (default: ${ENV_PORT}, else every serial port)"
    p.add_argument("port", nargs="?", default=os.environ.get(ENV_PORT) or None, help=help_text)
    p.add_argument("-b", "--baudrate", type=_BAUD, default=115200, help="serial speed")


def _protocol_arg(p: argparse.ArgumentParser, names: list[str], *, detected: bool) -> None:
    default = os.environ.get(ENV_PROTOCOL) or (None if detected else names[0])
    p.add_argument(
        "--protocol",
        choices=names,
        default=default,
        help=f"which device (default: ${ENV_PROTOCOL}, else "
        + ("detected)" if detected else f"{names[0]})"),
    )


def _parser() -> argparse.ArgumentParser:
    from .._version import __version__

    known = profiles()
    names = list(known)
    p = argparse.ArgumentParser(
        prog="chassis-sdk",
        description="Talk to robot chassis and controller boards, or simulate them.",
        epilog="devices: " + "; ".join(f"{n}: {d.summary}" for n, d in known.items()),
    )
    p.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    p.add_argument("-v", "--verbose", action="store_true", help="DEBUG logs with frame hex dumps")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    d = sub.add_parser("demo", help="drive the built-in simulator through the real serial stack")
    d.add_argument("--device", choices=names, default=names[0], help="which device to demo")
    for other in names[1:]:
        d.add_argument(
            f"--{other}",
            action="store_const",
            dest="device",
            const=other,
            help=f"= --device {other}",
        )

    po = sub.add_parser("ports", help="list the serial ports, with USB ids and access")
    po.add_argument("--json", action="store_true", help="one JSON array, for scripts")

    de = sub.add_parser("detect", help="listen and say which device is on a port (or on each)")
    _port_args(de, required=False)
    de.add_argument("--seconds", type=_positive("seconds"), default=1.5, help="how long to listen")

    s = sub.add_parser("sim", help="run a simulator until Ctrl-C; prints the port to use")
    s.add_argument("kind", choices=names)
    s.add_argument("--tcp", type=int, metavar="PORT", help="serve on TCP instead of a pty")
    for flag, dest, what in (
        ("--noise", "noise", "insert a random byte before a sent byte with this chance"),
        ("--bit-flips", "bit_flips", "flip one bit of a sent byte with this chance"),
        ("--drop", "drop", "lose a sent byte with this chance"),
    ):
        s.add_argument(flag, dest=dest, type=float, default=0.0, metavar="RATE", help=what)
    s.add_argument(
        "--reply-delay", type=float, default=0.0, metavar="SECONDS", help="hold replies back"
    )

    i = sub.add_parser("info", help="what the device says about itself, and a diagnosis")
    _port_args(i)
    _protocol_arg(i, names, detected=False)
    i.add_argument("--timeout", type=_positive("timeout"), default=1.0, help="seconds per request")

    m = sub.add_parser("monitor", help="live view of the streams, link, faults and events")
    _port_args(m)
    _protocol_arg(m, names, detected=False)
    m.add_argument("--seconds", type=_positive("seconds"), help="stop after this long")
    m.add_argument("--json", action="store_true", help="one JSON object per message")

    dr = sub.add_parser("drive", help="drive for a while (within limits), then stop")
    _port_args(dr)
    _protocol_arg(dr, names, detected=False)
    dr.add_argument("--linear", type=_finite("linear"), default=0.0, help="m/s")
    dr.add_argument("--angular", type=_finite("angular"), default=0.0, help="rad/s")
    dr.add_argument("--duration", type=_positive("duration"), default=1.0, help="seconds")
    dr.add_argument(
        "--max-linear",
        type=_positive("max_linear"),
        default=DRIVE_MAX_LINEAR,
        help="m/s (clamps --linear)",
    )
    dr.add_argument(
        "--max-angular",
        type=_positive("max_angular"),
        default=DRIVE_MAX_ANGULAR,
        help="rad/s (clamps --angular)",
    )
    dr.add_argument(
        "--timeout", type=_positive("timeout"), default=2.0, help="seconds to hear the device"
    )

    br = sub.add_parser("bridge", help="put the device on an MQTT broker (pip install '.[mqtt]')")
    _port_args(br)
    _protocol_arg(br, names, detected=False)
    br.add_argument(
        "--broker",
        default=os.environ.get(ENV_BROKER) or "mqtt://127.0.0.1:1883",
        help=f"mqtt://HOST:PORT or mqtts://HOST:PORT (default: ${ENV_BROKER})",
    )
    br.add_argument("--robot-id", required=True, help="the robot's name under the prefix")
    br.add_argument("--prefix", default="robots", help="the first topic level")
    br.add_argument("--rate", type=_positive("rate"), default=10.0, help="telemetry per second")
    br.add_argument("--read-only", action="store_true", help="never take a command")
    br.add_argument(
        "--take-over", action="store_true", help="start even if another bridge has this robot id"
    )
    br.add_argument(
        "--require-timestamp",
        action="store_true",
        help="refuse velocity commands without a 'timestamp' (clocks must be in sync)",
    )
    br.add_argument("--username", help="broker user name")
    br.add_argument("--password-file", help="a file holding the broker password")
    br.add_argument("--tls", action="store_true", help="TLS (implied by mqtts://)")
    br.add_argument("--cafile", help="CA certificates for TLS (default: the system's)")

    r = sub.add_parser("record", help="record a port: FILE.jsonl (raw bytes) or FILE.mcap")
    _port_args(r)
    r.add_argument("file", help="FILE.jsonl: raw bytes; FILE.mcap: also decoded (Foxglove)")
    r.add_argument("--seconds", type=_positive("seconds"), default=10.0)
    _protocol_arg(r, names, detected=True)

    ex = sub.add_parser("export", help="write a capture's streams as CSV files, one per stream")
    ex.add_argument("file", help="a .jsonl capture or a .mcap recording")
    ex.add_argument("--csv", required=True, metavar="DIR", help="directory for the CSV files")
    _protocol_arg(ex, names, detected=True)

    sv = sub.add_parser("serve", help="serve the device live to the Foxglove app (WebSocket)")
    _port_args(sv)
    _protocol_arg(sv, names, detected=False)
    sv.add_argument("--foxglove-port", type=int, default=8765, help="TCP port (default 8765)")
    sv.add_argument(
        "--host", default="127.0.0.1", help="address to bind (default: this computer only)"
    )
    sv.add_argument("--read-only", action="store_true", help="no Teleop; only stop services")
    sv.add_argument(
        "--allow-origin",
        action="append",
        metavar="ORIGIN",
        help="also let in web pages of this origin (scheme://host[:port]); repeatable",
    )
    sv.add_argument("--token", help="a secret clients must give (?token=...); visible in ps")
    sv.add_argument("--token-file", metavar="FILE", help="read the token from FILE (mode 600)")
    sv.add_argument(
        "--no-token", action="store_true", help="allow --host beyond loopback without a token"
    )
    sv.add_argument("--record", metavar="FILE.mcap", help="also record the session")
    sv.add_argument(
        "--max-linear", type=_positive("max_linear"), default=DRIVE_MAX_LINEAR, help="m/s"
    )
    sv.add_argument(
        "--max-angular", type=_positive("max_angular"), default=DRIVE_MAX_ANGULAR, help="rad/s"
    )
    sv.add_argument(
        "--command-timeout",
        type=_positive("command_timeout"),
        default=0.5,
        help="stop this long after Teleop's last message (s)",
    )
    sv.add_argument("--seconds", type=_positive("seconds"), help="stop after this long")

    rp = sub.add_parser("replay", help="decode a capture and print its messages")
    rp.add_argument("file")
    _protocol_arg(rp, names, detected=True)
    rp.add_argument("--json", action="store_true", help="one JSON object per line")
    rp.add_argument(
        "--as-device", action="store_true", help="serve the recorded bytes on a pty (or --tcp)"
    )
    rp.add_argument("--tcp", type=int, metavar="PORT", help="with --as-device: serve on TCP")
    rp.add_argument("--speed", type=_positive("speed"), default=1.0, help="playback speed")
    rp.add_argument(
        "--start-after",
        type=_positive("start_after"),
        default=1.0,
        help="with --as-device on a pty: seconds before playback starts",
    )

    pl = sub.add_parser("plot", help="plot a capture: velocities, wheel speeds, voltage, ...")
    pl.add_argument("file")
    pl.add_argument("-o", "--output", default="capture.png")
    _protocol_arg(pl, names, detected=True)
    return p


def _job(args: argparse.Namespace, parser: argparse.ArgumentParser) -> Coroutine[Any, Any, None]:
    command = args.command
    if command == "detect":
        return _detect(args.port, args.seconds, args.baudrate)
    if command == "demo":
        return _demo(profile(args.device))
    if command == "sim":
        faults = LineFaults(
            noise_rate=args.noise,
            bit_flip_rate=args.bit_flips,
            drop_rate=args.drop,
            reply_delay=args.reply_delay,
        )
        return _sim(profile(args.kind), args.tcp, faults)
    if args.port is None:
        parser.error(f"{command}: no port given (give PORT, or set {ENV_PORT})")
    if command == "record":
        return _record(args.port, args.file, args.seconds, args.baudrate, args.protocol)
    device = profile(args.protocol)
    if command == "info":
        return _info(device, args.port, args.baudrate, args.timeout)
    if command == "monitor":
        return _monitor(device, args.port, args.baudrate, args.seconds, args.json)
    if command == "bridge":
        return _bridge(device, args.port, args)
    if command == "serve":
        return _serve(device, args.port, args)
    return _drive(device, args.port, args)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``chassis-sdk`` console script."""
    parser = _parser()
    args = parser.parse_args(argv)
    # The CLI says what went wrong itself, in one line; the library's warnings (a
    # stale link, a reconnect) would only come first with a timestamp. -v shows all.
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.ERROR,
        format="%(asctime)s %(name)s %(levelname)s %(message)s",
    )
    try:
        if args.command == "ports":
            _ports(args.json)
            return 0
        protocol = getattr(args, "protocol", None)
        if protocol is not None and protocol not in profiles():  # from the environment
            parser.error(
                f"{ENV_PROTOCOL}={protocol!r} is not a known device "
                f"(known: {', '.join(profiles())})"
            )
        if args.command == "replay" and args.as_device:
            job = _replay_as_device(args)
        elif args.command in ("replay", "plot", "export"):
            if args.command == "replay":
                _replay(args.file, args.protocol, args.json)
            elif args.command == "export":
                _export(args.file, args.csv, args.protocol)
            else:
                _plot(args.file, args.output, args.protocol)
            return 0
        else:
            job = _job(args, parser)
    except BrokenPipeError:  # `| head`
        return 0
    except (ChassisError, ValueError, OSError) as exc:
        print(f"chassis-sdk: {exc}", file=sys.stderr)
        return 1
    try:
        run(job)  # SIGTERM and SIGHUP unwind like Ctrl-C: the robot is stopped first
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    except RequestTimeoutError as exc:
        hint = f"is the device powered, and is it a {getattr(args, 'protocol', None) or 'device'}?"
        print(f"chassis-sdk: {exc} ({hint})", file=sys.stderr)
        return 2
    except (ChassisError, ValueError) as exc:
        print(f"chassis-sdk: {exc}", file=sys.stderr)
        return 1
    return 0
