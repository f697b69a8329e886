"""``chassis-sdk sim``: a device's simulator on a pseudo-terminal (or TCP), with
optional line faults, until Ctrl-C or SIGTERM; its first line is the port to use."""

from __future__ import annotations

import argparse
import contextlib
import errno
from collections.abc import AsyncIterator, Sequence
from typing import TYPE_CHECKING

import anyio

from ..devices import DeviceProfile, profile
from ..errors import ChassisError
from ..sim import simulator
from ..sim.server import LineFaults, SimulatorServer
from .arguments import TCP_PORT, chance
from .common import out

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "serving", "sim"]


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``sim``."""
    p = sub.add_parser("sim", help="run a simulator until Ctrl-C; prints the port to use")
    p.add_argument("device", choices=list(names), help="which device to simulate")
    p.add_argument(
        "--tcp", type=TCP_PORT, metavar="PORT", help="serve on TCP instead of a pty (0: any free)"
    )
    for flag, dest, what in (
        ("--noise", "noise", "insert a random byte before a sent byte with this chance"),
        ("--bit-flips", "bit_flips", "flip one bit of a sent byte with this chance"),
        ("--drop", "drop", "lose a sent byte with this chance"),
    ):
        p.add_argument(flag, dest=dest, type=chance(dest), default=0.0, metavar="RATE", help=what)
    p.add_argument(
        "--reply-delay", type=float, default=0.0, metavar="SECONDS", help="hold replies back"
    )
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    faults = LineFaults(
        noise_rate=args.noise,
        bit_flip_rate=args.bit_flips,
        drop_rate=args.drop,
        reply_delay=args.reply_delay,
    )
    return sim(profile(args.device), args.tcp, faults)


async def sim(device: DeviceProfile, tcp: int | None, faults: LineFaults) -> None:
    """Serve ``device``'s simulator until cancelled, printing the port first."""
    async with serving(simulator(device.name, tcp_port=tcp, faults=faults), tcp) as server:
        out(server.port)
        out(f"{device.name} simulator running; connect to the line above. Ctrl-C stops it.")
        await anyio.sleep_forever()


@contextlib.asynccontextmanager
async def serving(server: SimulatorServer, tcp: int | None) -> AsyncIterator[SimulatorServer]:
    """``server`` started (and stopped after), a TCP port that cannot be listened on
    told in one line.

    Raises:
        ChassisError: The port is in use, or not ours to take.
    """
    try:
        await server.start()
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            why = "it is in use (another simulator or server?); pick another, or 0 for any"
        else:
            why = exc.strerror or str(exc)
        where = "a pty" if tcp is None else f"TCP port {tcp}"
        raise ChassisError(f"cannot serve on {where}: {why}") from None
    try:
        yield server
    finally:
        await server.stop()
