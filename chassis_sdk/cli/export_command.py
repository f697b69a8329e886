"""``chassis-sdk export``: a capture's streams (and the host's commands, where it holds
them) as CSV files, one per stream."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from .arguments import device_arg
from .captures import detect_file, no_messages, output_directory, require_reader
from .common import out, show_warnings

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "export"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``export``."""
    p = sub.add_parser("export", help="write a capture's streams as CSV files, one per stream")
    p.add_argument("file", help="a .jsonl capture or a .mcap recording")
    p.add_argument("--csv", required=True, metavar="DIR", help="directory for the CSV files")
    device_arg(p, names, detected=True)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    require_reader("export", args.file)
    output_directory(args.csv, "--csv")  # before the capture is read
    show_warnings("chassis_sdk.recording.capture", "export")  # a capture cut short
    export(args.file, args.csv, args.device)
    return None


def export(path: str, directory: str, device: str | None) -> None:
    """Write the capture ``path`` (of ``device``, else detected) as CSV files into
    ``directory``, printing each file with its row count.

    Raises:
        ChassisError: The capture holds no frames of the device.
    """
    from ..recording.export import export_csv

    proto = device or detect_file(path)
    written = export_csv(path, directory, proto)
    if not written:
        no_messages(path, proto)
    for name, table in sorted(written.items()):
        out(f"{table.path}: {table.rows:,} rows ({name})")
