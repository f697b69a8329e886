"""``chassis-sdk demo``: a device's simulator driven through the real serial stack,
narrated (the device's own ``demo``). No hardware needed."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..devices import DeviceProfile, profile
from ..errors import ChassisError
from .arguments import device_arg
from .devices import commands

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "demo"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``demo``: ``--device NAME``, and ``--NAME`` for each device but the
    first (the default)."""
    p = sub.add_parser("demo", help="drive the built-in simulator through the real serial stack")
    device_arg(p, names, default=names[0], help_text="which device to demo")
    for other in names[1:]:
        p.add_argument(
            f"--{other}",
            action="store_const",
            dest="device",
            const=other,
            help=f"= --device {other}",
        )
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    return demo(profile(args.device))


async def demo(device: DeviceProfile) -> None:
    """Run ``device``'s demo.

    Raises:
        ChassisError: The device has none.
    """
    own = commands(device.name).demo
    if own is None:
        raise ChassisError(f"there is no demo of a {device.name}; try `sim {device.name}`")
    await own()
