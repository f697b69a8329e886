"""What the chassis's status words mean: the edges its 0x81 status makes (events), and
the faults and notes its status and driver words give ``diagnose()``.

The mechanisms ([`EdgeDetector`][chassis_sdk.core.events.EdgeDetector],
[`Findings`][chassis_sdk.core.diagnosis.Findings]) are the core's; the tables are here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from ...core.diagnosis import Diagnosis, Findings, flag_names
from ...core.events import Edge, EdgeDetector, EventKind
from .messages import ChassisStatus, DriverError, DriverStatus, MotorStatus

__all__ = [
    "DRIVER_ERROR_MEANINGS",
    "EDGES",
    "FAULT_MOTOR",
    "FAULT_STATUS",
    "MOTOR_FAULT_MEANINGS",
    "STATUS_MEANINGS",
    "ChassisDiagnosis",
    "StatusEdges",
    "StatusFlag",
    "driver_findings",
    "explain_drivers",
    "explain_status",
    "status_findings",
]

S = ChassisStatus
E = EventKind
#: status bit -> (event when it sets, event when it clears, source)
EDGES: tuple[Edge, ...] = (
    (S.HARDWARE_ESTOP, E.ESTOP_ENGAGED, E.ESTOP_RELEASED, "hardware"),
    (S.REMOTE_ESTOP, E.ESTOP_ENGAGED, E.ESTOP_RELEASED, "remote"),
    (S.SOFTWARE_ESTOP, E.ESTOP_ENGAGED, E.ESTOP_RELEASED, "software"),
    (S.FRONT_BUMPER, E.BUMPER_HIT, E.BUMPER_CLEARED, "front"),
    (S.REAR_BUMPER, E.BUMPER_HIT, E.BUMPER_CLEARED, "rear"),
    (S.FRONT_DRIVER_OFFLINE, E.DRIVER_OFFLINE, E.DRIVER_ONLINE, "front"),
    (S.REAR_DRIVER_OFFLINE, E.DRIVER_OFFLINE, E.DRIVER_ONLINE, "rear"),
    (S.FRONT_LEFT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "front_left"),
    (S.FRONT_RIGHT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "front_right"),
    (S.REAR_LEFT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "rear_left"),
    (S.REAR_RIGHT_DRIVER_ERROR, E.DRIVER_ERROR, E.DRIVER_ERROR_CLEARED, "rear_right"),
)


class StatusEdges(EdgeDetector):
    """Edges of successive 0x81 (status, docking) levels: e-stops, bumpers, drivers,
    and docking changes."""

    def __init__(self) -> None:
        super().__init__(EDGES, EventKind.DOCKING_CHANGED)


#: Status bits that are faults; the others (REMOTE_OFFLINE, DOCKING_ENABLED) are notes.
FAULT_STATUS = (
    S.HARDWARE_ESTOP
    | S.REMOTE_ESTOP
    | S.SOFTWARE_ESTOP
    | S.FRONT_DRIVER_OFFLINE
    | S.REAR_DRIVER_OFFLINE
    | S.DRIVER_FAULT
    | S.BUMPER
)
#: What each status bit means, in plain words for an operator (what ``chassis-sdk info``
#: prints beside each set bit; the words of ``messages.ChassisStatus``'s comments, with
#: what to do about it). Every single bit of :class:`ChassisStatus` has an entry.
STATUS_MEANINGS: Mapping[ChassisStatus, str] = {
    S.HARDWARE_ESTOP: "the hardware emergency-stop button is pressed: release the button",
    S.REMOTE_ESTOP: "the remote control's emergency stop is on: release it on the remote",
    S.SOFTWARE_ESTOP: "the host's software emergency stop (0x03) is on: release it from the host",
    S.REMOTE_OFFLINE: "the remote control is off or out of range: normal under host control",
    S.FRONT_DRIVER_OFFLINE: "the front motor driver does not answer: check its power and cable",
    S.REAR_DRIVER_OFFLINE: "the rear motor driver does not answer: check its power and cable",
    S.FRONT_LEFT_DRIVER_ERROR: "the front-left motor driver reports an error: clear the faults",
    S.FRONT_RIGHT_DRIVER_ERROR: "the front-right motor driver reports an error: clear the faults",
    S.REAR_LEFT_DRIVER_ERROR: "the rear-left motor driver reports an error: clear the faults",
    S.REAR_RIGHT_DRIVER_ERROR: "the rear-right motor driver reports an error: clear the faults",
    S.FRONT_BUMPER: "the front bumper is triggered: free it, then clear the faults",
    S.REAR_BUMPER: "the rear bumper is triggered: free it, then clear the faults",
    S.DOCKING_ENABLED: "automatic docking is switched on",
}


@dataclass(frozen=True, slots=True)
class StatusFlag:
    """One set bit of a status word, explained.

    Attributes:
        name: The bit's name (``"SOFTWARE_ESTOP"``), or ``"BIT_<n>"`` for a bit the
            document does not name.
        fault: Whether it stops or degrades the robot (in `FAULT_STATUS`).
        meaning: What it means, in plain words (`STATUS_MEANINGS`).
    """

    name: str
    fault: bool
    meaning: str

    def __str__(self) -> str:
        return f"{self.name} ({'fault' if self.fault else 'info'}): {self.meaning}"


def explain_status(status: ChassisStatus | int) -> tuple[StatusFlag, ...]:
    """Every set bit of a 0x81 status word, lowest first, with whether it is a fault and
    what it means (an undocumented bit is a note: "not in the vendor document").

    Raises:
        TypeError: ``status`` is not an int (or a `ChassisStatus`).
    """
    if not isinstance(status, int) or isinstance(status, bool):
        raise TypeError(f"status must be a ChassisStatus or int, got {status!r}")
    bits, flags = int(status), []
    for n in range(bits.bit_length()):
        bit = 1 << n
        if not bits & bit:
            continue
        try:
            member = ChassisStatus(bit)
            name, meaning = str(member.name), STATUS_MEANINGS[member]
        except (ValueError, KeyError):
            name, meaning = f"BIT_{n}", "a bit the vendor document does not name"
        flags.append(StatusFlag(name, bool(bit & FAULT_STATUS), meaning))
    return tuple(flags)


#: Motor status bits that are faults.
FAULT_MOTOR = MotorStatus.ERROR_WARNING | MotorStatus.REVERSE_STALL | MotorStatus.FORWARD_STALL
_WHEELS = ("front_left", "front_right", "rear_left", "rear_right")

D = DriverError
#: What each error bit of a motor driver (0xB0) means, in plain words.
DRIVER_ERROR_MEANINGS: Mapping[DriverError, str] = {
    D.UNDER_VOLTAGE: "the battery is under-voltage: charge it",
    D.POSITION_ERROR: "position error: the wheel is not where the driver commanded",
    D.HALL_SENSOR: "the motor's hall sensor fails: check its cable",
    D.OVER_CURRENT: "over-current: the motor draws too much (blocked, or a short)",
    D.OVERLOAD: "overload: too heavy a load for too long",
    D.EEPROM: "the driver's EEPROM is faulty",
    D.IGBT: "the driver's power stage (IGBT) is faulty",
    D.DRIVER_OVER_TEMPERATURE: "the driver is too hot: let it cool",
    D.MOTOR_DEFECT: "the motor is defective",
    D.SUPPLY_OUT_OF_TOLERANCE: "the supply voltage is out of tolerance",
    D.SPEED_OUT_OF_TOLERANCE: "the speed is out of tolerance: the wheel does not follow",
    D.MOTOR_OVER_TEMPERATURE: "the motor is too hot: let it cool",
    D.SUPPLY_OVER_VOLTAGE: "the supply is over-voltage (regenerative braking, or the charger)",
    D.RUNAWAY: "runaway: the speed is not under control",
    D.DRIVER_OVER_TEMPERATURE_2: "the driver is too hot (second bit): let it cool",
}
#: What each faulty motor status bit (:data:`FAULT_MOTOR`) means.
MOTOR_FAULT_MEANINGS: Mapping[MotorStatus, str] = {
    MotorStatus.ERROR_WARNING: "the driver warns of an error",
    MotorStatus.REVERSE_STALL: "stalled in reverse: something blocks the wheel",
    MotorStatus.FORWARD_STALL: "stalled forwards: something blocks the wheel",
}


def explain_drivers(drivers: DriverStatus) -> tuple[StatusFlag, ...]:
    """Every error bit and faulty motor bit of each wheel's driver (a 0xB0 reply), as
    faults named ``"<wheel> driver <NAME>"`` and ``"<wheel> motor <NAME>"`` (the names
    `driver_findings` gives), with what each means."""
    flags = []
    for wheel in _WHEELS:
        d = getattr(drivers, wheel)
        for name in flag_names(DriverError(d.errors)):
            member = DriverError.__members__.get(name)
            meaning = DRIVER_ERROR_MEANINGS.get(member) if member is not None else None
            unnamed = "an error bit the vendor document does not name"
            flags.append(StatusFlag(f"{wheel} driver {name}", True, meaning or unnamed))
        for name in flag_names(d.motor & FAULT_MOTOR):
            meaning = MOTOR_FAULT_MEANINGS[MotorStatus[name]]
            flags.append(StatusFlag(f"{wheel} motor {name}", True, meaning))
    return tuple(flags)


@dataclass(frozen=True, slots=True)
class ChassisDiagnosis(Diagnosis):
    """The chassis's [`Diagnosis`][chassis_sdk.Diagnosis], with what was read for it.

    Attributes:
        status: The latest 0x81 status word, if any.
        drivers: The 0xB0 driver status read for this report, if any.
    """

    status: ChassisStatus | None = None
    drivers: DriverStatus | None = None


def status_findings(status: ChassisStatus, found: Findings | None = None) -> Findings:
    """Faults and notes for a 0x81 status word: every set bit, by name."""
    found = Findings() if found is None else found
    found.flags("status", status, FAULT_STATUS)
    return found


def driver_findings(drivers: DriverStatus, found: Findings | None = None) -> Findings:
    """Faults and notes for a 0xB0 reply: every error bit and faulty motor bit per wheel."""
    found = Findings() if found is None else found
    for flag in explain_drivers(drivers):
        found.fault(flag.name)
    for wheel in _WHEELS:
        d = getattr(drivers, wheel)
        found.note(
            f"{wheel} motor {'|'.join(flag_names(d.motor & ~FAULT_MOTOR)) or '-'}, "
            f"{d.current:+.1f} A (peak {d.peak_current:.1f} A)"
        )
    found.note(
        f"drivers {drivers.temperature_front:.1f}/{drivers.temperature_rear:.1f} °C, "
        f"{drivers.voltage_front:.1f}/{drivers.voltage_rear:.1f} V (front/rear)"
    )
    return found
