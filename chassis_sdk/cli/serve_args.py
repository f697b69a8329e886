"""``chassis-sdk serve``'s arguments; the command itself is
`chassis_sdk.cli.serve_command`, imported only when it runs."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..devices import DeviceProfile, profile
from .arguments import (
    TCP_PORT,
    check_record,
    deadman_args,
    device_arg,
    limit_args,
    port_args,
    record_arg,
    require_port,
)
from .extras import install_hint, require

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``serve``."""
    p = sub.add_parser(
        "serve",
        help=f"serve the device live to the Foxglove app ({install_hint('foxglove')})",
    )
    port_args(p)
    device_arg(p, names)
    p.add_argument("--foxglove-port", type=TCP_PORT, default=8765, help="TCP port (default 8765)")
    p.add_argument(
        "--host", default="127.0.0.1", help="address to bind (default: this computer only)"
    )
    p.add_argument("--read-only", action="store_true", help="no Teleop; only stop services")
    p.add_argument(
        "--allow-origin",
        action="append",
        metavar="ORIGIN",
        help="also let in web pages of this origin (scheme://host[:port]); repeatable",
    )
    p.add_argument("--token", help="a secret clients must give (?token=...); visible in ps")
    p.add_argument("--token-file", metavar="FILE", help="read the token from FILE (mode 600)")
    p.add_argument(
        "--no-token", action="store_true", help="allow --host beyond loopback without a token"
    )
    record_arg(p)
    limit_args(p, "Teleop's velocity")
    deadman_args(p, "Teleop")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    require("serve", "foxglove")
    check_record(args, "serve")
    return _serve(profile(args.device), port, args)


async def _serve(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .serve_command import serve

    await serve(device, port, args)
