"""What the chassis's status words mean: the edges its 0x81 status makes (events), and
the faults and notes its status and driver words give ``diagnose()``.

The mechanisms (:class:`~chassis_sdk.core.events.EdgeDetector`,
:class:`~chassis_sdk.core.diagnosis.Findings`) are the core's; the tables are here.
"""

from __future__ import annotations

from dataclasses import dataclass

from ...core.diagnosis import Diagnosis, Findings, flag_names
from ...core.events import Edge, EdgeDetector, EventKind
from .messages import ChassisStatus, DriverError, DriverStatus, MotorStatus

__all__ = [
    "EDGES",
    "FAULT_MOTOR",
    "FAULT_STATUS",
    "ChassisDiagnosis",
    "StatusEdges",
    "driver_findings",
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
#: Motor status bits that are faults.
FAULT_MOTOR = MotorStatus.ERROR_WARNING | MotorStatus.REVERSE_STALL | MotorStatus.FORWARD_STALL
_WHEELS = ("front_left", "front_right", "rear_left", "rear_right")


@dataclass(frozen=True, slots=True)
class ChassisDiagnosis(Diagnosis):
    """The chassis's :class:`~chassis_sdk.Diagnosis`, with what was read for it.

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
    for wheel in _WHEELS:
        d = getattr(drivers, wheel)
        for name in flag_names(DriverError(d.errors)):
            found.fault(f"{wheel} driver {name}")
        for name in flag_names(d.motor & FAULT_MOTOR):
            found.fault(f"{wheel} motor {name}")
        found.note(
            f"{wheel} motor {'|'.join(flag_names(d.motor & ~FAULT_MOTOR)) or '-'}, "
            f"{d.current:+.1f} A (peak {d.peak_current:.1f} A)"
        )
    found.note(
        f"drivers {drivers.temperature_front:.1f}/{drivers.temperature_rear:.1f} °C, "
        f"{drivers.voltage_front:.1f}/{drivers.voltage_rear:.1f} V (front/rear)"
    )
    return found
