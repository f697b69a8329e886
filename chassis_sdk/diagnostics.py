"""``diagnose()``'s report: everything known about a device's health in one value that
prints as a readable report.

A fault is anything that stops or degrades the robot (an e-stop, a bumper, a driver
error bit, a stale link, a low battery); a note is a fact worth reading next to them
(status bits that are not faults, counters of what the line dropped, the battery
voltage). Every set status and driver bit is named, per wheel.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from ._device import ConnectionState, LinkStats
from .protocol.chassis import ChassisStatus, DriverError, DriverStatus, MotorStatus

__all__ = ["Diagnosis", "flag_names"]

#: Status bits that are faults; the others (REMOTE_OFFLINE, DOCKING_ENABLED) are notes.
FAULT_STATUS = (
    ChassisStatus.HARDWARE_ESTOP
    | ChassisStatus.REMOTE_ESTOP
    | ChassisStatus.SOFTWARE_ESTOP
    | ChassisStatus.FRONT_DRIVER_OFFLINE
    | ChassisStatus.REAR_DRIVER_OFFLINE
    | ChassisStatus.DRIVER_FAULT
    | ChassisStatus.BUMPER
)
#: Motor status bits that are faults.
FAULT_MOTOR = MotorStatus.ERROR_WARNING | MotorStatus.REVERSE_STALL | MotorStatus.FORWARD_STALL
_WHEELS = ("front_left", "front_right", "rear_left", "rear_right")


def flag_names(value: enum.IntFlag) -> list[str]:
    """The name of every set bit of ``value``, lowest first; an undocumented bit is
    named ``BIT_n``."""
    names = []
    bits = int(value)
    cls = type(value)
    for n in range(bits.bit_length()):
        if bits >> n & 1:
            try:
                names.append(cls(1 << n).name or f"BIT_{n}")
            except ValueError:
                names.append(f"BIT_{n}")
    return names


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """A device's health at one moment.

    Attributes:
        device: ``"chassis"`` or ``"board"``.
        port: The port it was read from.
        state: The connection state.
        stats: The link counters.
        faults: Every problem found, one readable line each.
        notes: Facts beside the faults, one readable line each.
        status: The latest 0x81 status word (chassis), if any.
        drivers: The 0xB0 driver status read for this report (chassis), if any.
    """

    device: str
    port: str
    state: ConnectionState
    stats: LinkStats
    faults: tuple[str, ...]
    notes: tuple[str, ...]
    status: ChassisStatus | None = None
    drivers: DriverStatus | None = None

    @property
    def ok(self) -> bool:
        """True when no fault was found."""
        return not self.faults

    def __str__(self) -> str:
        lines = [f"{self.device} on {self.port}: {self.state.value}, "
                 + ("OK" if self.ok else f"{len(self.faults)} fault(s)")]  # fmt: skip
        lines += [f"  FAULT  {f}" for f in self.faults]
        lines += [f"  note   {n}" for n in self.notes]
        s = self.stats
        lines.append(
            f"  link   {s.frames} frames in, {s.frames_sent} out; dropped {s.bytes_dropped} "
            f"bytes, {s.checksum_errors} bad checksums, {s.sequence_gaps} sequence gaps, "
            f"{s.queue_drops} queue drops, {s.reconnects} reconnects"
        )
        return "\n".join(lines)


def status_findings(status: ChassisStatus) -> tuple[list[str], list[str]]:
    """(faults, notes) for a 0x81 status word: every set bit, by name."""
    faults = [f"status {name}" for name in flag_names(status & FAULT_STATUS)]
    notes = [f"status {name}" for name in flag_names(status & ~FAULT_STATUS)]
    return faults, notes


def driver_findings(drivers: DriverStatus) -> tuple[list[str], list[str]]:
    """(faults, notes) for a 0xB0 reply: every error bit and faulty motor bit per wheel."""
    faults: list[str] = []
    notes: list[str] = []
    for wheel in _WHEELS:
        d = getattr(drivers, wheel)
        faults += [f"{wheel} driver {name}" for name in flag_names(DriverError(d.errors))]
        faults += [f"{wheel} motor {name}" for name in flag_names(d.motor & FAULT_MOTOR)]
        notes.append(
            f"{wheel} motor {'|'.join(flag_names(d.motor & ~FAULT_MOTOR)) or '-'}, "
            f"{d.current:+.1f} A (peak {d.peak_current:.1f} A)"
        )
    notes.append(
        f"drivers {drivers.temperature_front:.1f}/{drivers.temperature_rear:.1f} °C, "
        f"{drivers.voltage_front:.1f}/{drivers.voltage_rear:.1f} V (front/rear)"
    )
    return faults, notes
