"""``chassis-sdk serve``: one device, live in the Foxglove app, for as long as it runs.

The device is opened once, with ``reconnect=True``; Ctrl-C or SIGTERM stops the server,
then the device (zero velocity first, as always).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import sys

from ..core.watchdog import MotionLimits
from ..devices import DeviceProfile
from ..errors import ChassisError
from .common import first_frame, out

__all__ = ["serve"]


async def serve(device: DeviceProfile, port: str, args: argparse.Namespace) -> None:
    """Serve until Ctrl-C, SIGTERM or ``--seconds``."""
    try:
        from ..live import FoxgloveServer
    except ImportError:
        raise ChassisError(
            "serve needs foxglove-sdk: pip install 'chassis-sdk[foxglove]'"
        ) from None
    limits = MotionLimits(max_linear=args.max_linear, max_angular=args.max_angular)
    async with device.device(
        port,
        baudrate=args.baudrate,
        reconnect=True,
        limits=limits,
        command_timeout=args.command_timeout,
    ) as dev:
        await first_frame(dev, 3.0, device.recognised_by)
        try:
            server = FoxgloveServer(
                dev,
                host=args.host,
                port=args.foxglove_port,
                read_only=args.read_only,
                record=args.record,
            )
            server.start()
        except RuntimeError as exc:  # the address is taken, or cannot be bound
            raise ChassisError(f"cannot serve on {args.host}:{args.foxglove_port}: {exc}") from None
        try:
            mode = "read-only" if args.read_only else "Teleop and services on"
            out(f"serving {port} ({device.name}) to Foxglove at {server.url} ({mode})")
            print(
                "open it in the Foxglove app (Open connection > Foxglove WebSocket); "
                "Ctrl-C to quit",
                file=sys.stderr,
            )
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(asyncio.Event().wait(), args.seconds)
        finally:
            server.stop()
