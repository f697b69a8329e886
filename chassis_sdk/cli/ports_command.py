"""``chassis-sdk ports``: every serial port, with its USB ids, whether this user may
open it (no port is opened), and the names of it that survive renumbering (its
``usb:VID:PID[:SERIAL]`` identity and udev's ``/dev/serial/by-id`` link)."""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..core.ports import list_serial_ports
from .common import out

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "ports"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``ports``."""
    p = sub.add_parser("ports", help="list the serial ports, with USB ids and access")
    p.add_argument("--json", action="store_true", help="one JSON array, for scripts")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    ports(args.json)
    return None


def ports(as_json: bool) -> None:
    """Print the serial ports, one a line (with a second line for a USB port's stable
    names), or as one JSON array."""
    found = list_serial_ports()
    if as_json:
        out(json.dumps([p.as_dict() for p in found]))
        return
    if not found:
        out("no serial ports found (is the adapter plugged in? see `dmesg | tail`)")
        return
    for p in found:
        usb = f"  USB {p.vid_pid}" if p.vid_pid else ""
        who = ", ".join(x for x in (p.manufacturer, p.description) if x)
        serial_no = f"  serial {p.serial_number}" if p.serial_number else ""
        out(f"{p.device:<16}{usb}  {who or '-'}{serial_no}  [{p.access}]")
        if p.identity:
            by_id = f"  by-id {p.by_id}" if p.by_id else ""
            out(f"{'':<16}  id {p.identity}{by_id}")
    named = [p.identity for p in found if p.identity]
    unique = [i for i in named if named.count(i) == 1]
    if unique:
        out(f"use PORT={unique[0]} (a device's id above) to survive renumbering")
