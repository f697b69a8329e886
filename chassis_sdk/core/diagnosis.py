"""``diagnose()``'s report: everything known about a device's health in one value that
prints as a readable report.

A fault is anything that stops or degrades the robot (an e-stop, a bumper, a driver
error bit, a stale link, a low battery); a note is a fact worth reading next to them
(status bits that are not faults, counters of what the line dropped, the battery
voltage). The device base finds the link's and the battery's; each device adds the
findings of its own status words (`Findings` collects them), naming every set bit
(`flag_names`).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from .enums import flag_names
from .stats import LinkStats
from .supervisor import ConnectionState

__all__ = ["Diagnosis", "Findings", "flag_names"]


class Findings:
    """Faults and notes as a diagnosis gathers them, one readable line each."""

    faults: list[str]
    notes: list[str]

    def __init__(self) -> None:
        self.faults = []
        self.notes = []

    def fault(self, text: str) -> None:
        """Something that stops or degrades the robot."""
        self.faults.append(text)

    def note(self, text: str) -> None:
        """A fact worth reading beside the faults."""
        self.notes.append(text)

    def flags(self, prefix: str, value: enum.IntFlag, faulty: enum.IntFlag | int) -> None:
        """Every set bit of ``value`` by name: those in ``faulty`` as faults, the rest
        as notes (``"{prefix} {NAME}"``)."""
        # Plain ints: an IntFlag's ~ keeps only its named bits, and would lose the
        # undocumented ones, which are notes worth reading.
        cls, bits, mask = type(value), int(value), int(faulty)
        self.faults += [f"{prefix} {name}" for name in flag_names(cls(bits & mask))]
        self.notes += [f"{prefix} {name}" for name in flag_names(cls(bits & ~mask))]


@dataclass(frozen=True, slots=True)
class Diagnosis:
    """A device's health at one moment.

    A device may return a subclass that adds what it read for the report (the chassis
    adds its status word and driver status).

    Attributes:
        device: The device's profile name (``"chassis"``, ``"board"``, ...).
        port: The port it was read from.
        state: The connection state.
        stats: The link counters.
        faults: Every problem found, one readable line each.
        notes: Facts beside the faults, one readable line each.
    """

    device: str
    port: str
    state: ConnectionState
    stats: LinkStats
    faults: tuple[str, ...]
    notes: tuple[str, ...]

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
