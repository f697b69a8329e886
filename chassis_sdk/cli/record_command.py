"""``chassis-sdk record``: listen on a port (never write) and write a capture,
``FILE.jsonl`` (the raw bytes) or ``FILE.mcap`` (decoded too, for Foxglove)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..errors import ChassisError
from ..recording import capture
from .arguments import device_arg, port_args, positive, require_port
from .common import progress_line

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "record"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``record``."""
    p = sub.add_parser("record", help="record a port: FILE.jsonl (raw bytes) or FILE.mcap")
    port_args(p)
    p.add_argument("file", help="FILE.jsonl: raw bytes; FILE.mcap: also decoded (Foxglove)")
    p.add_argument("--seconds", type=positive("seconds"), default=10.0)
    device_arg(p, names, detected=True)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    return record(port, args.file, args.seconds, args.baudrate, args.device)


async def record(port: str, path: str, seconds: float, baudrate: int, device: str | None) -> None:
    """Record ``port`` into ``path`` for ``seconds``, showing progress.

    Raises:
        ChassisError: The link was lost and not restored before the end.
    """
    show = progress_line(f"recording {path}")

    def progress(n_bytes: int, elapsed: float, up: bool) -> None:
        link = "" if up else "  LINK LOST, reconnecting"
        show(f"{n_bytes:,} bytes, {elapsed:4.1f}/{seconds:g} s{link}", not up)

    cap = await capture.record(
        port, path, seconds=seconds, baudrate=baudrate, progress=progress, device=device
    )
    show.done(
        f"recorded {cap.bytes:,} bytes in {cap.chunks} chunks over {cap.seconds:.1f} s "
        f"to {path}" + (f"; the link dropped {cap.disconnects} time(s)" if cap.disconnects else "")
    )
    if not cap.connected:
        raise ChassisError(f"the link to {port} was lost and not restored before the end")
