"""``chassis-sdk drive``: drive for a while, within limits, then stop; only a device
that answers in its own protocol is driven, and a lost link ends it at once."""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import anyio

from ..core.supervisor import ConnectionState
from ..core.watchdog import MotionLimits
from ..devices import DeviceProfile, profile
from ..errors import ChassisError
from .arguments import device_arg, finite, limit_args, port_args, positive, require_port
from .common import first_frame, out

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "drive"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``drive``."""
    p = sub.add_parser("drive", help="drive for a while (within limits), then stop")
    port_args(p)
    device_arg(p, names)
    p.add_argument("--linear", type=finite("linear"), default=0.0, help="m/s")
    p.add_argument("--angular", type=finite("angular"), default=0.0, help="rad/s")
    p.add_argument("--duration", type=positive("duration"), default=1.0, help="seconds")
    limit_args(p, "--linear and --angular")
    p.add_argument(
        "--timeout", type=positive("timeout"), default=2.0, help="seconds to hear the device"
    )
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    return drive(profile(args.device), port, args)


def _clamp(name: str, value: float, limit: float, flag: str, unit: str) -> float:
    if abs(value) <= limit:
        return value
    clamped = limit if value > 0 else -limit
    out(f"{name} {value:g} {unit} clamped to {clamped:g} {unit} ({flag})")
    return clamped


async def drive(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Drive ``device`` on ``port`` at ``args.linear``/``args.angular`` (clamped) for
    ``args.duration`` seconds, then stop.

    Raises:
        ChassisError: The link was lost while driving (the firmware stops the wheels).
    """
    linear = _clamp("linear", args.linear, args.max_linear, "--max-linear", "m/s")
    angular = _clamp("angular", args.angular, args.max_angular, "--max-angular", "rad/s")
    limits = MotionLimits(max_linear=args.max_linear, max_angular=args.max_angular)
    async with device.device(port, baudrate=args.baudrate, limits=limits) as dev:
        # Only a device that answers in its own protocol is driven.
        await first_frame(dev, args.timeout, device.recognised_by)
        states = dev.connection_states()
        out(f"driving v={linear:g} m/s, w={angular:g} rad/s for {args.duration:g} s")
        started = time.monotonic()
        await dev.set_velocity(linear, angular, duration=args.duration)
        with anyio.move_on_after(args.duration):
            async for state in states:
                if state in (ConnectionState.LOST, ConnectionState.RECONNECTING):
                    raise ChassisError(
                        f"lost the link to {port} after {time.monotonic() - started:.1f} s "
                        "while driving; the firmware stops the wheels on its own"
                    )
        await dev.stop()
    out("stopped")
