"""``chassis-sdk info``: what the device says about itself, and a diagnosis (the
device's own ``info`` if its commands have one)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..devices import DeviceProfile, profile
from .arguments import device_arg, port_args, positive, require_port
from .common import first_frame, out
from .devices import commands

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "info"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``info``."""
    p = sub.add_parser("info", help="what the device says about itself, and a diagnosis")
    port_args(p)
    device_arg(p, names)
    p.add_argument("--timeout", type=positive("timeout"), default=1.0, help="seconds per request")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    return info(profile(args.device), port, args.baudrate, args.timeout)


async def info(device: DeviceProfile, port: str, baudrate: int, timeout: float) -> None:
    """Print what ``device`` on ``port`` says about itself (generic: its first frame,
    the link and the counters)."""
    own = commands(device.name).info
    if own is not None:
        await own(port, baudrate, timeout)
        return
    async with device.device(port, baudrate=baudrate, request_timeout=timeout) as dev:
        out(f"port         {port}")
        out(f"device       {device.name}: {device.summary}")
        await first_frame(dev, max(timeout, 1.0), device.recognised_by)
        out(f"link         {dev.connection_state.value} via {dev.transport_backend}")
        for key, value in dev.stats.as_dict().items():
            if value:
                out(f"  {key:<19}{value}")
