"""``chassis-sdk detect``: listen, and say which device is on a port, or on each port
this user can open (all at once). Nothing is ever written to a port."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING

import anyio

from ..core.ports import list_serial_ports
from ..devices import profiles
from ..errors import ChassisError
from ..recording import capture
from .arguments import port_args, positive
from .common import out

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["EXIT_NOTHING_HEARD", "add_parser", "detect"]

#: ``detect``'s exit status when no known device is heard: 2, as ``info``, ``monitor``
#: and ``drive`` give for a port where nothing answers in time.
EXIT_NOTHING_HEARD = 2


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``detect``."""
    p = sub.add_parser("detect", help="listen and say which device is on a port (or on each)")
    port_args(p, required=False)
    p.add_argument("--seconds", type=positive("seconds"), default=1.5, help="how long to listen")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    return detect(args.port, args.seconds, args.baudrate)


async def _detect_one(port: str, seconds: float, baudrate: int) -> str:
    """The device heard on ``port``, else a line saying nothing was.

    Raises:
        ChassisError: ``port`` cannot be opened.
    """
    found = await capture.detect_device(port, seconds=seconds, baudrate=baudrate)
    if found is None:
        heard = " or ".join(p.recognised_by for p in profiles().values())
        return f"nothing recognisable within {seconds:g} s (expected {heard})"
    return found


async def detect(port: str | None, seconds: float, baudrate: int) -> None:
    """Print the device on ``port``, or a line per openable port when it is ``None``.

    Raises:
        ChassisError: The port cannot be opened, or there is no port to listen to.
        SystemExit: `EXIT_NOTHING_HEARD`, after one line on stderr, when no known
            device was heard (on ``port``, or on any port).
    """
    if port is not None:
        found = await _detect_one(port, seconds, baudrate)  # not opened: exit 1
        if found not in profiles():
            _nothing_heard(f"{port}: {found}")
        out(found)
        return
    # Every listed port at once, listening only: nothing is ever written to a port
    # that may be someone else's device.
    ports = [p.device for p in list_serial_ports() if p.access == "ok"]
    if not ports:
        raise ChassisError("no serial port this user can open (see `chassis-sdk ports`)")
    results = [""] * len(ports)

    async def listen(i: int) -> None:
        try:
            results[i] = await _detect_one(ports[i], seconds, baudrate)
        except ChassisError as exc:
            results[i] = str(exc)

    async with anyio.create_task_group() as tg:
        for i in range(len(ports)):
            tg.start_soon(listen, i)
    for port_name, found in zip(ports, results, strict=True):
        out(f"{port_name}: {found}")
    if not any(found in profiles() for found in results):
        _nothing_heard("no known device answered on any port")


def _nothing_heard(line: str) -> None:
    print(f"chassis-sdk: {line}", file=sys.stderr, flush=True)
    raise SystemExit(EXIT_NOTHING_HEARD)
