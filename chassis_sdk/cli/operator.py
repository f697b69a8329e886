"""What the operator's commands (``estop``, ``clear-faults``, ``dock``) share: which
devices have them, their common arguments, and sending a command that the chassis
confirms in its telemetry, with one line (or one JSON object) of what it now shows.

Exit status: 0 when the telemetry shows the effect, `EXIT_UNCONFIRMED` (3) when
it does not within ``--timeout`` (one line on stderr); the everyday failures keep
theirs (1: no such port, another device on the port; 2: nothing answered, a bad
argument).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

from ..devices import DeviceProfile, profile, profiles
from ..devices.chassis.device import Chassis
from ..devices.chassis.health import explain_status
from ..devices.chassis.messages import ChassisStatus, Telemetry
from ..errors import ChassisError, RequestTimeoutError
from .arguments import device_arg, port_args, positive, require_port
from .common import first_frame, out

if TYPE_CHECKING:
    from .arguments import Job

__all__ = [
    "EXIT_UNCONFIRMED",
    "Action",
    "Outcome",
    "able_devices",
    "common_args",
    "confirmed",
    "start",
]

#: Exit status when the chassis does not confirm (its telemetry never shows the effect).
EXIT_UNCONFIRMED = 3


@dataclass(frozen=True, slots=True)
class Action:
    """One operator command, as sent and as confirmed.

    Attributes:
        command: The command's name (``"estop"``).
        action: What it does (``"engage"``, ``"release"``, ``"clear"``, ``"start"``...).
        send: Sends it through the public API, with ``confirm=True`` and the timeout
            it is given; raises `RequestTimeoutError` when not confirmed.
        bits: The status bits that show the effect.
        present: Whether the effect is ``bits`` set (True) or clear (False).
        done: The line's start when confirmed (``"e-stop engaged"``).
        what: What ``bits`` are called in that line (``"SOFTWARE_ESTOP"``).
        docking: The line also names the docking state.
    """

    command: str
    action: str
    send: Callable[[Chassis, float], Awaitable[None]]
    bits: ChassisStatus
    present: bool
    done: str
    what: str
    docking: bool = False


@dataclass(frozen=True, slots=True)
class Outcome:
    """What the telemetry showed after an `Action` (``--json`` prints it).

    Attributes:
        command, action: As in the `Action`.
        port: The port.
        confirmed: The telemetry showed the effect in time.
        status: Every set status bit of the latest telemetry, by name.
        remaining: The action's bits not (yet) as asked, by name.
        docking: The latest docking state, by name.
        message: The line printed (stdout when confirmed, stderr when not).
    """

    command: str
    action: str
    port: str
    confirmed: bool
    status: tuple[str, ...]
    remaining: tuple[str, ...]
    docking: str
    message: str

    def as_dict(self) -> dict[str, object]:
        """The outcome as plain JSON values."""
        return {
            "command": self.command,
            "action": self.action,
            "port": self.port,
            "confirmed": self.confirmed,
            "status": list(self.status),
            "remaining": list(self.remaining),
            "docking": self.docking,
            "message": self.message,
        }


def _names(bits: ChassisStatus | int) -> tuple[str, ...]:
    return tuple(flag.name for flag in explain_status(bits))


def _is_chassis(device: DeviceProfile) -> bool:
    try:
        return issubclass(device.device, Chassis)
    except Exception:  # a plugin whose class does not import cannot do it either
        return False


def able_devices() -> list[str]:
    """The registered devices that have the operator's commands (a `Chassis`)."""
    return [name for name, device in profiles().items() if _is_chassis(device)]


def common_args(p: argparse.ArgumentParser, names: Sequence[str]) -> None:
    """``PORT``, ``-b``, ``--device``, ``--timeout`` (2 s) and ``--json``."""
    port_args(p)
    device_arg(p, names)
    p.add_argument(
        "--timeout",
        type=positive("timeout"),
        default=2.0,
        help="seconds to wait for the telemetry to confirm (default %(default)s)",
    )
    p.add_argument("--json", action="store_true", help="print the outcome as one JSON object")


def start(args: argparse.Namespace, action: Action, cannot: str) -> Job:
    """The job of an operator command: checks (the port given, a device that has the
    command, before any port opens), then `confirmed`.

    Raises:
        UsageError: No port given.
        ChassisError: The device has no such command (``cannot``: what it cannot do),
            naming the devices that can.
    """
    port = require_port(args)
    device = profile(args.device)
    if not _is_chassis(device):
        able = ", ".join(able_devices()) or "none"
        raise ChassisError(f"{action.command}: a {device.name} {cannot} (devices that can: {able})")
    return confirmed(device, port, args.baudrate, args.timeout, action, args.json)


async def confirmed(
    device: DeviceProfile,
    port: str,
    baudrate: int,
    timeout: float,
    action: Action,
    as_json: bool,
) -> None:
    """Open ``port``, make sure it is ``device`` (`first_frame`), send ``action``
    and print what the telemetry now shows.

    Raises:
        SystemExit: `EXIT_UNCONFIRMED`, after one line on stderr, when the
            telemetry did not show the effect within ``timeout`` (the port is closed
            and the robot stopped by then).
    """
    async with device.device(port, baudrate=baudrate, request_timeout=timeout) as dev:
        if not isinstance(dev, Chassis):  # _is_chassis said so: a registry changed meanwhile
            raise ChassisError(f"{action.command}: {device.name} is not a chassis")
        await first_frame(
            dev,
            max(timeout, 1.0),
            device.recognised_by,
            command=action.command,
            able=able_devices(),
        )
        failure: str | None = None
        try:
            await action.send(dev, timeout)
        except RequestTimeoutError as exc:
            failure = str(exc)
        latest = dev.latest_telemetry
    outcome = _outcome(action, port, timeout, latest, failure)
    if as_json:
        out(json.dumps(outcome.as_dict()))
    elif outcome.confirmed:
        out(outcome.message)
    if not outcome.confirmed:
        print(f"chassis-sdk: {outcome.message}", file=sys.stderr, flush=True)
        raise SystemExit(EXIT_UNCONFIRMED)


def _outcome(
    action: Action, port: str, timeout: float, latest: Telemetry | None, failure: str | None
) -> Outcome:
    status = ChassisStatus(0) if latest is None else latest.status
    wrong = action.bits & ~status if action.present else action.bits & status
    if failure is None:
        shown = f"{action.what} {'set' if action.present else 'clear'}"
        if action.docking and latest is not None:
            shown += f", docking {latest.docking.name}"
        message = f"{action.done} ({shown})"
        others = [f for f in explain_status(status & ~action.bits) if f.fault]
        if others:
            message += "; still set: " + "; ".join(str(f) for f in others)
    elif wrong:
        flags = explain_status(wrong)
        names = ", ".join(f.name for f in flags)
        state = "not set" if action.present else "still set"
        message = f"{action.command}: not confirmed: {names} {state} after {timeout:g} s"
        if not action.present:
            message += ": " + "; ".join(f.meaning for f in flags)
    else:  # the telemetry stopped, or showed it only after the timeout
        message = f"{action.command}: not confirmed: {failure}"
    return Outcome(
        command=action.command,
        action=action.action,
        port=port,
        confirmed=failure is None,
        status=_names(status),
        remaining=_names(wrong),
        docking="unknown" if latest is None else latest.docking.name,
        message=message,
    )
