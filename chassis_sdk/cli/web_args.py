"""``chassis-sdk web``'s arguments; the command itself is
`chassis_sdk.cli.web_command`, imported only when it runs (it needs aiohttp)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..core.validation import check_int, check_real
from ..devices import DeviceProfile, profile
from .arguments import (
    TCP_PORT,
    Renamed,
    arg_type,
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

#: A gamepad's axis or button index.
INDEX = arg_type(int, lambda v: check_int(v, "index", low=0, high=63))


#: A fraction of full scale: (0, 1].
FRACTION = arg_type(float, lambda v: check_real(v, "pad_scale", low=0, low_open=True, high=1))


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``web``."""
    p = sub.add_parser(
        "web",
        help=f"a dashboard in the browser: watch and drive by hand ({install_hint('web')})",
        description=(
            "Serve one page that shows the device live and drives it from an on-screen "
            "joystick, the keyboard or a gamepad, every command under the deadman. "
            "Loopback by default; beyond it a random token is required (the address to "
            "open is printed once)."
        ),
    )
    port_args(p)
    device_arg(p, names)
    p.add_argument(
        "--host", default="127.0.0.1", help="address to bind (default: this computer only)"
    )
    p.add_argument(
        "--http-port",
        type=TCP_PORT,
        default=8080,
        help="TCP port of the page (default 8080; 0: any free one)",
    )
    # Was --port (and [web] port in a profile), which elsewhere is the serial port: one
    # meaning per name, so the old spelling is refused naming the new one.
    p.add_argument("--port", action=Renamed, new="--http-port", help=argparse.SUPPRESS)
    p.add_argument(
        "--read-only", action="store_true", help="show everything; offer only STOP and E-STOP"
    )
    p.add_argument(
        "--token-file",
        metavar="FILE",
        help="the token to require, from FILE (mode 600), instead of a random one",
    )
    p.add_argument(
        "--allow-origin",
        action="append",
        metavar="ORIGIN",
        help="also let pages of this origin open the WebSocket (scheme://host[:port])",
    )
    pad = p.add_argument_group("gamepad (the browser's Gamepad API, standard mapping)")
    pad.add_argument("--enable-button", type=INDEX, default=4, help="held to drive (default 4: LB)")
    pad.add_argument(
        "--linear-axis", type=INDEX, default=1, help="forward and back (default 1: left stick)"
    )
    pad.add_argument(
        "--angular-axis", type=INDEX, default=0, help="turning (default 0: left stick)"
    )
    pad.add_argument(
        "--pad-scale",
        type=FRACTION,
        default=1.0,
        help="full deflection as a fraction of --max-linear/--max-angular (default 1)",
    )
    limit_args(p, "what the page may ask for")
    deadman_args(p, "the page")
    record_arg(p)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    require("web", "web")
    check_record(args, "web")
    return _web(profile(args.device), port, args)


async def _web(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .web_command import web

    await web(device, port, args)
