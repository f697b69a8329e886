"""``chassis-sdk replay``: decode a capture and print its messages (the host's
commands among them, marked ``>``, where the capture holds them: a session recorded
with ``--record`` or ``record=``), or, with ``--as-device``, serve its bytes on a pty
(or TCP) as the device sent them."""

from __future__ import annotations

import argparse
import heapq
import json
import sys
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING

import anyio

from ..errors import ChassisError
from ..recording import capture
from .arguments import TCP_PORT, UsageError, device_arg, positive
from .captures import detect_file, no_messages, require_reader
from .common import jsonable, out, show_warnings
from .monitor_command import brief
from .sim_command import serving

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "replay", "replay_as_device", "replay_line"]

#: The options that only mean something with ``--as-device``, and their defaults.
_DEVICE_OPTIONS = {"tcp": None, "speed": 1.0, "start_after": 1.0}


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``replay``."""
    p = sub.add_parser("replay", help="decode a capture and print its messages")
    p.add_argument("file")
    device_arg(p, names, detected=True)
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.add_argument(
        "--as-device", action="store_true", help="serve the recorded bytes on a pty (or --tcp)"
    )
    p.add_argument(
        "--tcp", type=TCP_PORT, metavar="PORT", help="with --as-device: serve on TCP (0: any free)"
    )
    p.add_argument(
        "--speed", type=positive("speed"), help="with --as-device: playback speed (default 1)"
    )
    p.add_argument(
        "--start-after",
        type=positive("start_after"),
        help="with --as-device on a pty: seconds before playback starts (default 1)",
    )
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    given = [name for name in _DEVICE_OPTIONS if getattr(args, name) is not None]
    if not args.as_device and given:
        flags = ", ".join("--" + name.replace("_", "-") for name in given)
        raise UsageError(f"{flags} needs --as-device (serve the capture as a device)")
    for name, default in _DEVICE_OPTIONS.items():
        if getattr(args, name) is None:
            setattr(args, name, default)
    require_reader("replay", args.file)
    # A capture cut by a hard kill is read up to the cut; say so at any verbosity.
    show_warnings("chassis_sdk.recording.capture", "replay")
    if args.as_device:
        return replay_as_device(args)
    replay(args.file, args.device, args.json)
    return None


def replay_line(t: float, msg: object, sent: bool = False) -> str:
    """A decoded message as ``replay`` prints it: its time, its type and its fields the
    way ``monitor`` shows them (names for flags and enums, numbers to three
    decimals); a command the host ``sent`` is marked ``>``."""
    mark = "> " if sent else ""
    return f"{t:10.3f}  {mark}{type(msg).__name__}: {brief(jsonable(msg))}"


def _messages(path: str, device: str) -> Iterator[tuple[float, bool, object]]:
    """``(t, sent, message)`` of the capture in time order: what the device sent, and
    what the host sent where the capture holds it (the frames written: a session
    recorded by its application; a passive capture has none)."""
    received = ((t, False, msg) for t, msg in capture.decode_capture(path, device))
    if next(capture.read_capture(path, sent=True), None) is None:
        return received
    sent = ((t, True, msg) for t, msg in capture.decode_capture(path, device, commands=True))
    # Both directions share the capture's clock; at one time, the host's frame first.
    return heapq.merge(sent, received, key=lambda item: item[0])


def replay(path: str, device: str | None, as_json: bool) -> None:
    """Print every message of the capture ``path`` (of ``device``, else detected),
    the host's commands among them where the capture holds them (``sent`` in JSON).

    Raises:
        ChassisError: The capture holds no frames of that device.
    """
    proto = device or detect_file(path)
    count = 0
    lines: list[str] = []
    # Streamed: decoded as read, written a thousand lines at a time (a line per write
    # and a flush per line cost more than the decoding).
    for t, sent, msg in _messages(path, proto):
        count += not sent
        if as_json:
            item = {"t": t, "type": type(msg).__name__, **jsonable(msg)}
            lines.append(json.dumps({**item, "sent": True} if sent else item))
        else:
            lines.append(replay_line(t, msg, sent))
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
    ``args.speed``), then say what the application wrote. On TCP, playback starts
    when a client connects (and again from the start for each new one).

    Raises:
        ChassisError: The capture holds no bytes, or the TCP port cannot be served.
    """
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
    async with serving(SimulatorServer(device, tcp_port=args.tcp), args.tcp) as server:
        if args.tcp is not None:
            device.hold()  # not to nobody: from the first client's connection
        out(server.port)
        out(f"replaying {total:,} bytes of {proto} capture {args.file} at {args.speed:g}x")
        await finished.wait()
        await anyio.sleep(0.5)  # the last bytes reach the application before the line goes
    kinds: dict[str, int] = {}
    for command in device.commands:
        kinds[type(command).__name__] = kinds.get(type(command).__name__, 0) + 1
    wrote = ", ".join(f"{n} {k}" for k, n in sorted(kinds.items())) or "nothing"
    out(
        f"replayed {device.bytes_played:,} of the capture's {total:,} bytes; "
        f"the application wrote {wrote}"
    )
