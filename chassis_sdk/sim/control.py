"""Runtime commands to a simulated device: faults a newcomer can inject while the
simulator runs (``chassis-sdk sim`` reads them from its standard input), one line in,
one line out. Pure: the firmware model and the time are given, nothing is read or
printed here.

=====================================  ==========================================
``bumper front|rear``                  press a bumper (latched until clear-faults)
``bumper front|rear hold``             hold it pressed (clear-faults cannot clear it)
``bumper front|rear off``              let it go and clear its latch
``estop on|off [hardware|remote]``     press or release an e-stop button
``battery VOLTS``                      set the battery's open-circuit voltage
``driver-fault FL|FR|RL|RR [ERROR]``   latch a motor-driver error (``over_current``)
``driver-fault FL|FR|RL|RR off``       clear that driver's errors
``stall SECONDS|off``                  hold the wheels still (commanded, not turning)
``tilt DEGREES|off [pitch|roll]``      tilt a board (its IMU shows it)
``reset [SECONDS]``                    reboot the firmware (silent for 0.5 s)
``status``                             the true pose and what is injected
``help``                               the commands this device takes
=====================================  ==========================================

Every answer is one line starting ``ok: `` or ``error: ``; a blank line or a ``#``
comment gets no answer. No line raises: what cannot be done is said.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..core.firmware import Firmware
from ..core.validation import check_real
from ..devices.board.firmware import BoardFirmware
from ..devices.chassis.firmware import ChassisFirmware
from ..devices.chassis.messages import DriverError

__all__ = ["COMMANDS", "apply", "help_line"]

_WHEELS = ("fl", "fr", "rl", "rr")
_CHASSIS = (ChassisFirmware,)
_BOARD = (BoardFirmware,)
_BOTH = (ChassisFirmware, BoardFirmware)


class _Usage(Exception):
    """The arguments do not fit the command's usage."""


@dataclass(frozen=True, slots=True)
class _Command:
    usage: str
    run: Callable[[Any, list[str], float], str]
    devices: tuple[type, ...]
    #: What the devices it does not apply to lack, for the refusal.
    lacks: str


def _on_off(word: str) -> bool:
    if word in ("on", "off"):
        return word == "on"
    raise _Usage


def _number(word: str, name: str, low: float, high: float, unit: str) -> float:
    try:
        value = float(word)
    except ValueError:
        raise ValueError(f"{name} must be a number, got {word!r}") from None
    return check_real(value, name, low=low, high=high, unit=unit)


def _bumper(fw: ChassisFirmware, args: list[str], now: float) -> str:
    if not 1 <= len(args) <= 2 or args[0] not in ("front", "rear"):
        raise _Usage
    side, front = args[0], args[0] == "front"
    action = args[1] if len(args) == 2 else "press"
    if action == "press":
        fw.press_bumper(front)
        return f"{side} bumper pressed (latched until clear-faults)"
    if action == "hold":
        fw.hold_bumper(front)
        return f"{side} bumper held pressed (clear-faults cannot clear it; 'bumper {side} off')"
    if action == "off":
        fw.release_bumper(front)
        return f"{side} bumper released and its latch cleared"
    raise _Usage


def _estop(fw: ChassisFirmware, args: list[str], now: float) -> str:
    if not 1 <= len(args) <= 2:
        raise _Usage
    pressed = _on_off(args[0])
    kind = args[1] if len(args) == 2 else "hardware"
    if kind == "hardware":
        fw.set_hardware_estop(pressed)
    elif kind == "remote":
        fw.set_remote_estop(pressed)
    else:
        raise _Usage
    return f"{kind} e-stop {'pressed' if pressed else 'released'}"


def _battery(fw: ChassisFirmware | BoardFirmware, args: list[str], now: float) -> str:
    if len(args) != 1:
        raise _Usage
    volts = _number(args[0], "battery", 0, 100, "V")
    fw.set_battery(volts)
    return f"battery at {volts:g} V (open circuit; it sags under load)"


def _driver_fault(fw: ChassisFirmware, args: list[str], now: float) -> str:
    if not 1 <= len(args) <= 2 or args[0] not in _WHEELS:
        raise _Usage
    wheel, name = _WHEELS.index(args[0]), args[0].upper()
    what = args[1] if len(args) == 2 else "over_current"
    if what == "off":
        fw.set_driver_fault(wheel, DriverError(0))
        return f"{name} driver's errors cleared"
    try:
        error = DriverError[what.upper()]
    except KeyError:
        known = ", ".join(e.name.lower() for e in DriverError if e.name)
        raise ValueError(f"unknown driver error {what!r} (known: {known})") from None
    fw.set_driver_fault(wheel, error)
    return f"{name} driver fault {error.name} (latched until clear-faults)"


