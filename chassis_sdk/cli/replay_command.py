"""``chassis-sdk replay``: decode a capture and print its messages, or, with
``--as-device``, serve its bytes on a pty (or TCP) as the device sent them."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import anyio

from ..errors import ChassisError
from ..recording import capture
from .arguments import device_arg, positive
from .captures import detect_file, no_messages
from .common import jsonable, out

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "replay", "replay_as_device"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``replay``."""
    p = sub.add_parser("replay", help="decode a capture and print its messages")
    p.add_argument("file")
    device_arg(p, names, detected=True)
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument(
        "--as-device", action="store_true", help="serve the recorded bytes on a pty (or --tcp)"
    )
    p.add_argument("--tcp", type=int, metavar="PORT", help="with --as-device: serve on TCP")
    p.add_argument("--speed", type=positive("speed"), default=1.0, help="playback speed")
    p.add_argument(
        "--start-after",
        type=positive("start_after"),
        default=1.0,
        help="with --as-device on a pty: seconds before playback starts",
    )
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    if args.as_device:
        return replay_as_device(args)
    replay(args.file, args.device, args.json)
    return None


def replay(path: str, device: str | None, as_json: bool) -> None:
    """Print every message of the capture ``path`` (of ``device``, else detected).

    Raises:
        ChassisError: The capture holds no frames of that device.
    """
    proto = device or detect_file(path)
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
        no_messages(path, proto)


async def replay_as_device(args: argparse.Namespace) -> None:
    """Serve the bytes of the capture ``args.file`` at the recorded timing (times
    ``args.speed``), then say what the application wrote."""
    from ..sim.server import SimulatorServer

    proto = args.device or detect_file(args.file)
    start_after = 0.0 if args.tcp is not None else args.start_after
    finished = anyio.Event()
    device = capture.CaptureFirmware(
        args.file, proto, speed=args.speed, start_after=start_after, on_done=finished.set
    )
    total = sum(len(data) for _, data in device.chunks)
    if not total:
        raise ChassisError(f"{args.file} holds no bytes to replay")
    async with SimulatorServer(device, tcp_port=args.tcp) as server:
        out(server.port)
        out(f"replaying {total:,} bytes of {proto} capture {args.file} at {args.speed:g}x")
        await finished.wait()
        await anyio.sleep(0.5)  # the last bytes reach the application before the line goes
    kinds: dict[str, int] = {}
    for command in device.commands:
        kinds[type(command).__name__] = kinds.get(type(command).__name__, 0) + 1
    wrote = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "nothing"
    out(f"replayed {device.bytes_played:,} bytes; the application wrote {wrote}")
