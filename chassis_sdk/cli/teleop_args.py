"""``chassis-sdk teleop``'s arguments; the command itself is
`chassis_sdk.cli.teleop_command`."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..core.validation import check_real
from ..devices import DeviceProfile, profile
from ..errors import ChassisError
from ..teleop.gamepad import ABS_CODES, BTN_CODES, event_code
from ..teleop.keys import KEY_TIMEOUT, MAX_KEY_TIMEOUT
from .arguments import (
    arg_type,
    check_record,
    deadman_args,
    device_arg,
    finite,
    limit_args,
    port_args,
    record_arg,
    require_port,
)
from .extras import install_hint, require

#: The longest a silent pad may go on driving (s).
MAX_JOY_TIMEOUT = 5.0

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser"]

SPEED = arg_type(float, lambda v: check_real(v, "speed", low=0, high=1, low_open=True))
DEADZONE = arg_type(float, lambda v: check_real(v, "joy_deadzone", low=0, high=0.99))
JOY_TIMEOUT = arg_type(float, lambda v: check_real(v, "joy_timeout", low=0, high=MAX_JOY_TIMEOUT))
KEY_TIMEOUT_ARG = arg_type(
    float, lambda v: check_real(v, "key_timeout", low=0, low_open=True, high=MAX_KEY_TIMEOUT)
)
BUTTON = arg_type(str, lambda v: event_code(v, BTN_CODES, "--enable-button"))
AXIS = arg_type(str, lambda v: event_code(v, ABS_CODES, "an axis"))


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``teleop``."""
    p = sub.add_parser(
        "teleop",
        help="drive from the terminal's keys (or a gamepad), e.g. over ssh",
        description=(
            "Drive with the arrow keys or WASD (held: the terminal's autorepeat keeps the "
            "robot moving; released: it stops within the key timeout), +/- speed, space "
            "stop, e e-stop, r release it, q quit. Losing the terminal (SIGHUP, ssh "
            "dropping) stops the robot at once."
        ),
    )
    port_args(p)
    device_arg(p, names)
    limit_args(p, "every command; 100 %% speed is these")
    deadman_args(p, "teleop")
    p.add_argument(
        "--key-timeout",
        type=KEY_TIMEOUT_ARG,
        default=KEY_TIMEOUT,
        metavar="S",
        help=(
            "a key counts as released when it has not repeated for this long before its "
            "first autorepeat (must exceed the terminal's autorepeat delay; default "
            "%(default)s s covers X11's 660 ms); while it repeats, 3 repeat intervals "
            "(at least 0.15 s)"
        ),
    )
    p.add_argument(
        "--speed",
        type=SPEED,
        default=0.3,
        metavar="FRACTION",
        help="starting speed, a fraction of the maxima (default %(default)s; +/- step 0.1)",
    )
    joy = p.add_argument_group(f"gamepad ({install_hint('joystick')})")
    joy.add_argument(
        "--joystick", metavar="DEVICE", help="a gamepad's /dev/input/event* (Linux evdev)"
    )
    joy.add_argument(
        "--enable-button",
        type=BUTTON,
        default=BTN_CODES["BTN_TL"],
        metavar="BTN",
        help="the deadman button, a name (BTN_TL, BTN_SOUTH, ...) or code (default BTN_TL)",
    )
    joy.add_argument(
        "--linear-axis",
        type=AXIS,
        default=ABS_CODES["ABS_Y"],
        metavar="ABS",
        help="axis for linear speed (default ABS_Y; up = forward)",
    )
    joy.add_argument(
        "--angular-axis",
        type=AXIS,
        default=ABS_CODES["ABS_X"],
        metavar="ABS",
        help="axis for turning (default ABS_X; left = turn left)",
    )
    joy.add_argument(
        "--joy-scale-linear",
        type=finite("joy_scale_linear"),
        metavar="V",
        help="m/s at full stick (negative inverts; default --max-linear)",
    )
    joy.add_argument(
        "--joy-scale-angular",
        type=finite("joy_scale_angular"),
        metavar="W",
        help="rad/s at full stick (negative inverts; default --max-angular)",
    )
    joy.add_argument(
        "--joy-deadzone",
        type=DEADZONE,
        default=0.1,
        metavar="F",
        help="fraction of each half-axis read as zero (default %(default)s)",
    )
    joy.add_argument(
        "--joy-timeout",
        type=JOY_TIMEOUT,
        default=1.0,
        metavar="S",
        help=(
            "stop when the enabled pad sends nothing for this long (evdev reports changes "
            "only: a stick held exactly still counts; 0: never; default %(default)s)"
        ),
    )
    record_arg(p)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    if args.joystick:
        require("teleop --joystick", "joystick")
    check_record(args, "teleop")
    if not sys.stdin.isatty():  # before anything opens: nothing is written
        raise ChassisError(
            "teleop reads keys from a terminal, and stdin is not one (over ssh: ssh -t)"
        )
    return _teleop(profile(args.device), port, args)


async def _teleop(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    from .teleop_command import teleop

    await teleop(device, port, args)
