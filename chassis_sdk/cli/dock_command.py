"""``chassis-sdk dock PORT start|stop``: switch automatic docking on or off, confirmed
by the telemetry's ``DOCKING_ENABLED`` bit."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..devices.chassis.device import Chassis
from ..devices.chassis.messages import ChassisStatus
from .operator import Action, common_args, start

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["add_parser"]


async def _start_docking(robot: Chassis, timeout: float) -> None:
    await robot.start_docking(confirm=True, timeout=timeout)


async def _stop_docking(robot: Chassis, timeout: float) -> None:
    await robot.stop_docking(confirm=True, timeout=timeout)


ACTIONS = {
    "start": Action("dock", "start", _start_docking, ChassisStatus.DOCKING_ENABLED, True,
                    "docking started", "DOCKING_ENABLED", docking=True),
    "stop": Action("dock", "stop", _stop_docking, ChassisStatus.DOCKING_ENABLED, False,
                   "docking stopped", "DOCKING_ENABLED", docking=True),
}  # fmt: skip


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``dock``."""
    p = sub.add_parser(
        "dock",
        help="start or stop automatic docking, confirmed by telemetry",
        description="Start or stop the chassis's automatic docking (0x06) and wait for "
        "the telemetry to show DOCKING_ENABLED set or clear; follow the docking state with "
        "`chassis-sdk monitor`. Exit 3 when the chassis does not confirm.",
    )
    common_args(p, names)  # PORT first: dock PORT start|stop
    # Named as docs/cli.md writes it: a refused word reads "argument start|stop: ...".
    p.add_argument(
        "what", metavar="start|stop", choices=sorted(ACTIONS), help="start or stop docking"
    )
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    return start(args, ACTIONS[args.what], "cannot dock")
