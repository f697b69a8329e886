"""``chassis-sdk monitor``: a live view of a device's streams, link, faults and events
(the device's own ``monitor`` if its commands have one, else every stream its profile
names, as lines or JSON)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import anyio

from ..devices import DeviceProfile, profile
from .arguments import device_arg, port_args, positive, require_port
from .common import first_frame, jsonable, out
from .devices import commands

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "monitor"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``monitor``."""
    p = sub.add_parser("monitor", help="live view of the streams, link, faults and events")
    port_args(p)
    device_arg(p, names)
    p.add_argument("--seconds", type=positive("seconds"), help="stop after this long")
    p.add_argument("--json", action="store_true", help="one JSON object per message")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    return monitor(profile(args.device), port, args.baudrate, args.seconds, args.json)


async def monitor(
    device: DeviceProfile, port: str, baudrate: int, seconds: float | None, as_json: bool
) -> None:
    """Follow ``device`` on ``port`` for ``seconds`` (``None``: until cancelled)."""
    own = commands(device.name).monitor
    if own is not None:
        await own(port, baudrate, seconds, as_json)
        return
    # Any other device: its streams (from its profile), link and events, as lines.
    async with device.device(port, baudrate=baudrate, reconnect=True) as dev:
        await first_frame(dev, 3.0, device.recognised_by)
        if not as_json:
            print("Ctrl-C to quit", file=sys.stderr)
        async with anyio.create_task_group() as tg:
            for name in device.remote.streams:
                tg.start_soon(_follow, dev, name, as_json)
            tg.start_soon(_follow_link, dev, as_json)
            with anyio.move_on_after(math.inf if seconds is None else seconds):
                await anyio.sleep_forever()
            tg.cancel_scope.cancel()


def _brief(value: object) -> str:
    """A message's fields on one line, numbers to three decimals."""
    if isinstance(value, dict):
        return " ".join(f"{k}={_brief(v)}" for k, v in value.items() if k != "timestamp")
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


async def _follow(dev: Any, stream: str, as_json: bool) -> None:
    last = 0.0
    async for message in getattr(dev, stream)():
        if as_json:
            out(json.dumps({"type": type(message).__name__, **jsonable(message)}))
        elif time.monotonic() - last >= 0.2:  # five lines a second per stream at most
            out(f"{stream}: {_brief(jsonable(message))}")
            last = time.monotonic()


async def _follow_link(dev: Any, as_json: bool) -> None:
    async for state in dev.connection_states():
        out(
            json.dumps({"type": "link", "state": state.value})
            if as_json
            else f"link: {state.value}"
        )
