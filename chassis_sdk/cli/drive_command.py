"""``chassis-sdk drive``: drive for a while, within limits, then stop; only a device
that answers in its own protocol is driven, one whose motion is blocked (an e-stop, a
bumper, a driver fault) is refused before anything is written, and a lost link ends it
at once."""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import anyio

from ..core.device import Device
from ..core.supervisor import ConnectionState
from ..core.validation import check_real
from ..devices import DeviceProfile, profile
from ..errors import ChassisError
from .arguments import (
    DRIVE_CEILING_ANGULAR,
    DRIVE_CEILING_LINEAR,
    UsageError,
    arg_type,
    check_record,
    device_arg,
    finite,
    limit_args,
    port_args,
    positive,
    record_arg,
    require_port,
)
from .common import blocked_line, first_frame, out
from .info_command import EXIT_FAULT
from .profile import device_options

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["MAX_DURATION", "add_parser", "drive"]

#: The longest ``--duration`` (s): ten minutes; a longer run is a job for teleop or a
#: program, not one command line (``1e9`` was 31 years).
MAX_DURATION = 600.0
DURATION = arg_type(
    float, lambda v: check_real(v, "duration", low=0, low_open=True, high=MAX_DURATION, unit="s")
)


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``drive``."""
    p = sub.add_parser(
        "drive",
        help="drive for a while (within limits), then stop",
        description="Drive at --linear and/or --angular (at least one) for --duration, "
        f"then stop. Speeds beyond --max-linear/--max-angular are clamped (the defaults "
        f"are slow; the flags or the profile's [limits] raise them, up to "
        f"{DRIVE_CEILING_LINEAR:g} m/s and {DRIVE_CEILING_ANGULAR:g} rad/s). A device "
        f"that reports its motion blocked (an e-stop, a bumper, a driver fault) is "
        f"refused with exit {EXIT_FAULT} and nothing written; Ctrl-C stops it.",
    )
    port_args(p)
    device_arg(p, names)
    p.add_argument("--linear", type=finite("linear"), help="m/s (default 0 if --angular)")
    p.add_argument("--angular", type=finite("angular"), help="rad/s (default 0 if --linear)")
    p.add_argument(
        "--duration",
        type=DURATION,
        default=1.0,
        help=f"seconds, at most {MAX_DURATION:g}; default %(default)s",
    )
    limit_args(p, "--linear and --angular")
    p.add_argument(
        "--timeout", type=positive("timeout"), default=2.0, help="seconds to hear the device"
    )
    record_arg(p)
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    if args.linear is None and args.angular is None:
        raise UsageError("give a velocity: --linear V and/or --angular W")
    check_record(args, "drive")
    return drive(profile(args.device), port, args)


def _clamp(name: str, value: float, limit: float, flag: str, unit: str, ceiling: float) -> float:
    if abs(value) <= limit:
        return value
    clamped = limit if value > 0 else -limit
    more = f"; {flag} raises it, up to {ceiling:g} {unit}" if limit < ceiling else ""
    out(f"{name} {value:g} {unit} clamped to {clamped:g} {unit} ({flag}){more}")
    return clamped


async def drive(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Drive ``device`` on ``port`` at ``args.linear``/``args.angular`` (clamped) for
    ``args.duration`` seconds, then stop.

    Raises:
        ChassisError: The link was lost while driving (the firmware stops the wheels).
        SystemExit: `EXIT_FAULT`, after one line on stderr, when
            the device reports its motion blocked (nothing is written).
    """
    linear = _clamp(
        "linear", args.linear or 0.0, args.max_linear, "--max-linear", "m/s", DRIVE_CEILING_LINEAR
    )
    angular = _clamp(
        "angular",
        args.angular or 0.0,
        args.max_angular,
        "--max-angular",
        "rad/s",
        DRIVE_CEILING_ANGULAR,
    )
    blocked: tuple[str, ...] = ()
    try:
        async with device.device(port, **device_options(args, record=args.record)) as dev:
            # Only a device that answers in its own protocol is driven.
            await first_frame(dev, args.timeout, device.recognised_by)
            # The firmware takes a command while e-stopped and ignores it: say so first.
            blocked = dev.motion_blocked()
            if not blocked:
                await _drive(dev, port, linear, angular, args.duration)
    except anyio.get_cancelled_exc_class():
        # Ctrl-C or SIGTERM: leaving the block wrote zero and closed the port.
        out("interrupted; stopped")
        raise
    if blocked:
        print(f"chassis-sdk: {blocked_line(device.name, port, blocked)}", file=sys.stderr)
        raise SystemExit(EXIT_FAULT)
    out("stopped")


async def _drive(
    dev: Device[Any, Any], port: str, linear: float, angular: float, duration: float
) -> None:
    states = dev.connection_states()
    out(f"driving v={linear:g} m/s, w={angular:g} rad/s for {duration:g} s")
    started = time.monotonic()
    await dev.set_velocity(linear, angular, duration=duration)
    with anyio.move_on_after(duration):
        async for state in states:
            if state in (ConnectionState.LOST, ConnectionState.RECONNECTING):
                raise ChassisError(
                    f"lost the link to {port} after {time.monotonic() - started:.1f} s "
                    "while driving; the firmware stops the wheels on its own"
                )
    await dev.stop()
