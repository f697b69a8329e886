"""``chassis-sdk record``: listen on a port (never write) and write a capture,
``FILE.jsonl`` (the raw bytes) or ``FILE.mcap`` (decoded too, for Foxglove; with
``--ros2``, a rosbag2 file for ROS 2 tools)."""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import anyio

from ..errors import ChassisError
from ..recording import capture
from .arguments import device_arg, port_args, positive, require_port
from .captures import writable
from .common import progress_line, show_warnings
from .extras import require

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "record"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``record``."""
    p = sub.add_parser(
        "record", help="record a port: FILE.jsonl (raw bytes) or FILE.mcap (Foxglove; --ros2)"
    )
    port_args(p)
    p.add_argument("file", help="FILE.jsonl: raw bytes; FILE.mcap: also decoded (Foxglove)")
    p.add_argument(
        "--seconds",
        type=positive("seconds"),
        help="how long to record, in seconds (default: until Ctrl-C)",
    )
    device_arg(p, names, detected=True)
    p.add_argument(
        "--ros2",
        action="store_true",
        help="FILE.mcap as a rosbag2 file (ROS 2 types and QoS: ros2 bag, rosbags); "
        "needs the ros2 extra",
    )
    p.add_argument("--namespace", metavar="NS", help="with --ros2: the topics' namespace")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    writable(args.file)
    path: str | os.PathLike[str] = args.file
    if args.namespace is not None and not args.ros2:
        raise ChassisError("--namespace is for --ros2 (a rosbag2 file)")
    mcap = Path(args.file).suffix.lower() == ".mcap"
    if args.ros2:
        if not mcap:
            raise ChassisError(
                f"--ros2 writes a rosbag2 MCAP file: name it FILE.mcap, not {args.file!r}"
            )
        require("record --ros2", "ros2")
        from ..recording.ros2 import rosbag

        try:  # checked before the port opens
            path = rosbag(args.file, namespace=args.namespace or "")
        except (ImportError, TypeError) as exc:
            raise ChassisError(str(exc)) from None
    elif mcap:
        require("record", "foxglove")
    # No frame of the device a few seconds in is said while recording, in one line.
    show_warnings("chassis_sdk.recording.capture", "record")
    return record(port, path, args.seconds, args.baudrate, args.device)


async def record(
    port: str,
    path: str | os.PathLike[str],
    seconds: float | None,
    baudrate: int,
    device: str | None,
) -> None:
    """Record ``port`` into ``path`` (a file name, or a recording chosen with its
    options: `chassis_sdk.recording.ros2.rosbag`) for ``seconds`` (``None``: until
    Ctrl-C or SIGTERM, like ``candump -l`` and ``ros2 bag record``; the file is closed
    whole and what was recorded is said), showing progress.

    Raises:
        ChassisError: The link was lost and not restored before the end, or no frame
            of the device (of any known device, when none is named) arrived: the
            file is kept, but it is not the recording that was meant.
    """
    show = progress_line(f"recording {os.fspath(path)}")
    until = f"/{seconds:g} s" if seconds is not None else " s (Ctrl-C to stop)"
    so_far = [0, 0.0]

    def progress(n_bytes: int, elapsed: float, up: bool) -> None:
        so_far[:] = [n_bytes, elapsed]
        link = "" if up else "  LINK LOST, reconnecting"
        show(f"{n_bytes:,} bytes, {elapsed:4.1f}{until}{link}", not up)

    try:
        cap = await capture.record(
            port, path, seconds=seconds, baudrate=baudrate, progress=progress, device=device
        )
    except ChassisError:
        raise
    except OSError as exc:  # the file, not the port (the port's are ChassisErrors)
        raise ChassisError(f"cannot write {os.fspath(path)}: {exc.strerror or exc}") from None
    except (anyio.get_cancelled_exc_class(), KeyboardInterrupt):
        # Ctrl-C, SIGTERM: the file was closed whole; say what it holds.
        if so_far[1]:
            show.done(f"recorded {so_far[0]:,} bytes over {so_far[1]:.1f} s to {os.fspath(path)}")
        raise
    show.done(
        f"recorded {cap.bytes:,} bytes in {cap.chunks} chunks over {cap.seconds:.1f} s "
        f"to {os.fspath(path)}"
        + (f"; the link dropped {cap.disconnects} time(s)" if cap.disconnects else "")
    )
    if not cap.connected:
        raise ChassisError(f"the link to {port} was lost and not restored before the end")
    if cap.device is None:
        what = f"{device} frame" if device else "frame of any known device"
        raise ChassisError(
            f"no {what} in the {cap.bytes:,} bytes recorded from {port}"
            + _hint(os.fspath(path), device, cap.bytes)
        )


def _hint(path: str, device: str | None, total: int) -> str:
    """What the recorded bytes look like instead, where a known device's frames are
    in them."""
    if not total or device is None:
        return " (is the device on and sending, at this baud rate?)"
    from .captures import head

    try:
        other = capture.detect_in(head(path))
    except (OSError, ValueError):  # not readable back: no hint, the error stands
        other = None
    if other is not None and other != device:
        return f": they look like a {other}; record again with --device {other}"
    return " (the wrong baud rate?)"
