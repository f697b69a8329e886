"""``chassis-sdk sim``: a device's simulator on a pseudo-terminal (or TCP), with
optional line faults and a world of walls, until Ctrl-C or SIGTERM; its first line is
the port to use. While it runs it takes runtime commands, one a line, on its standard
input (``bumper front``, ``stall 2``, ``help``: `chassis_sdk.sim.control`) and answers
each with one line on its standard output.

Standard input is read without a thread: the loop waits until the descriptor is
readable and then reads what is there, so Ctrl-C and SIGTERM end the wait like any
other (no thread is left blocked in ``read``). A file or ``/dev/null``, which cannot
be waited on (epoll refuses them), never blocks and is read as it is. At the end of
input the simulator runs on. On a terminal, input is read only while the simulator
is in the foreground: a read from the background would stop the process (SIGTTIN),
and ``chassis-sdk sim chassis &`` must keep serving.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
from collections.abc import AsyncIterator, Sequence
from typing import TYPE_CHECKING

import anyio
import anyio.lowlevel

from ..devices import DeviceProfile, profile
from ..errors import ChassisError
from ..sim import World, simulator
from ..sim.server import LineFaults, SimulatorServer
from .arguments import TCP_PORT, arg_type, chance
from .common import out

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser", "serving", "sim", "take_commands"]

#: The longest command line taken (bytes); a longer one is refused whole.
MAX_LINE = 1024
#: How often a terminal's background reader looks whether it is in the foreground (s).
_BACKGROUND_POLL = 0.5


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``sim``."""
    p = sub.add_parser(
        "sim",
        help="run a simulator until Ctrl-C; prints the port to use",
        description="Run a device's simulator until Ctrl-C; its first line is the port to "
        "use. While it runs, it takes commands on its standard input, one a line "
        "(bumper front, estop on, battery 21.0, driver-fault FL, stall 2, tilt 30, "
        "status, help), and answers each in one line.",
    )
    p.add_argument("device", choices=list(names), help="which device to simulate")
    p.add_argument(
        "--world",
        type=arg_type(World.parse, lambda world: world),
        metavar="SPEC",
        help="walls to run into: arena:WxH (metres, centred on the start pose) or "
        "wall:X1,Y1,X2,Y2, several joined by +",
    )
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
        "--reply-delay",
        # Refused while parsing as LineFaults refuses it (a finite number >= 0).
        type=arg_type(float, lambda v: LineFaults(reply_delay=v).reply_delay),
        default=0.0,
        metavar="SECONDS",
        help="hold replies back",
    )
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    faults = LineFaults(
        noise_rate=args.noise,
        bit_flip_rate=args.bit_flips,
        drop_rate=args.drop,
        reply_delay=args.reply_delay,
    )
    device = profile(args.device)
    # Made here, before the loop: a world the robot does not fit in is one line, exit 1.
    server = simulator(device.name, tcp_port=args.tcp, faults=faults, world=args.world)
    return _serve(device, server, args.tcp, args.world)


async def sim(
    device: DeviceProfile, tcp: int | None, faults: LineFaults, world: World | None = None
) -> None:
    """Serve ``device``'s simulator until cancelled, printing the port first, and take
    runtime commands on standard input meanwhile.

    Raises:
        ValueError: A world for a device without one, or one the robot does not fit in.
    """
    server = simulator(device.name, tcp_port=tcp, faults=faults, world=world)
    await _serve(device, server, tcp, world)


async def _serve(
    device: DeviceProfile, server: SimulatorServer, tcp: int | None, world: World | None
) -> None:
    async with serving(server, tcp):
        out(server.port)
        where = "" if world is None else f" in a world of {len(world.walls)} walls"
        out(
            f"{device.name} simulator running{where}; connect to the line above. "
            "Ctrl-C stops it; type help for commands."
        )
        await take_commands(server)
        await anyio.sleep_forever()  # the end of input is not the end of the simulator


async def take_commands(server: SimulatorServer, fd: int = 0) -> None:
    """Carry out each line arriving on ``fd`` (standard input) as a runtime command of
    ``server`` (`SimulatorServer.command`), answering each on standard output, until
    the end of input. No line ends it; nothing to read (a closed descriptor) ends it
    at once."""
    try:
        terminal = os.isatty(fd)
        os.fstat(fd)
    except OSError:
        return
    async for line in _lines(fd, terminal):
        if line is None:
            out(f"error: line longer than {MAX_LINE} bytes; ignored")
            continue
        answer = server.command(line)
        if answer:
            out(answer)
    if terminal:
        out("ok: end of input; the simulator runs on until Ctrl-C")


async def _lines(fd: int, terminal: bool) -> AsyncIterator[str | None]:
    """The lines read from ``fd`` until its end (``None`` for one too long)."""
    pending = b""
    overlong = False
    pollable = True
    while True:
        if pollable:
            try:
                await anyio.wait_readable(fd)
            except OSError:  # EPERM: a file or /dev/null, always ready
                pollable = False
        else:
            await anyio.lowlevel.checkpoint()
        if terminal and not _foreground(fd):
            await anyio.sleep(_BACKGROUND_POLL)
            continue
        try:
            chunk = os.read(fd, 4096)
        except BlockingIOError:  # someone else made it non-blocking and took the data
            continue
        except OSError:  # the terminal hung up
            return
        if not chunk:
            break
        pending += chunk
        *lines, pending = pending.split(b"\n")
        for line in lines:
            if overlong:  # the rest of a line already refused
                overlong = False
                continue
            yield None if len(line) > MAX_LINE else line.decode("utf-8", "replace")
        if len(pending) > MAX_LINE and not overlong:
            overlong, pending = True, b""
            yield None
        elif overlong:
            pending = b""
    if pending and not overlong:
        yield pending.decode("utf-8", "replace")


def _foreground(fd: int) -> bool:
    """True if this process's group owns the terminal ``fd`` (reading will not stop it)."""
    try:
        return os.tcgetpgrp(fd) == os.getpgrp()
    except OSError:
        return True  # not a controlling terminal: reading cannot stop us


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
