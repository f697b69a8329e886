"""The ``chassis-sdk`` command line, built on the public API and the device registry.

Every command prints one clear line and exits non-zero on the everyday failures (no
such port, permission denied, nothing answering) instead of a traceback. Commands loop
over :func:`chassis_sdk.devices.profiles`: a device registered or installed as a
package is simulated, detected, recorded, replayed and driven like the built-in ones,
and a device's own commands (``demo``, ``info``, ``monitor``, ``plot``) come from its
profile.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import sys
from collections.abc import Coroutine, Sequence
from typing import Any

from .. import capture
from ..core.run import run
from ..core.simulator import LineFaults
from ..devices import DeviceProfile, profile, profiles
from ..errors import ChassisError, RequestTimeoutError
from .common import jsonable, out

__all__ = ["main"]


async def _sim(device: DeviceProfile, tcp: int | None, faults: LineFaults) -> None:
    async with device.simulator(tcp_port=tcp, faults=faults) as server:
        out(server.port)
        out(f"{device.name} simulator running; connect to the line above. Ctrl-C stops it.")
        await asyncio.Event().wait()


async def _info(device: DeviceProfile, port: str, timeout: float) -> None:
    if device.info is not None:
        await device.info(port, timeout)
        return
    async with device.device(port, request_timeout=timeout) as dev:
        out(f"port         {port}")
        out(f"device       {device.name}: {device.summary}")
        for _ in range(int(timeout / 0.05) + 1):  # a generic device: wait for frames
            if dev.stats.frames:
                break
            await asyncio.sleep(0.05)
        else:
            raise RequestTimeoutError(f"no {device.recognised_by} within {timeout:g} s")
        out(f"link         {dev.connection_state.value} via {dev.transport_backend}")
        for key, value in dev.stats.as_dict().items():
            if value:
                out(f"  {key:<19}{value}")


async def _drive(
    device: DeviceProfile, port: str, linear: float, angular: float, seconds: float
) -> None:
    async with device.device(port) as dev:
        out(f"driving v={linear} m/s, w={angular} rad/s for {seconds} s")
        await dev.set_velocity(linear, angular, duration=seconds)
        await asyncio.sleep(seconds)
        await dev.stop()
    out("stopped")


async def _monitor(device: DeviceProfile, port: str, seconds: float | None) -> None:
    if device.monitor is None:
        raise ChassisError(f"monitor has no view of a {device.name}; try `info` or `record`")
    await device.monitor(port, seconds)


async def _record(port: str, path: str, seconds: float) -> None:
    def progress(n_bytes: int, elapsed: float) -> None:
        print(f"\rrecording {path}: {n_bytes:,} bytes, {elapsed:4.1f}/{seconds:g} s", end="")
        sys.stdout.flush()

    cap = await capture.record(port, path, seconds=seconds, progress=progress)
    out(f"\rrecorded {cap.bytes:,} bytes in {cap.chunks} chunks over {cap.seconds:.1f} s to {path}")


def _replay(path: str, protocol: str | None, as_json: bool) -> None:
    proto = protocol or _detect_file(path)
    for t, msg in capture.decode_capture(path, proto):
        if as_json:
            out(json.dumps({"t": t, "type": type(msg).__name__, **jsonable(msg)}))
        else:
            out(f"{t:10.6f}  {msg}")


def _detect_file(path: str) -> str:
    data = b"".join(chunk for _, chunk in capture.read_capture(path))
    found = capture.detect_in(data)
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
    device = profile(proto)
    rows = list(capture.decode_capture(path, proto))
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(10, 8))
    if device.plot is not None:
        device.plot(rows, axes)
    else:  # a generic device: every numeric field of every message, by type
        _plot_fields(rows, axes)
    axes[2].set_xlabel("time since start of capture (s)")
    for ax in axes:
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper right")
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"{proto} capture {path}")
    fig.tight_layout()
    fig.savefig(output, dpi=100)
    out(f"wrote {output} ({len(rows)} messages)")


def _plot_fields(rows: list[tuple[float, object]], axes: Any) -> None:
    series: dict[str, tuple[list[float], list[float]]] = {}
    for t, msg in rows:
        for key, value in jsonable(msg).items():
            if isinstance(value, int | float) and not isinstance(value, bool):
                name = f"{type(msg).__name__}.{key}"
                if key != "timestamp":
                    ts, ys = series.setdefault(name, ([], []))
                    ts.append(t)
                    ys.append(float(value))
    for i, (name, (ts, ys)) in enumerate(sorted(series.items())[:9]):
        axes[min(i // 3, 2)].plot(ts, ys, label=name)


async def _detect(port: str, seconds: float) -> None:
    found = await capture.detect_protocol(port, seconds=seconds)
    if found is None:
        heard = " or ".join(p.recognised_by for p in profiles().values())
        raise ChassisError(
            f"nothing recognisable on {port} within {seconds:g} s (expected {heard} frames)"
        )
    out(found)


async def _demo(device: DeviceProfile) -> None:
    if device.demo is None:
        raise ChassisError(f"there is no demo of a {device.name}; try `sim {device.name}`")
    await device.demo()


def _parser() -> argparse.ArgumentParser:
    from .. import __version__

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

    s = sub.add_parser("sim", help="run a simulator until Ctrl-C; prints the port to use")
    s.add_argument("kind", choices=names)
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

    i = sub.add_parser("info", help="what the device says about itself, and a diagnosis")
    i.add_argument("port", help="device path, pty path or socket://host:port")
    i.add_argument("--protocol", choices=names, default=names[0])
    i.add_argument("--timeout", type=float, default=1.0, help="seconds per request")

    m = sub.add_parser("monitor", help="live view of the telemetry, faults and events")
    m.add_argument("port")
    m.add_argument("--protocol", choices=names, default=names[0])
    m.add_argument("--seconds", type=float, help="stop after this long")

    dr = sub.add_parser("drive", help="drive for a while, then stop")
    dr.add_argument("port")
    dr.add_argument("--protocol", choices=names, default=names[0])
    dr.add_argument("--linear", type=float, default=0.0, help="m/s")
    dr.add_argument("--angular", type=float, default=0.0, help="rad/s")
    dr.add_argument("--duration", type=float, default=1.0, help="seconds")
    r = sub.add_parser("record", help="capture timestamped raw bytes from a port")
    r.add_argument("port")
    r.add_argument("file")
    r.add_argument("--seconds", type=float, default=10.0)

    rp = sub.add_parser("replay", help="decode a capture and print its messages")
    rp.add_argument("file")
    rp.add_argument("--protocol", choices=names, help="default: detected")
    rp.add_argument("--json", action="store_true", help="one JSON object per line")

    pl = sub.add_parser("plot", help="plot a capture: velocities, wheel speeds, voltage, ...")
    pl.add_argument("file")
    pl.add_argument("-o", "--output", default="capture.png")
    pl.add_argument("--protocol", choices=names, help="default: detected")

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
        job = _demo(profile(args.device))
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
        job = _sim(profile(args.kind), args.tcp, faults)
    elif args.command == "info":
        job = _info(profile(args.protocol), args.port, args.timeout)
    elif args.command == "monitor":
        job = _monitor(profile(args.protocol), args.port, args.seconds)
    else:
        job = _drive(profile(args.protocol), args.port, args.linear, args.angular, args.duration)
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
    return str(getattr(args, "protocol", None) or next(iter(profiles())))
