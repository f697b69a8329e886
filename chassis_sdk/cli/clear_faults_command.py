"""``chassis-sdk clear-faults PORT [--driver] [--front-bumper] [--rear-bumper]``: clear
latched faults (all three without a flag), confirmed by the telemetry."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..devices.chassis.device import Chassis
from ..devices.chassis.messages import ChassisStatus
from .operator import Action, common_args, start

if TYPE_CHECKING:
    from .arguments import Job, Subparsers

__all__ = ["action", "add_parser"]

#: Each flag: (the argument's destination, the status bits it clears, its name in lines).
_WHAT = (
    ("driver", ChassisStatus.DRIVER_FAULT, "driver faults"),
    ("front_bumper", ChassisStatus.FRONT_BUMPER, "FRONT_BUMPER"),
    ("rear_bumper", ChassisStatus.REAR_BUMPER, "REAR_BUMPER"),
)


def add_parser(sub: Subparsers, names: Sequence[str]) -> None:
    """Register ``clear-faults``."""
    p = sub.add_parser(
        "clear-faults",
        help="clear driver and bumper faults, confirmed by telemetry",
        description="Clear latched faults (0x05) and wait for the telemetry to show them "
        "clear: the driver faults and both bumpers, or only those flagged. Exit 3, naming "
        "what is still set, when the chassis does not confirm (a bumper still pressed).",
    )
    common_args(p, names)
    p.add_argument("--driver", action="store_true", help="the motor drivers' faults")
    p.add_argument("--front-bumper", action="store_true", help="the front bumper's latch")
    p.add_argument("--rear-bumper", action="store_true", help="the rear bumper's latch")
    p.set_defaults(func=_start)


def action(driver: bool, front_bumper: bool, rear_bumper: bool) -> Action:
    """The `Action` that clears what is selected (all
    three when nothing is)."""
    chosen = {"driver": driver, "front_bumper": front_bumper, "rear_bumper": rear_bumper}
    if not any(chosen.values()):
        chosen = dict.fromkeys(chosen, True)
    bits = ChassisStatus(0)
    what = []
    for key, bit, name in _WHAT:
        if chosen[key]:
            bits |= bit
            what.append(name)

    async def send(robot: Chassis, timeout: float) -> None:
        await robot.clear_faults(**chosen, confirm=True, timeout=timeout)

    return Action("clear-faults", "clear", send, bits, False, "faults cleared", ", ".join(what))


def _start(args: argparse.Namespace) -> Job:
    chosen = action(args.driver, args.front_bumper, args.rear_bumper)
    return start(args, chosen, "has no faults to clear")
