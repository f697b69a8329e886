"""``chassis-sdk estop PORT [--release]``: engage (or release) the software emergency
stop, confirmed by the telemetry's ``SOFTWARE_ESTOP`` bit."""

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


async def _engage(robot: Chassis, timeout: float) -> None:
    await robot.emergency_stop(confirm=True, timeout=timeout)


async def _release(robot: Chassis, timeout: float) -> None:
    await robot.release_emergency_stop(confirm=True, timeout=timeout)


ENGAGE = Action("estop", "engage", _engage, ChassisStatus.SOFTWARE_ESTOP, True,
                "e-stop engaged", "SOFTWARE_ESTOP")  # fmt: skip
RELEASE = Action("estop", "release", _release, ChassisStatus.SOFTWARE_ESTOP, False,
                 "e-stop released", "SOFTWARE_ESTOP")  # fmt: skip


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``estop``."""
    p = sub.add_parser(
        "estop",
        help="engage the software e-stop (or --release it), confirmed by telemetry",
        description="Engage the chassis's software emergency stop (0x03) and wait for "
        "the telemetry to show SOFTWARE_ESTOP; --release clears it (the robot then moves "
        "only on the next velocity command). Exit 3 when the chassis does not confirm.",
    )
    common_args(p, names)
    p.add_argument("--release", action="store_true", help="release the software e-stop")
    p.set_defaults(func=_start)


def _start(args: argparse.Namespace) -> Job:
    return start(args, RELEASE if args.release else ENGAGE, "has no software e-stop")