def _stall(fw: ChassisFirmware | BoardFirmware, args: list[str], now: float) -> str:
    if len(args) != 1:
        raise _Usage
    seconds = 0.0 if args[0] == "off" else _number(args[0], "stall", 0, 3600, "s")
    fw.stall_wheels(now, seconds)
    if not seconds:
        return "wheels free"
    return f"wheels stalled for {seconds:g} s (commanded, not turning)"


def _tilt(fw: BoardFirmware, args: list[str], now: float) -> str:
    if not 1 <= len(args) <= 2:
        raise _Usage
    degrees = 0.0 if args[0] == "off" else _number(args[0], "tilt", -90, 90, "°")
    axis = args[1] if len(args) == 2 else "pitch"
    if axis not in ("pitch", "roll"):
        raise _Usage
    fw.set_tilt(*((degrees, 0.0) if axis == "pitch" else (0.0, degrees)))
    if not degrees:
        return "board level"
    return f"board tilted {degrees:g}° ({axis}); the IMU shows it"


def _reset(fw: ChassisFirmware | BoardFirmware, args: list[str], now: float) -> str:
    if len(args) > 1:
        raise _Usage
    downtime = _number(args[0], "reset", 0, 60, "s") if args else 0.5
    fw.reset(now, downtime)
    return f"firmware rebooting (silent for {downtime:g} s)"


def _status(fw: ChassisFirmware | BoardFirmware, args: list[str], now: float) -> str:
    if args:
        raise _Usage
    x, y, heading = fw.true_pose
    parts = [f"true pose x={x:.3f} m y={y:.3f} m heading={math.degrees(heading):.1f}°"]
    if isinstance(fw, ChassisFirmware):
        parts.append(f"status {fw.status.name or 'clear'}")
    else:
        pitch, roll = fw.tilt
        parts.append(f"tilt pitch {pitch:g}° roll {roll:g}°")
    parts.append(f"battery {fw.battery_voltage:.1f} V")
    if fw.stalled(now):
        parts.append("stalled")
    if fw.world is not None:
        parts.append(f"{fw.impacts} impacts")
    return "; ".join(parts)


#: The commands, by name: usage, what runs it, the firmware models it applies to.
COMMANDS: dict[str, _Command] = {
    "bumper": _Command("bumper front|rear [hold|off]", _bumper, _CHASSIS, "no bumpers"),
    "estop": _Command("estop on|off [hardware|remote]", _estop, _CHASSIS, "no e-stop button"),
    "battery": _Command("battery VOLTS", _battery, _BOTH, "no battery model"),
    "driver-fault": _Command(
        "driver-fault FL|FR|RL|RR [off|ERROR]", _driver_fault, _CHASSIS, "no motor drivers to ask"
    ),
    "stall": _Command("stall SECONDS|off", _stall, _BOTH, "no wheels to stall"),
    "tilt": _Command("tilt DEGREES|off [pitch|roll]", _tilt, _BOARD, "no IMU"),
    "reset": _Command("reset [SECONDS]", _reset, _BOTH, "no reset"),
    "status": _Command("status", _status, _BOTH, "no status"),
}


def _device(firmware: Firmware) -> str:
    if isinstance(firmware, ChassisFirmware):
        return "the chassis"
    if isinstance(firmware, BoardFirmware):
        return "the board"
    return "this device's simulator"


def help_line(firmware: Firmware) -> str:
    """The commands ``firmware`` takes, in one line."""
    usages = [c.usage for c in COMMANDS.values() if isinstance(firmware, c.devices)]
    return "commands: " + "; ".join([*usages, "help"])


def apply(firmware: Firmware, line: str, now: float) -> str:
    """Carry out one command line on ``firmware`` at time ``now`` (the clock its
    ``poll`` is given) and say what happened.

    Args:
        firmware: The model (a chassis or a board; other models take only ``help``).
        line: The command, e.g. ``"bumper front"``; words are case-insensitive,
            ``#`` starts a comment.
        now: The model's time.

    Returns:
        One line, ``ok: ...`` or ``error: ...``; empty for a blank or comment line.
    """
    words = line.split("#", 1)[0].split()
    if not words:
        return ""
    name, args = words[0].lower(), [word.lower() for word in words[1:]]
    if name == "help":
        return f"ok: {help_line(firmware)}"
    command = COMMANDS.get(name)
    if command is None:
        return f"error: unknown command {words[0]!r}; try help"
    if not isinstance(firmware, command.devices):
        return f"error: {name} does not apply to {_device(firmware)} (it has {command.lacks})"
    try:
        return f"ok: {command.run(firmware, args, now)}"
    except _Usage:
        return f"error: usage: {command.usage}"
    except (TypeError, ValueError) as exc:
        return f"error: {exc}"
