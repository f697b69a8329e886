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

from ..core.charge import battery_fields, battery_text
from ..core.plain import outbound
from ..devices import DeviceProfile, profile
from .arguments import device_arg, port_args, positive, require_port
from .common import first_frame, out
from .devices import commands
from .profile import device_options

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "brief", "monitor"]


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
    # A viewer writes nothing, not even the zero at close: another program may be
    # driving this robot (read_only). The profile's battery model gives the charge.
    options = device_options(args, read_only=True)
    baudrate = options.pop("baudrate")
    return monitor(profile(args.device), port, baudrate, args.seconds, args.json, **options)


async def monitor(
    device: DeviceProfile,
    port: str,
    baudrate: int,
    seconds: float | None,
    as_json: bool,
    **options: Any,
) -> None:
    """Follow ``device`` on ``port`` for ``seconds`` (``None``: until cancelled).

    ``options`` are the device's keyword options, passed to its own monitor (if it has
    one) or its constructor: ``battery=BatteryModel(...)`` shows the state of charge
    beside each voltage (``24.6 V  63 %``, ``--`` while not known; in JSON
    ``battery_percentage`` and ``battery_level``, ``null`` while not known)."""
    own = commands(device.name).monitor
    if own is not None:
        await own(port, baudrate, seconds, as_json, **options)
        return
    # Any other device: its streams (from its profile), link and events, as lines.
    options = {"reconnect": True, **options}
    async with device.device(port, baudrate=baudrate, **options) as dev:
        await first_frame(dev, 3.0, device.recognised_by)
        if not as_json:
            print("Ctrl-C to quit", file=sys.stderr)
        async with anyio.create_task_group() as tg:
            for name in device.remote.streams:
                tg.start_soon(_follow, dev, name, as_json)
            tg.start_soon(_follow_link, dev, as_json)
            tg.start_soon(_follow_events, dev, as_json)
            with anyio.move_on_after(math.inf if seconds is None else seconds):
                await anyio.sleep_forever()
            tg.cancel_scope.cancel()


#: Fields a line leaves out: the clock (wall and monotonic) of each message.
_CLOCKS = frozenset({"timestamp", "monotonic"})


#: Values whose text is ``str(value)``, written without a call to `brief`.
_AS_TEXT = frozenset({int, str, bool, type(None)})


def brief(value: object) -> str:
    """A message's fields on one line (not its clock), numbers to three decimals."""
    if isinstance(value, dict):
        # A loop, not a call per field: `replay` writes a line per frame of a capture
        # (180,000 an hour), and most fields are a float or a name.
        parts = []
        for k, v in value.items():
            if k in _CLOCKS:
                continue
            cls = v.__class__
            if cls is float:
                parts.append(f"{k}={v:.3f}")
            elif cls in _AS_TEXT:
                parts.append(f"{k}={v}")
            else:
                parts.append(f"{k}={brief(v)}")
        return " ".join(parts)
    if isinstance(value, float):
        return f"{value:.3f}"
    return str(value)


async def _follow(dev: Any, stream: str, as_json: bool) -> None:
    last = 0.0
    async for message in getattr(dev, stream)():
        fields = outbound(message)
        # A reading of the pack's voltage: the state of charge beside it.
        voltage = fields.get("voltage") if isinstance(fields, dict) else None
        if as_json:
            body = {"type": type(message).__name__, **fields}
            if isinstance(voltage, float):
                body.update(battery_fields(dev))
            out(json.dumps(body))
        elif time.monotonic() - last >= 0.2:  # five lines a second per stream at most
            if isinstance(voltage, float):
                rest = brief({k: v for k, v in fields.items() if k != "voltage"})
                text = f"{battery_text(voltage, dev)}  {rest}".rstrip()
            else:
                text = brief(fields)
            out(f"{stream}: {text}")
            last = time.monotonic()


async def _follow_link(dev: Any, as_json: bool) -> None:
    async for state in dev.connection_states():
        out(
            json.dumps({"type": "link", "state": state.value})
            if as_json
            else f"link: {state.value}"
        )


async def _follow_events(dev: Any, as_json: bool) -> None:
    async for event in dev.events():
        if event.kind.value.startswith("link_"):
            continue  # _follow_link tells these
        out(json.dumps({"type": "event", **outbound(event)}) if as_json else f"event: {event}")
