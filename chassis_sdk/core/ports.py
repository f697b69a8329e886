"""Finding the port: every serial port on this machine, what it is, and whether this
user can open it now.

Nothing here opens a port: opening one toggles DTR, which resets some boards. Access
is read from the file's permissions and the kernel's table of locks (a program holding
the port, as ``chassis_sdk`` and most serial tools do, is named when it is visible).
"""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass
from typing import Any

from serial.tools import list_ports

from .transport import lock_holder

__all__ = ["PortInfo", "list_serial_ports"]


@dataclass(frozen=True, slots=True)
class PortInfo:
    """One serial port.

    Attributes:
        device: The path to open (``/dev/ttyUSB0``).
        description: What the system calls it (``CP2102 USB to UART Bridge``), or ``""``.
        manufacturer: The USB manufacturer string, or ``""``.
        vid_pid: ``"10C4:EA60"`` for a USB device, ``""`` otherwise.
        serial_number: The USB serial number, or ``""``.
        access: ``"ok"``, ``"permission denied"``, ``"busy: held by ..."`` or
            ``"missing"``.
    """

    device: str
    description: str
    manufacturer: str
    vid_pid: str
    serial_number: str
    access: str

    def as_dict(self) -> dict[str, Any]:
        """The fields as a plain ``dict`` (for JSON)."""
        return asdict(self)


def _access(path: str) -> str:
    if not os.path.exists(path):
        return "missing"
    if not os.access(path, os.R_OK | os.W_OK):
        return "permission denied (join the group that owns it, usually dialout)"
    holder = lock_holder(path)
    return f"busy: held by {holder}" if holder else "ok"


def _text(value: object) -> str:
    return "" if value in (None, "n/a") else str(value)


def list_serial_ports() -> list[PortInfo]:
    """Every serial port the system lists (``serial.tools.list_ports``), USB first."""
    found = []
    for port in list_ports.comports():
        vid_pid = f"{port.vid:04X}:{port.pid:04X}" if port.vid is not None else ""
        found.append(
            PortInfo(
                device=port.device,
                description=_text(port.description),
                manufacturer=_text(port.manufacturer),
                vid_pid=vid_pid,
                serial_number=_text(port.serial_number),
                access=_access(port.device),
            )
        )
    return sorted(found, key=lambda p: (not p.vid_pid, p.device))
