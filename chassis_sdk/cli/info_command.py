"""``chassis-sdk info``: what the device says about itself, and a diagnosis (the
device's own ``info`` if its commands have one).

A scriptable health check: exit status 0 when the diagnosis finds no fault,
`EXIT_FAULT` (4) when it finds one (one line on stderr names them), so
``chassis-sdk info PORT || alert`` works; the everyday failures keep theirs (1, 2).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from ..core.diagnosis import Diagnosis
from ..devices import DeviceProfile, profile
from ..devices.config import Profile
from .arguments import device_arg, port_args, positive, require_port
from .common import first_frame, out, port_lines
from .devices import commands

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["EXIT_FAULT", "EXIT_PARTIAL", "add_parser", "info", "verdict"]

#: ``info``'s exit status when the device reports a fault.
EXIT_FAULT = 4
#: ``info``'s exit status when the device answered some requests but not all (a noisy
#: line): what it answered is printed, the rest marked.
EXIT_PARTIAL = 5


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``info``."""
    p = sub.add_parser(
        "info",
        help="what the device says about itself, and a diagnosis (exit 4 on a fault)",
        description="Versions, one frame of each stream, what each set status flag means "
        "and a diagnosis. Exit 0 when healthy, 4 when a fault is present (a scriptable "
        "health check); REMOTE_OFFLINE and other notes are information, not faults.",
    )
    port_args(p)
    device_arg(p, names)
    p.add_argument("--timeout", type=positive("timeout"), default=1.0, help="seconds per request")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    port = require_port(args)
    loaded: Profile = getattr(args, "profile", None) or Profile()
    battery = loaded.battery()
    options = {} if battery is None else {"battery": battery}
    return info(profile(args.device), port, args.baudrate, args.timeout, **options)


async def info(
    device: DeviceProfile, port: str, baudrate: int, timeout: float, **options: Any
) -> None:
    """Print what ``device`` on ``port`` says about itself (generic: its first frame,
    the link and the counters). ``options`` go to the device's constructor (the
    profile's ``battery=BatteryModel(...)``, for the state of charge)."""
    own = commands(device.name).info
    if own is not None:
        await own(port, baudrate, timeout, **options)
        return
    async with device.device(port, baudrate=baudrate, request_timeout=timeout, **options) as dev:
        port_lines(port)
        out(f"device       {device.name}: {device.summary}")
        await first_frame(dev, max(timeout, 1.0), device.recognised_by)
        out(f"link         {dev.connection_state.value} via {dev.transport_backend}")
        for key, value in dev.stats.as_dict().items():
            if value:
                out(f"  {key:<19}{value}")


def verdict(report: Diagnosis, unanswered: Sequence[str] = ()) -> None:
    """The end of a device's ``info``, once its port is closed: nothing when ``report``
    is healthy and every request was answered; else one line on stderr, and exit
    `EXIT_FAULT` naming the faults, or `EXIT_PARTIAL` naming what went
    ``unanswered`` (a fault is the more important news).

    Raises:
        SystemExit: `EXIT_FAULT`, when ``report`` has a fault;
            `EXIT_PARTIAL`, when some request was not answered.
    """
    where = f"{report.device} on {report.port}"
    if not report.ok:
        n = len(report.faults)
        print(
            f"chassis-sdk: info: {where}: {n} fault{'s' * (n > 1)}: " + ", ".join(report.faults),
            file=sys.stderr,
            flush=True,
        )
        raise SystemExit(EXIT_FAULT)
    if unanswered:
        print(
            f"chassis-sdk: info: {where}: partial: no reply for {', '.join(unanswered)} "
            "(a noisy line? try --timeout)",
            file=sys.stderr,
            flush=True,
        )
        raise SystemExit(EXIT_PARTIAL)
